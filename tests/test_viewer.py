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
from fnsi_lab.viewer.cli import rrd_entities, rrd_text


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


def scalars_by_index(batches, index: str) -> list[tuple[int, list[float]]]:
    """Sorted (index value, scalars) rows of a Scalars entity."""
    rows = []
    for is_static, batch in batches:
        if is_static or index not in batch.schema.names:
            continue
        idx = batch.column(index).cast("int64").to_pylist()
        val = batch.column("Scalars:scalars").to_pylist()
        rows += list(zip(idx, val))
    return sorted(rows, key=lambda r: r[0])


@pytest.fixture
def rec_path(tmp_path):
    path = tmp_path / "run.rrd"
    rec = rr.RecordingStream("fnsi-lab-test", recording_id="test")
    rec.save(str(path), default_blueprint=blueprint(("force", "displacement"),
                                                    coefficient_names=["k_nl"]))
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


def test_identification_subtrees_hold_the_expected_values(rec_path):
    rec, path = rec_path
    vlog.log_styles(rec, coefficient_names=["k_nl"])
    f = np.array([5.0, 10.5, 20.25])
    h = np.array([1.0, 0.1j, -0.01])
    vlog.log_identification(rec, {
        "frf": {"frequency_hz": f, "measured": h, "linear": 2 * h, "model": h},
        "stabilisation": {"order": [2, 4, 4, 6, 6, 6], "frequency_hz": [10, 10, 20, 10, 20, 33],
                          "pole_class": ["new", "frequency", "new", "stable", "stable",
                                         "unstable"]},
        "criterion": {"orders": [2, 4, 6, 8], "criterion": [100.0, 1.0, 10.0, np.inf],
                      "selected_order": 4},
        "mdi": {"frequency_hz": [10.0, 20.0, 33.0], "mdi": [1e-2, 1e-4, 1e-9],
                "kept": [True, True, False], "threshold": 1e-6},
        "coefficients": {"frequency_hz": f, "full": {"k_nl": [1.1e7, 0.9e7, 1.0e7 + 5j]},
                         "reduced": {"k_nl": [1.0e7, 1.0e7, 1.0e7]}, "exact": {"k_nl": 1e7}},
        "convergence": {"update": 3, "acq_time_s": 49.152,
                        "values": {"natural_frequency_hz": [10.0, 20.0]}},
        "summary": vlog.summary_markdown("SmallSat", [("order", "4")],
                                         [{"mode": 1, "f (Hz)": 10.0}]),
    })
    _finish(rec)
    got = read_rrd(path)

    frf = scalars_by_index(got[paths.FRF_MEASURED], paths.TIME_FREQUENCY)
    assert [i for i, _ in frf] == [5000, 10500, 20250]
    assert [v[0] for _, v in frf] == pytest.approx([0.0, -20.0, -40.0])
    lin = scalars_by_index(got[paths.FRF_LINEAR], paths.TIME_FREQUENCY)
    assert lin[0][1][0] == pytest.approx(20 * np.log10(2))

    stable = scalars_by_index(got[paths.stabilisation_class("stable")], paths.TIME_ORDER)
    assert stable == [(6, [10.0]), (6, [20.0])]
    new = scalars_by_index(got[paths.stabilisation_class("new")], paths.TIME_ORDER)
    assert new == [(2, [10.0]), (4, [20.0])]
    assert column(got[paths.stabilisation_class("unstable")], "SeriesPoints:names",
                  static=True) == [["unstable (zeta < 0)"]]

    crit = scalars_by_index(got[paths.ORDER_CRITERION], paths.TIME_ORDER)
    assert crit == [(2, [2.0]), (4, [0.0]), (6, [1.0])]  # log10; the unstable inf is skipped
    assert scalars_by_index(got[paths.ORDER_SELECTED], paths.TIME_ORDER) == [(4, [0.0])]

    kept = scalars_by_index(got[paths.MDI_KEPT], paths.TIME_FREQUENCY)
    assert kept == [(10000, [pytest.approx(-2.0)]), (20000, [pytest.approx(-4.0)])]
    removed = scalars_by_index(got[paths.MDI_REMOVED], paths.TIME_FREQUENCY)
    assert removed == [(33000, [pytest.approx(-9.0)])]
    thr = scalars_by_index(got[paths.MDI_THRESHOLD], paths.TIME_FREQUENCY)
    assert [i for i, _ in thr] == [10000, 33000] and thr[0][1] == [pytest.approx(-6.0)]

    full = scalars_by_index(got[paths.coefficient("k_nl", "full")], paths.TIME_FREQUENCY)
    assert [v[0] for _, v in full] == [1.1e7, 0.9e7, 1.0e7]  # real part
    exact = scalars_by_index(got[paths.coefficient("k_nl", "exact")], paths.TIME_FREQUENCY)
    assert exact == [(5000, [1e7]), (20250, [1e7])]

    conv = got[paths.convergence("natural_frequency_hz")]
    assert column(conv, "Scalars:scalars") == [[10.0, 20.0]]
    assert column(conv, paths.TIME_UPDATE) == [3]

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
    for p in (paths.STABILISATION, paths.ORDER, paths.FRF, paths.MDI,
              paths.CONVERGENCE_FREQUENCIES, paths.CONVERGENCE_COEFFICIENTS,
              paths.signal_group("force"), f"{paths.COEFFICIENTS}/k_nl"):
        assert p in origins


