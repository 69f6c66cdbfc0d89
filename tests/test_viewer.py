"""Viewer: every log_* function writes a real .rrd that rerun's own reader reads back."""

from __future__ import annotations

import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from fnsi_lab.cli import main
from fnsi_lab.viewer import log as vlog
from fnsi_lab.viewer import paths
from fnsi_lab.viewer.blueprint import blueprint
from fnsi_lab.viewer.cli import rrd_entities, rrd_text, signal_groups
from fnsi_lab.viewer.figure import dashes as figure_dashes


def read_rrd(path) -> dict[str, list]:
    """entity -> list of (is_static, pyarrow RecordBatch), read with rerun's RrdReader."""
    out: dict[str, list] = {}
    for chunk in RrdReader(str(path)).stream().collect().stream():
        out.setdefault(chunk.entity_path, []).append((chunk.is_static, chunk.to_record_batch()))
    return out


def column(batches, name: str, *, static: bool = False) -> list:
    """Concatenate one column over an entity's chunks (temporal or static only)."""
    values = []
    for is_static, batch in batches:
        if is_static == static and name in batch.schema.names:
            values += batch.column(name).to_pylist()
    return values


def static_values(batches, name: str) -> list:
    """The last static value of column ``name`` (a figure series' physical values)."""
    got = column(batches, name, static=True)
    assert got, f"no static column {name}"
    return got[-1]


@pytest.fixture
def rec_path(tmp_path):
    path = tmp_path / "run.rrd"
    rec = rr.RecordingStream("fnsi-lab-test", recording_id="test")
    rec.save(str(path), default_blueprint=blueprint(("force", "displacement")))
    yield rec, path


def _finish(rec):
    rec.flush()
    rec.disconnect()


def test_signals_go_to_one_entity_per_group_on_acq_time(rec_path):
    rec, path = rec_path
    names = ["F", "x1", "x2"]
    groups = vlog.channel_groups(names, ["force", "displacement", "displacement"])
    assert groups == {"force": [0], "displacement": [1, 2]}
    vlog.log_signal_styles(rec, groups, names)
    data = np.arange(60, dtype=float).reshape(20, 3)
    vlog.log_signals(rec, data[:10], 0.0, 100.0, groups)
    vlog.log_signals(rec, data[10:], 0.1, 100.0, groups, decimation=2)
    _finish(rec)
    got = read_rrd(path)
    disp = got[paths.signal_group("displacement")]
    vals = column(disp, "Scalars:scalars")
    assert len(vals) == 10 + 5
    assert vals[0] == [1.0, 2.0] and vals[10] == [31.0, 32.0] and vals[11] == [37.0, 38.0]
    t = []
    for is_static, b in disp:
        if not is_static:
            t += [v.total_seconds() for v in b.column(paths.TIME_ACQ).to_pylist()]
            assert "log_time" not in b.schema.names  # only the one x timeline
    assert t[10] == pytest.approx(0.1) and t[11] == pytest.approx(0.12)
    assert column(disp, "SeriesLines:names", static=True) == [["x1", "x2"]]


