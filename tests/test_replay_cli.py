"""``fnsi-lab replay`` and ``fnsi-lab live`` end to end, the .rrd read back with rerun's reader."""

from __future__ import annotations

import numpy as np
import pytest
from rerun.chunk import RrdReader

from fnsi_lab.cli import main
from fnsi_lab.ident.robust.options import parse_orders
from fnsi_lab.viewer import paths
from fnsi_lab.viewer.cli import rrd_entities, rrd_text


def _values(path, entity: str, name: str) -> list:
    """Physical values of a figure series (static ``AnyValues`` column; the last logged)."""
    out = []
    for chunk in RrdReader(str(path)).stream().collect().stream():
        if chunk.entity_path == entity and chunk.is_static:
            batch = chunk.to_record_batch()
            if name in batch.schema.names:
                out = batch.column(name).to_pylist()[-1]
    return out


def _scalars(path, entity: str) -> list[list[float]]:
    out = []
    for chunk in RrdReader(str(path)).stream().collect().stream():
        if (chunk.entity_path == entity or chunk.entity_path.startswith(entity + "/")) \
                and not chunk.is_static:
            out += chunk.to_record_batch().column("Scalars:scalars").to_pylist()
    return out


def test_replay_to_rrd_holds_poles_mdi_and_criterion(tmp_path, capsys):
    from test_service import record, two_dof

    path = record(tmp_path / "chain.mcap", *two_dof(4))
    rrd = tmp_path / "chain.rrd"
    assert main(["replay", str(path), "--orders", "2:6", "--rrd", str(rrd), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "selected order (IC)" in out and "service:" in out and str(rrd) in out
    entities = rrd_entities(rrd)
    for e in (paths.ORDER_CRITERION, paths.ORDER_SELECTED, paths.MDI_KEPT, paths.FRF_MEASURED,
              paths.FRF_LINEAR, paths.FRF_MODEL, paths.stabilisation_class("stable"),
              paths.convergence_mode("natural_frequency_hz", 1), paths.signal_group("force"),
              paths.signal_group("displacement"), paths.SUMMARY, paths.STATUS_LOG):
        assert e in entities, e
    # the identified first mode of the chain (9.836 Hz) is among the logged poles
    freqs = np.concatenate([np.asarray(v, float) for v in
                            _scalars(rrd, paths.convergence("natural_frequency_hz"))])
    assert np.min(np.abs(freqs - 9.836)) < 0.01
    # MDI of the kept poles and the threshold are there, finite
    kept = _values(rrd, paths.MDI_KEPT, "mdi")
    thr = _values(rrd, paths.MDI_THRESHOLD, "threshold")
    assert kept and thr and np.all(np.isfinite(kept + thr))
    # the highest-MDI pole is kept
    removed = _values(rrd, paths.MDI_REMOVED, "mdi")
    assert max(kept) > max(removed, default=-np.inf)
    # every sample reached the viewer (4 periods of 512 samples)
    assert sum(1 for _ in _scalars(rrd, paths.signal_group("force"))) == 4 * 512
    assert "selected order (IC)" in rrd_text(rrd, paths.SUMMARY)


def test_spawn_without_display_falls_back_to_saving(tmp_path, capsys, monkeypatch):
    from test_service import record, two_dof

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    path = record(tmp_path / "chain.mcap", *two_dof(3))
    assert main(["replay", str(path), "--method", "frf", "--spawn", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "no display" in err
    assert (tmp_path / "chain.rrd").is_file()
    assert paths.FRF_MEASURED in rrd_entities(tmp_path / "chain.rrd")


def test_live_runs_the_lumped_experiment_end_to_end(tmp_path, capsys):
    """Simulated 3-DOF chain with a cubic spring (k = 1e9 N/m^3): acquire -> MCAP -> ident -> rrd."""
    pytest.importorskip("fnsi_lab.daq.sim.source", reason="fnsi_lab.daq.sim.source (simulated sources) missing")
    mcap, rrd = tmp_path / "live.mcap", tmp_path / "live.rrd"
    assert main(["live", "--config", "lumped.yaml", "--fast", "--orders", "2:10",
                 "--out", str(mcap), "--rrd", str(rrd), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "recorded" in out and "0 blocks dropped" in out and "0 failures" in out
    from fnsi_lab.daq.recording.reader import read_periodic

    rec = read_periodic(mcap)
    assert rec.n_realizations == 2 and rec.n_periods == 4  # recording complete
    entities = set(rrd_entities(rrd))
    name = "X2-X3-cubic"
    assert {paths.FRF_MEASURED, paths.signal_group("force"), paths.MDI_KEPT,
            paths.coefficient(name, "full"), paths.coefficient(name, "exact")} <= entities
    # the coefficient over the excited band is within 0.5 % of the truth, logged exactly
    assert _values(rrd, paths.coefficient(name, "exact"), "exact") == [1e9]
    full = np.array(_values(rrd, paths.coefficient(name, "full"), "re"))
    assert abs(np.median(full) / 1e9 - 1) < 5e-3
    # the summary table reports the error against the truth
    assert "error" in rrd_text(rrd, paths.SUMMARY)
    # the three modes of the chain are kept (log10 MDI of kept poles)
    kept = _values(rrd, paths.MDI_KEPT, "mdi")
    assert len(kept) >= 3


def test_bad_options_give_one_line_errors(tmp_path, capsys):
    assert main(["replay", str(tmp_path / "missing.mcap"), "--quiet"]) == 2
    assert "no such recording" in capsys.readouterr().err
    assert parse_orders("2:5") == [2, 3, 4, 5] and parse_orders("4,8") == [4, 8]
    with pytest.raises(Exception, match="orders 'x'"):
        parse_orders("x")


def test_replay_follow_picks_up_a_file_being_written(tmp_path, capsys):
    """`fnsi-lab replay --follow` while a writer thread appends flushed blocks."""
    import threading
    import time

    from fnsi_lab.daq.recording import Recorder
    from fnsi_lab.daq.sources.array_source import ArraySource
    from test_service import CHANNELS, FS, two_dof

    data, meta = two_dof(4)
    path = tmp_path / "growing.mcap"
    rec = Recorder(path, CHANNELS, FS, metadata=meta)

    def writer() -> None:
        for i, b in enumerate(ArraySource(data, CHANNELS, FS, block_size=128)):
            rec.write_block(b)
            if i % 4 == 3:
                rec.flush()
                time.sleep(0.02)
        rec.close()

    thread = threading.Thread(target=writer)
    thread.start()
    try:
        assert main(["replay", str(path), "--follow", "--follow-timeout", "5", "--method",
                     "frf", "--quiet", "--rrd", str(tmp_path / "g.rrd")]) == 0
    finally:
        thread.join()
    out = capsys.readouterr().out
    assert "4 periods (3 steady)" in out
    assert "0 samples lost" in out



def test_replay_honours_the_auto_section_of_the_ident_file(tmp_path, capsys):
    """``fnsi-lab replay REC --ident X.yaml``: the file's ``auto:`` section (order sweep and
    top_n) reaches the robust pipeline, as it does for ``fnsi-lab ident`` (issue 10: it was
    silently ignored); ``--orders`` on the command line still wins over ``auto.orders``."""
    pytest.importorskip("fnsi_lab.daq.sim.source", reason="fnsi_lab.daq.sim.source (simulated sources) missing")
    rec = tmp_path / "lumped.mcap"
    assert main(["acquire", "--config", "lumped.yaml", "--out", str(rec), "--quiet",
                 "--no-info"]) == 0
    capsys.readouterr()
    base = ("band_hz: [3, 150]\n"
            "inputs:\n  - {name: F-X3, driving_point: X3}\n"
            "nonlinearities:\n"
            "  - {name: knl, kind: polynomial, exponent: 3, channels: {X2: 1, X3: -1}}\n")
    plain, with_auto = tmp_path / "plain.yaml", tmp_path / "auto.yaml"
    plain.write_text(base)
    with_auto.write_text(base + 'auto: {orders: "2:8", top_n: 1}\n')

    def replay(cfg, *extra):
        assert main(["replay", str(rec), "--ident", str(cfg), "--rrd",
                     str(tmp_path / (cfg.stem + ".rrd")), "--force", *extra]) == 0
        io = capsys.readouterr()
        text = io.out + io.err
        selected = int(text.split("selected order (IC)")[1].split()[0])
        physical = int(text.split("physical modes")[1].split()[0])
        return text, selected, physical

    text, selected, physical = replay(plain)
    assert "orders 2-60" in text            # the one default sweep (ident.request)
    assert physical >= 2                     # the chain has three modes
    assert selected > 8
    text, selected, physical = replay(with_auto)
    assert "orders 2-8" in text and "orders 2-60" not in text
    assert selected <= 8
    assert physical == 1                     # top_n: 1
    text, selected, physical = replay(with_auto, "--orders", "2:6")
    assert "orders 2-6" in text and selected <= 6 and physical == 1

@pytest.mark.slow
def test_run_is_the_readme_main_job_on_the_default_smallsat(tmp_path, capsys):
    """``fnsi-lab run`` (the README's first command): simulated SmallSat -> MCAP -> robust
    identification -> .rrd + the Table-2 summary."""
    pytest.importorskip("fnsi_lab.daq.sim.source", reason="fnsi_lab.daq.sim.source (simulated sources) missing")
    mcap, rrd = tmp_path / "smallsat.mcap", tmp_path / "smallsat.rrd"
    assert main(["run", "--out", str(mcap), "--rrd", str(rrd), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "0 blocks dropped" in out and "0 failures" in out
    from fnsi_lab.daq.recording.reader import read_periodic

    rec = read_periodic(mcap)      # the paper's record: 6 periods of 8192 samples, 39 outputs
    assert rec.y.shape[1:] == (6, 8192, 39) and rec.u.shape[-1] == 1
    # the summary names both NC2-Z stops with their error against the truth; the paper's
    # worst Table-2 error is 0.76 %, ours is ~0.1-0.2 % (bench/RESULTS.md): 1 % bounds it
    rows = [ln for ln in out.splitlines() if ln.startswith("NC2-Z:") and " model " in ln]
    assert len(rows) >= 2
    # and how far the answer's values can be trusted (issue 29): both stops identified
    verdicts = [ln.split()[-1] for ln in out.splitlines()
                if ln.startswith("NC2-Z:") and ", verdict" in ln]
    assert verdicts == ["identified", "identified"], verdicts
    for ln in rows:
        err = float(ln.split("error")[1].split("%")[0])
        assert abs(err) < 1.0, ln
    # the modes of Table 1 with the largest response (11.01, 28.41, 32.62 Hz) are listed
    # and classified physical (0.5 %: the tolerance)
    # (the table's last column is each pole's fate, ident.robust.pole_fate's words)
    table = [ln.split() for ln in out.splitlines()
             if ln.strip()[:1].isdigit() and ln.strip().endswith(("physical", "MDI"))]
    phys = [float(t[0]) for t in table if t[-1] == "physical"]
    for f in (11.01, 28.41, 32.62):
        assert min(abs(p - f) / f for p in phys) < 5e-3, (f, phys)
    entities = set(rrd_entities(rrd))
    assert {paths.coefficient("NC2-Z:neg", "full"), paths.MDI_KEPT, paths.ORDER_CRITERION} <= entities