def test_view_command_lists_entities_and_prints_the_summary(rec_path, capsys):
    rec, path = rec_path
    vlog.log_summary(rec, vlog.summary_markdown("Result", [("selected order", "26")]))
    vlog.log_information_criterion(rec, [2, 4], [1.0, 0.5], 4)
    _finish(rec)
    assert set(rrd_entities(path)) >= {paths.SUMMARY, paths.ORDER_CRITERION}
    assert main(["view", str(path)]) == 0
    out = capsys.readouterr().out
    assert paths.ORDER_CRITERION in out and "| selected order | 26 |" in out
    assert main(["view", str(path.parent / "nope.rrd")]) == 2


@pytest.mark.parametrize("command", ["view", "replay", "live"])
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


def test_empty_inputs_log_nothing_and_do_not_fail(rec_path):
    rec, path = rec_path
    vlog.log_frf(rec, [], measured=[])
    vlog.log_stabilisation(rec, [], [], [])
    vlog.log_mdi(rec, [], [], [], None)
    vlog.log_information_criterion(rec, [], [], None)
    vlog.log_coefficients(rec, [], {"k": []}, None, {"k": 1.0})
    vlog.log_convergence(rec, 1, 0.0, {"natural_frequency_hz": []})
    _finish(rec)
    got = read_rrd(path)
    assert paths.FRF_MEASURED not in got and paths.convergence("natural_frequency_hz") not in got


def test_updates_get_their_own_entities_and_the_previous_one_is_hidden(rec_path):
    """Rerun averages values sharing an x within one series: updates must not share one."""
    rec, path = rec_path
    f = np.array([10.0, 20.0])
    for k, gain in ((1, 1.0), (2, 10.0)):
        vlog.log_identification(rec, {
            "frf": {"frequency_hz": f, "measured": gain * np.ones(2)},
            "mdi": {"frequency_hz": f, "mdi": [1.0, 1e-6], "kept": [True, k == 1],
                    "threshold": 1e-3},
            "stabilisation": {"order": [2, 4], "frequency_hz": [10.0, 10.0],
                              "pole_class": ["new", "stable"] if k == 1 else ["new", "new"]},
        }, update=k)
    _finish(rec)
    got = read_rrd(path)
    one, two = (paths.versioned(paths.FRF_MEASURED, k) for k in (1, 2))
    assert scalars_by_index(got[one], paths.TIME_FREQUENCY) == [(10000, [0.0]), (20000, [0.0])]
    assert scalars_by_index(got[two], paths.TIME_FREQUENCY) == [(10000, [20.0]), (20000, [20.0])]
    assert column(got[one], "SeriesLines:visible_series", static=True) == [[False]]
    assert column(got[two], "SeriesLines:visible_series", static=True) == []
    # a class present in update 1 only is hidden by update 2
    stable1 = paths.versioned(paths.stabilisation_class("stable"), 1)
    assert column(got[stable1], "SeriesPoints:visible_series", static=True) == [[False]]
    assert paths.versioned(paths.stabilisation_class("stable"), 2) not in got
    removed2 = got[paths.versioned(paths.MDI_REMOVED, 2)]
    assert scalars_by_index(removed2, paths.TIME_FREQUENCY) == [(20000, [pytest.approx(-6.0)])]


def test_view_spawn_without_display_says_how_to_open_it(rec_path, capsys, monkeypatch):
    rec, path = rec_path
    vlog.log_summary(rec, "x")
    _finish(rec)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["view", str(path), "--spawn"]) == 0
    assert "no display" in capsys.readouterr().err