def test_identification_figures_hold_the_physical_values(rec_path):
    rec, path = rec_path
    f = np.array([5.0, 10.5, 20.25])
    h = np.array([1.0, 0.1j, -0.01])
    order = [2, 4, 4, 6, 6, 6, 6]
    freq = [10, 10, 20, 10, 20, 20.5, 33]
    cls = ["new", "frequency", "new", "stable", "stable", "stable", "unstable"]
    vlog.log_identification(rec, {
        "frf": {"frequency_hz": f, "measured": h, "linear": 2 * h, "model": h},
        "stabilisation": {"order": order, "frequency_hz": freq, "pole_class": cls,
                          "damping_ratio": [0.01] * 6 + [-0.02]},
        "criterion": {"orders": [2, 4, 6, 8], "criterion": [100.0, 1.0, 10.0, np.inf],
                      "selected_order": 4},
        "mdi": {"frequency_hz": [10.0, 20.0, 33.0], "mdi": [1e-2, 1e-4, 1e-9],
                "kept": [True, True, False], "threshold": 1e-6},
        "coefficients": {"frequency_hz": f, "full": {"k_nl": [1.1e7, 0.9e7, 1.0e7 + 5j]},
                         "reduced": {"k_nl": [1.0e7, 1.0e7, 1.0e7]},
                         "exact": {"k_nl": 1e7, "k_not_estimated": 3.0}},
        "convergence": {"update": 3, "acq_time_s": 49.152,
                        "values": {"natural_frequency_hz": [10.0, 28.34],
                                   "selected_order": [4]}},
        "summary": vlog.summary_markdown("SmallSat", [("order", "4")],
                                         [{"mode": 1, "f (Hz)": 10.0}]),
    }, update=3)
    _finish(rec)
    got = read_rrd(path)

    # FRF: every line with its complex value; the canvas lines exist
    measured = got[paths.FRF_MEASURED]
    assert static_values(measured, "frequency_hz") == [5.0, 10.5, 20.25]
    assert static_values(measured, "re") == pytest.approx(h.real)
    assert static_values(measured, "im") == pytest.approx(h.imag)
    assert static_values(got[paths.FRF_LINEAR], "re") == pytest.approx(2 * h.real)
    assert f"{paths.FRF_PHASE}/model" in got

    # stabilisation diagram: every pole once, several per order (the former export lost them)
    exported = []
    for c in paths.POLE_CLASSES:
        batches = got[paths.stabilisation_class(c)]
        o = column(batches, "order", static=True)
        if o and o[-1]:
            exported += [(c, n, fr) for n, fr in zip(o[-1], static_values(batches,
                                                                         "frequency_hz"))]
    assert sorted(exported) == sorted(zip(cls, order, map(float, freq)))
    assert static_values(got[paths.stabilisation_class("unstable")], "damping_ratio") == [-0.02]
    positions = column(got[paths.stabilisation_class("stable")], "Points2D:positions",
                       static=True)[-1]
    assert len(positions) == 3

    # criterion: all orders kept (inf as is), the selected point
    assert static_values(got[paths.ORDER_CRITERION], "order") == [2, 4, 6, 8]
    assert static_values(got[paths.ORDER_SELECTED], "criterion") == [1.0]

    assert static_values(got[paths.MDI_KEPT], "mdi") == [1e-2, 1e-4]
    assert static_values(got[paths.MDI_REMOVED], "frequency_hz") == [33.0]
    assert static_values(got[paths.MDI_THRESHOLD], "threshold") == [1e-6]

    full = got[paths.coefficient("k_nl", "full")]
    assert static_values(full, "re") == [1.1e7, 0.9e7, 1.0e7]
    assert static_values(full, "im") == [0.0, 0.0, 5.0]
    assert static_values(got[paths.coefficient("k_nl", "exact")], "exact") == [1e7]
    # the exact value of a coefficient that is not estimated is not drawn
    assert not any("k_not_estimated" in e for e in got)

    # per-update series: one per mode, named by it, lines and points (visible at once)
    mode2 = got[paths.convergence_mode("natural_frequency_hz", 2)]
    assert column(mode2, "Scalars:scalars") == [[28.34]]
    assert column(mode2, paths.TIME_UPDATE) == [3]
    assert column(mode2, "SeriesLines:names", static=True)[-1] == ["mode 2 (28.3 Hz)"]
    assert column(mode2, "SeriesPoints:names", static=True)[-1] == ["mode 2 (28.3 Hz)"]
    assert column(got[paths.convergence("selected_order")], "Scalars:scalars") == [[4.0]]

    text = rrd_text(path, paths.SUMMARY)
    assert "| order | 4 |" in text and "| 1 | 10 |" in text


def test_status_and_blueprint_are_stored(rec_path):
    rec, path = rec_path
    vlog.log_status(rec, 1.5, {"rate": 120.0, "dropped_blocks": 0}, "update 1 done")
    _finish(rec)
    got = read_rrd(path)
    assert column(got[paths.status("rate")], "Scalars:scalars") == [[120.0]]
    assert column(got[paths.STATUS_LOG], "TextLog:text") == [["update 1 done"]]
    reader = RrdReader(str(path))
    assert [s.kind for s in reader.blueprints()] == ["blueprint"]
    blueprint_entities = {c.entity_path for c in reader.stream(store=reader.blueprints()[0])
                          .collect().stream()}
    # the view origins are the paths constants
    origins = set()
    for chunk in reader.stream(store=reader.blueprints()[0]).collect().stream():
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if name.endswith(":space_origin"):
                origins |= {v[0] if isinstance(v, list) else v
                            for v in batch.column(name).to_pylist() if v}
    assert blueprint_entities
    for p in (paths.STABILISATION, paths.ORDER, paths.FRF, paths.MDI, paths.COEFFICIENTS,
              paths.CONVERGENCE_FREQUENCIES, paths.CONVERGENCE_COEFFICIENTS,
              paths.signal_group("force")):
        assert p in origins


def test_view_command_lists_entities_and_prints_the_summary(rec_path, capsys):
    rec, path = rec_path
    vlog.log_summary(rec, vlog.summary_markdown("Result", [("selected order", "26")]))
    vlog.log_information_criterion(rec, [2, 4], [1.0, 0.5], 4)
    _finish(rec)
    assert set(rrd_entities(path)) >= {paths.SUMMARY, paths.ORDER_CRITERION}
    assert main(["view", str(path), "--list"]) == 0
    out = capsys.readouterr().out
    assert paths.ORDER_CRITERION in out and "| selected order | 26 |" in out
    assert main(["view", str(path.parent / "nope.rrd")]) == 2


def test_view_serves_a_file_with_the_signal_views_of_its_groups(rec_path):
    """``view --serve-web``/``--connect`` build the blueprint from the file's own groups."""
    rec, path = rec_path
    names = ["F", "a1", "a2"]
    groups = vlog.channel_groups(names, ["force", "acceleration", "acceleration"])
    vlog.log_signal_styles(rec, groups, names)
    vlog.log_signals(rec, np.zeros((10, 3)), 0.0, 100.0, groups)
    vlog.log_information_criterion(rec, [2, 4], [1.0, 0.5], 4)
    _finish(rec)
    assert signal_groups(rrd_entities(path)) == ("force", "acceleration")
    assert signal_groups(["/signals/velocity", "/signals/force", "/signals/acceleration",
                          "/ident/order/criterion"]) == ("force", "acceleration", "velocity")
    assert signal_groups([paths.ORDER_CRITERION]) == ("force", "displacement")


@pytest.mark.parametrize("command", ["view", "replay", "live", "report"])
def test_every_help_has_an_example(command, capsys):
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "example" in out and f"fnsi-lab {command}" in out


def test_part_sanitises_names():
    assert paths.part("F-NC2W Z") == "F-NC2W_Z"
    assert paths.part("a/b") == "a_b"
    assert paths.part("///") == "unnamed"


def test_empty_inputs_log_empty_figures_and_do_not_fail(rec_path):
    rec, path = rec_path
    vlog.log_frf(rec, [], measured=[])
    vlog.log_stabilisation(rec, [], [], [])
    vlog.log_mdi(rec, [], [], [], None)
    vlog.log_information_criterion(rec, [], [], None)
    vlog.log_coefficients(rec, [], {"k": []}, None, {"k": 1.0})
    vlog.log_convergence(rec, 1, 0.0, {"natural_frequency_hz": []})
    _finish(rec)
    got = read_rrd(path)
    assert static_values(got[paths.FRF_MEASURED], "frequency_hz") == []
    assert paths.convergence_mode("natural_frequency_hz", 1) not in got


def test_an_update_replaces_the_figures(rec_path):
    """Static figures: the newest update is what every tab shows, whatever the cursor."""
    rec, path = rec_path
    f = np.array([10.0, 20.0])
    for k, gain in ((1, 1.0), (2, 10.0)):
        vlog.log_identification(rec, {
            "frf": {"frequency_hz": f, "measured": gain * np.ones(2)},
            "stabilisation": {"order": [2, 4], "frequency_hz": [10.0, 10.0],
                              "pole_class": ["new", "stable"] if k == 1 else ["new", "new"]},
        }, update=k)
    _finish(rec)
    got = read_rrd(path)
    assert static_values(got[paths.FRF_MEASURED], "re") == [10.0, 10.0]
    # a class update 2 no longer has is emptied, not left over from update 1
    assert static_values(got[paths.stabilisation_class("stable")], "order") == []
    assert static_values(got[paths.stabilisation_class("new")], "order") == [2, 4]


def test_axis_ticks_are_round_and_cover_the_range():
    from fnsi_lab.viewer.figure import Axis, nice_ticks

    t = nice_ticks(4.9, 50.1)
    assert list(t) == [10, 20, 30, 40, 50]
    assert list(nice_ticks(-0.013, 0.0)) == pytest.approx([-0.0125, -0.01, -0.0075, -0.005,
                                                           -0.0025, 0.0])
    vals, labels = Axis("f (Hz)", 5.0, 250.0).ticks()
    assert labels == ["50", "100", "150", "200", "250"]
    vals, labels = Axis("MDI", 3e-7, 2e4, log=True).ticks()
    assert labels[0] == "1e-6" and labels[-1] == "1e4" and np.all(np.diff(np.log10(vals)) > 0)
    ax = Axis.fit("x", [1.0, 3.0], pad=0.0)
    assert ax.unit([1.0, 2.0, 3.0]) == pytest.approx([0.0, 0.5, 1.0])


def test_view_spawn_without_display_says_how_to_open_it(rec_path, capsys, monkeypatch):
    rec, path = rec_path
    vlog.log_summary(rec, "x")
    _finish(rec)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["view", str(path), "--spawn"]) == 0
    assert "no display" in capsys.readouterr().err


def test_lines_of_several_realizations_are_drawn_in_frequency_order(rec_path):
    """Realizations come one after the other: a curve through them would run back."""
    from fnsi_lab.viewer.frf import phase_deg

    rec, path = rec_path
    f = np.array([10.0, 20.0, 10.5, 20.5])  # realization 1, then 2
    h = np.array([1.0, 2.0, 3.0, 4.0]) + 0j
    vlog.log_frf(rec, f, measured=h, model=h)
    _finish(rec)
    got = read_rrd(path)
    assert static_values(got[paths.FRF_MODEL], "frequency_hz") == [10.0, 10.5, 20.0, 20.5]
    assert static_values(got[paths.FRF_MODEL], "re") == [1.0, 3.0, 2.0, 4.0]
    # a phase wrap breaks the line instead of drawing a vertical jump
    wrapped = phase_deg(np.exp(1j * np.radians([170.0, 179.0, -179.0, -170.0])))
    assert np.isnan(wrapped[2]) and wrapped[1] == pytest.approx(179.0)


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_view_without_a_display_serves_the_web_viewer_and_prints_its_url(rec_path):
    """`fnsi-lab view F.rrd` opens the file: on a machine without a display, the web viewer
    on localhost (a real `rerun --serve-web`), its URL printed; Ctrl-C stops it (exit 0)."""
    import os
    import signal
    import subprocess
    import sys
    import time
    import urllib.request

    rec, path = rec_path
    vlog.log_information_criterion(rec, [2, 4], [1.0, 0.5], 4)
    _finish(rec)
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    web, grpc = _free_port(), _free_port()
    proc = subprocess.Popen([sys.executable, "-m", "fnsi_lab", "view", str(path),
                             "--web-port", str(web), "--grpc-port", str(grpc)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = ""
        deadline = time.monotonic() + 60
        while "serving" not in line and time.monotonic() < deadline and proc.poll() is None:
            line = proc.stdout.readline()
        assert "serving" in line and f"http://127.0.0.1:{web}" in line, (line, proc.poll())
        url = line.split(" at ", 1)[1].split()[0]
        with urllib.request.urlopen(url, timeout=10) as page:
            assert page.status == 200
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            out, err = proc.communicate(timeout=60)  # a loaded 2-core machine
        except subprocess.TimeoutExpired:
            proc.kill()
            out, err = proc.communicate()
    assert proc.returncode == 0, err
    assert "no display: serving the web viewer" in err


def test_a_signal_group_of_many_channels_has_no_legend_over_its_curves(tmp_path):
    """39 displacement channels: no legend column over the data (issue 27); a group of a
    few keeps its legend; the view names its unit."""
    bp = blueprint(("force", "displacement"), group_sizes={"force": 1, "displacement": 39},
                   group_units={"force": "N", "displacement": "mm"})
    bp.save("fnsi-lab-test", str(tmp_path / "b.rbl"))
    reader = RrdReader(str(tmp_path / "b.rbl"))
    names, legend = {}, {}
    for chunk in reader.stream(store=reader.blueprints()[0]).collect().stream():
        batch = chunk.to_record_batch()
        path = str(chunk.entity_path)
        if "ViewBlueprint:display_name" in batch.schema.names:
            names[path] = batch.column("ViewBlueprint:display_name").to_pylist()[-1][0]
        if "PlotLegend:visible" in batch.schema.names:
            legend[path.rsplit("/", 1)[0]] = batch.column("PlotLegend:visible").to_pylist()[-1][0]
    by_name = {name: legend.get(path) for path, name in names.items()}
    assert by_name["signals: displacement (mm)"] is False
    assert by_name["signals: force (N)"] is True


def test_channels_are_coloured_by_direction_family():
    colours = vlog.direction_colours(["X", "Y", "Z", "-x", "Z", ""])
    assert colours[0] in vlog.DIRECTION_PALETTES["X"] and colours[3] in vlog.DIRECTION_PALETTES["X"]
    assert colours[1] in vlog.DIRECTION_PALETTES["Y"]
    assert colours[2] != colours[4] and colours[4] in vlog.DIRECTION_PALETTES["Z"]
    assert colours[5] in vlog.SIGNAL_PALETTE  # no direction: the plain palette


def _union_kinds(column) -> list[str]:
    """Kind of each value of a dense-union column (``Infinite``, ``CursorRelative``...)."""
    return [column.type.field(int(t)).name for t in column.type_codes.to_pylist()]


def test_one_update_reads_in_the_modes_figure_and_on_a_labelled_time_axis(rec_path, tmp_path):
    """Issue 27: with one identification update every per-update series is one point. The
    modes figure draws each mode of the update (damping against frequency, labelled with its
    number, its values attached); the per-update views span the whole recording and 5 s past
    the cursor (a time axis from 0 s with the update inside, not an axis of one tick); a
    later update with fewer modes replaces the figure."""
    rec, path = rec_path
    view = {"convergence": {"update": 1, "acq_time_s": 49.152,
                            "values": {"natural_frequency_hz": [10.67, 28.26, 28.41],
                                       "damping_ratio": [0.056, 0.11, 0.10]}}}
    vlog.log_identification(rec, view, update=1)
    _finish(rec)
    got = read_rrd(path)
    modes = got[paths.MODES_POINTS]
    assert static_values(modes, "frequency_hz") == [10.67, 28.26, 28.41]
    assert static_values(modes, "damping_ratio") == [0.056, 0.11, 0.10]
    assert column(modes, "Points2D:labels", static=True)[-1] == ["1", "2", "3"]
    xy = np.array(column(modes, "Points2D:positions", static=True)[-1])
    assert len(xy) == 3 and np.all(np.diff(xy[:, 0]) > 0)  # inside the plot, by frequency
    # the per-update series are one point each: the figure, not they, reads at one update
    assert column(got[paths.convergence_mode("natural_frequency_hz", 3)],
                  "Scalars:scalars") == [[28.41]]
    title = [t for t in column(got[f"{paths.MODES}/axes/labels"], "Points2D:labels",
                               static=True)[-1] if "modes" in t]
    assert title == ["3 modes: damping (%) vs frequency (Hz) (update 1)"]

    two = rr.RecordingStream("fnsi-lab-test", recording_id="two-updates")
    two.save(str(tmp_path / "two.rrd"))
    vlog.log_identification(two, view, update=1)
    vlog.log_identification(two, {"convergence": {
        "update": 2, "acq_time_s": 60.0, "values": {"natural_frequency_hz": [10.6],
                                                    "damping_ratio": [0.05]}}}, update=2)
    _finish(two)
    modes = read_rrd(tmp_path / "two.rrd")[paths.MODES_POINTS]
    assert static_values(modes, "frequency_hz") == [10.6]
    assert len(column(modes, "Points2D:positions", static=True)[-1]) == 1

    # the blueprint: the modes figure in the Live tab; the three per-update views carry an
    # x range from the recording's start to 5 s past the cursor
    blueprint(("force",)).save("fnsi-lab-test", str(tmp_path / "b.rbl"))
    reader = RrdReader(str(tmp_path / "b.rbl"))
    names, ranges, origins = {}, {}, {}
    for chunk in reader.stream(store=reader.blueprints()[0]).collect().stream():
        batch, entity = chunk.to_record_batch(), str(chunk.entity_path)
        if "ViewBlueprint:display_name" in batch.schema.names:
            names[entity] = batch.column("ViewBlueprint:display_name").to_pylist()[-1][0]
            origins[entity] = batch.column("ViewBlueprint:space_origin").to_pylist()[-1][0]
        if "TimeAxis:view_range" in batch.schema.names:
            r = batch.column("TimeAxis:view_range").flatten()
            ranges[entity.rsplit("/", 1)[0]] = (_union_kinds(r.field("start")),
                                                _union_kinds(r.field("end")),
                                                r.field("end").to_pylist())
    per_update = {names[v]: kinds for v, kinds in ranges.items()}
    axis = (["Infinite"], ["CursorRelative"], [5_000_000_000])   # ns past the cursor
    assert per_update == {"natural frequencies per update (Hz; hover: mode)": axis,
                          "coefficients per update (mean Re)": axis,
                          "status (hover: quantity)": axis}
    assert paths.MODES in origins.values()


def test_coefficient_panels_draw_re_and_im_with_units(rec_path):
    """Issue 27: the viewer drew Re only; the report draws Re and Im. Each coefficient has a
    Re panel (solid) over an Im panel (dashed, with the zero line of a real coefficient),
    titled with Re / Im and the unit, the Im values attached."""
    rec, path = rec_path
    f = np.linspace(5.0, 50.0, 40)
    c = 116.7 + 0.01 * np.sin(f / 7) + 1j * (0.02 - 0.003 * f)   # N/mm, Im << Re
    vlog.log_coefficients(rec, f, full={"NC2-Z:neg": c * 1.0001}, reduced={"NC2-Z:neg": c},
                          exact={"NC2-Z:neg": 116.7}, units={"NC2-Z:neg": "N/mm"}, update=1)
    _finish(rec)
    got = read_rrd(path)
    im = got[paths.coefficient_im("NC2-Z:neg", "reduced")]
    assert static_values(im, "im") == pytest.approx(c.imag)
    assert static_values(got[paths.coefficient("NC2-Z:neg", "reduced")], "re") == \
        pytest.approx(c.real)
    # dashed: many short strips along the curve (14 canvas units on, 9 off), vs one solid
    dashes = column(im, "LineStrips2D:strips", static=True)[-1]
    solid = column(got[paths.coefficient("NC2-Z:neg", "reduced")], "LineStrips2D:strips",
                   static=True)[-1]
    assert len(solid) == 1 and len(dashes) > 20
    for d in dashes:
        d = np.asarray(d)
        assert np.hypot(*np.diff(d, axis=0).T).sum() <= 14.0 + 1e-3  # float32 positions
    zero = got[paths.coefficient_im("NC2-Z:neg", "zero")]
    assert len(column(zero, "LineStrips2D:strips", static=True)[-1]) == 1
    panel = paths.coefficient_panel("NC2-Z:neg")
    re_labels = column(got[f"{panel}/axes/labels"], "Points2D:labels", static=True)[-1]
    im_labels = column(got[f"{panel}/im/axes/labels"], "Points2D:labels", static=True)[-1]
    assert "Re NC2-Z:neg (N/mm) (update 1)" in re_labels
    assert "Im NC2-Z:neg (N/mm), dashed" in im_labels
    legend = column(got[f"{panel}/im/legend"], "Points2D:labels", static=True)[-1]
    assert legend == ["Im, full model", "Im, reduced model", "0: real"]
    # the Im axis is Im's own (it includes 0), not Re's 116.7: the curve spans the panel
    ys = np.concatenate([np.asarray(s)[:, 1] for s in dashes])
    assert np.ptp(ys) > 0.5 * 300 * 4 / 2 / 2   # > half of an Im panel's height (4 rows, 2 panels)


def test_dashes_follow_the_line_with_gaps():
    line = np.array([[0.0, 0.0], [100.0, 0.0]])
    got = figure_dashes(line, on=10.0, off=5.0)
    assert len(got) == 7                       # 0-10, 15-25, ..., 90-100
    assert [d[0, 0] for d in got] == pytest.approx([0, 15, 30, 45, 60, 75, 90])
    assert all(np.ptp(d[:, 0]) == pytest.approx(10.0) for d in got)
