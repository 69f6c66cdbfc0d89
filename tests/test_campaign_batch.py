"""``fnsi-lab batch`` on real Dask clusters: local processes, and a started scheduler + workers.

The inputs are real recordings of the simulated 3-DOF chain with a two-sided stop, made by
``fnsi-lab acquire`` with a level sweep (``excitation.levels``), plus one corrupted copy.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from fnsi_lab.campaign.batch import (contact_by_coefficient, expand_inputs, make_spec,
                                     plan_inputs)
from fnsi_lab.campaign.table import read_table, write_table
from fnsi_lab.cli import main
from fnsi_lab.errors import ConfigError, DataFileError

pytest.importorskip("distributed")

SWEEP = """\
name: stop
sample_rate_hz: 1000
source:
  kind: simulated
  options: {model: lumped, lumped: {variant: trilinear}, verify: false, snr_db: 60}
excitation:
  band_hz: [3, 150]
  levels: [5, 10]
  samples_per_period: 2048
  periods: 4
  transient_periods: 1
"""
CONFIG = "lumped-stop"
ORDERS = "2:12"  # the chain has 3 modes: order 6 plus room for spurious poles
IGNORED = {"timings_s", "campaign"}  # wall-clock times differ from run to run


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    """Two good recordings (5 N and 10 N RMS) and a corrupted copy of the first."""
    root = tmp_path_factory.mktemp("campaign")
    (root / "sweep.yaml").write_text(SWEEP)
    assert main(["acquire", "--config", str(root / "sweep.yaml"), "--out", str(root / "runs"),
                 "--quiet"]) == 0
    good = sorted((root / "runs").glob("*.mcap"))
    data = bytearray(good[0].read_bytes())
    middle = len(data) // 2
    data[middle:middle + 4096] = bytes(4096)  # a zeroed stretch inside the data chunks
    bad = root / "runs" / "stop-corrupted.mcap"
    bad.write_bytes(bytes(data))
    return root, good, bad


def _ident_json(path: Path, out: Path) -> dict:
    """One-by-one reference: ``fnsi-lab ident --auto --json``."""
    assert main(["ident", str(path), "--config", CONFIG, "--auto", "--orders", ORDERS,
                 "--json", str(out), "--quiet", "--force"]) == 0
    return json.loads(out.read_text())


def _batch(root: Path, out: Path, *extra: str) -> int:
    return main(["batch", str(root / "runs" / "*.mcap"), "--config", CONFIG, "--auto",
                 "--orders", ORDERS, "--out", str(out), "--quiet", *extra])


def _rows(out: Path) -> dict[str, dict]:
    rows, _ = read_table(out)
    return {Path(r["file"]).name: r for r in rows}


def test_local_cluster_matches_ident_and_survives_a_corrupted_input(recordings, tmp_path, capsys):
    root, good, bad = recordings
    out = tmp_path / "campaign.parquet"
    assert _batch(root, out, "--workers", "2") == 1  # one input failed
    assert "failed: " in capsys.readouterr().err
    rows = _rows(out)
    assert set(rows) == {p.name for p in good} | {bad.name}
    assert rows[bad.name]["status"] == "error" and rows[bad.name]["error"]
    assert "\n" not in rows[bad.name]["error"]
    for p in good:
        row = rows[p.name]
        assert row["status"] == "ok" and row["error"] is None
        assert row["worker"].startswith("tcp://")  # ran on a Dask worker process
        # identical, to the last bit, to identifying the file alone with fnsi-lab ident
        ref = _ident_json(p, tmp_path / f"{p.stem}-ident.json")
        mine = json.loads(Path(row["result"]).read_text())
        assert {k: v for k, v in mine.items() if k not in IGNORED} == \
               {k: v for k, v in ref.items() if k not in IGNORED}
        assert row["order"] == ref["order"] and row["n_modes"] == len(ref["modes"])
        for c in ref["coefficients"]:
            assert row[c["name"]] == c["mean_real"]
            assert row[f"{c['name']}:std"] == c["std_real"]
        # the level and the contact statistics come from the recording
        assert row["force_rms"] == float(p.stem.split("rms")[1])
        assert 0 < row["stop:neg:contact"] < 1 and 0 < row["stop:pos:contact"] < 1
    # physics: the stop is stiffer than nothing and the two runs agree within their spreads
    a, b = (rows[p.name] for p in good)
    for name in ("stop:neg", "stop:pos"):
        assert abs(a[name] - b[name]) < 3 * (a[f"{name}:std"] + b[f"{name}:std"])

    # resumed: nothing new, the good inputs are skipped, the corrupted one is tried again
    stamps = {p.name: Path(rows[p.name]["result"]).stat().st_mtime_ns for p in good}
    assert _batch(root, out, "--workers", "2") == 1
    again = _rows(out)
    assert [again[p.name]["status"] for p in good] == ["skipped", "skipped"]
    assert again[bad.name]["status"] == "error"
    for p in good:
        assert Path(again[p.name]["result"]).stat().st_mtime_ns == stamps[p.name]
        assert {k: v for k, v in again[p.name].items() if k != "status"} == \
               {k: v for k, v in rows[p.name].items() if k != "status"}
    # only the corrupted input was identified again: the good results are untouched (their
    # files' times above). Not timed here: both runs are dominated by the cluster's start,
    # and once writing results got faster the two times came within 4 % of each other
    # (resume speed is measured by bench/campaign.py: 2 % of the first run).

    # the table deleted: the results themselves are recognised (same content and config)
    out.unlink()
    assert _batch(root, out, "--scheduler", "serial") == 1
    assert [_rows(out)[p.name]["status"] for p in good] == ["skipped", "skipped"]
    # another order sweep is another campaign: everything runs again
    assert main(["batch", str(good[0]), "--config", CONFIG, "--auto", "--orders", "2:10",
                 "--out", str(out), "--quiet", "--scheduler", "serial"]) == 0
    assert _rows(out)[good[0].name]["status"] == "ok"


def test_nothing_new_needs_no_cluster_and_is_fast(recordings, tmp_path):
    root, good, _ = recordings
    out = tmp_path / "c.parquet"
    t0 = time.perf_counter()
    assert main(["batch", *map(str, good), "--config", CONFIG, "--auto", "--orders", ORDERS,
                 "--out", str(out), "--quiet", "--scheduler", "serial"]) == 0
    first_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    # an unreachable scheduler is never contacted when every input is done
    assert main(["batch", *map(str, good), "--config", CONFIG, "--auto", "--orders", ORDERS,
                 "--out", str(out), "--quiet", "--scheduler", "tcp://127.0.0.1:9"]) == 0
    resumed_s = time.perf_counter() - t0
    assert {r["status"] for r in _rows(out).values()} == {"skipped"}
    assert resumed_s < 0.5 * first_s


def test_running_scheduler_and_two_workers(recordings, tmp_path):
    from distributed import Client

    root, good, bad = recordings
    scheduler_file = tmp_path / "scheduler.json"
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    dask = [sys.executable, "-m", "dask"]
    procs = [subprocess.Popen(dask + ["scheduler", "--host", "127.0.0.1", "--port", "0",
                                      "--no-dashboard", "--scheduler-file", str(scheduler_file)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)]
    try:
        deadline = time.monotonic() + 60
        while not scheduler_file.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        address = json.loads(scheduler_file.read_text())["address"]
        for i in range(2):
            procs.append(subprocess.Popen(
                dask + ["worker", address, "--nthreads", "1", "--nworkers", "1",
                        "--no-dashboard", "--name", f"test-worker-{i}"],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env))
        out = tmp_path / "remote.parquet"
        status = main(["batch", str(root / "runs"), "--config", CONFIG, "--auto", "--orders",
                       ORDERS, "--out", str(out), "--results", str(tmp_path / "results"),
                       "--quiet", "--scheduler", address, "--workers", "2"])
        assert status == 1
        with Client(address, timeout="30s") as client:
            workers = set(client.scheduler_info()["workers"])
        assert len(workers) == 2
        rows = _rows(out)
        assert rows[bad.name]["status"] == "error"
        for p in good:
            assert rows[p.name]["status"] == "ok" and rows[p.name]["worker"] in workers
            assert Path(rows[p.name]["result"]).parent == tmp_path / "results"
    finally:
        for proc in reversed(procs):
            proc.terminate()
        for proc in procs:
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()


def test_unreachable_scheduler_is_one_line_usage_error(recordings, tmp_path, capsys):
    # nothing listens on port 9: refused at once. Dask's client retried it for its whole
    # 30 s timeout before saying so; 10 s leaves the machine's load a wide margin.
    import time

    root, good, _ = recordings
    t0 = time.perf_counter()
    status = main(["batch", str(good[0]), "--config", CONFIG, "--order", "6",
                   "--out", str(tmp_path / "c.parquet"), "--quiet",
                   "--scheduler", "tcp://127.0.0.1:9"])
    err = capsys.readouterr().err
    assert status == 2 and "cannot connect" in err and "fix:" in err
    assert len(err.strip().splitlines()) == 1
    assert time.perf_counter() - t0 < 10.0


def test_inputs_config_and_outputs_are_checked_first(recordings, tmp_path, capsys):
    root, good, _ = recordings
    with pytest.raises(DataFileError, match="no file matches"):
        expand_inputs([str(root / "runs" / "*.npz")])
    with pytest.raises(DataFileError, match="no such file"):
        expand_inputs([str(root / "missing.mcap")])
    # folder + glob + file naming the same recordings: each input once
    assert expand_inputs([str(root / "runs"), str(good[0])]) == sorted((root / "runs").glob("*.mcap"))
    with pytest.raises(ConfigError, match="band_hz"):
        make_spec(str(root / "sweep.yaml"))  # an experiment, not an ident config
    from fnsi_lab.ident.config import packaged_config

    no_order = tmp_path / "no-order.yaml"
    no_order.write_text("".join(line for line in packaged_config(CONFIG).read_text()
                                .splitlines(keepends=True) if not line.startswith("order:")))
    with pytest.raises(ConfigError, match="no model order"):
        make_spec(str(no_order))
    assert make_spec(str(no_order), auto=True).auto
    # the order choice is part of the config hash
    assert make_spec(CONFIG, order=6).config_sha256 != make_spec(CONFIG, order=7).config_sha256
    assert make_spec(CONFIG, auto=True).config_sha256 != make_spec(CONFIG, order=6).config_sha256
    with pytest.raises(SystemExit) as refused:  # argparse: the option's one rule
        main(["batch", str(good[0]), "--config", CONFIG, "--order", "6", "--out",
              str(tmp_path / "w.parquet"), "--workers", "0"])
    assert refused.value.code == 2 and "--workers" in capsys.readouterr().err
    # a foreign file under --out is refused before any work
    foreign = tmp_path / "mine.parquet"
    foreign.write_text("not a campaign")
    assert main(["batch", str(good[0]), "--config", CONFIG, "--order", "6", "--out",
                 str(foreign), "--quiet", "--scheduler", "serial"]) == 2
    assert "--force" in capsys.readouterr().err and foreign.read_text() == "not a campaign"


def test_same_stem_in_two_folders_gets_two_results(recordings, tmp_path):
    _, good, _ = recordings
    for sub in ("a", "b"):
        (tmp_path / sub).mkdir()
    shutil.copy(good[0], tmp_path / "a" / "run.mcap")
    shutil.copy(good[1], tmp_path / "b" / "run.mcap")
    planned = plan_inputs([tmp_path / "a" / "run.mcap", tmp_path / "b" / "run.mcap"], tmp_path)
    assert len({p.result_path for p in planned}) == 2


def test_table_round_trip_keeps_types_and_relative_results(tmp_path):
    rows = [{"file": "a.mcap", "status": "ok", "error": None, "worker": "w", "order": 6,
             "n_modes": 3, "force_rms": 5.0, "wall_time_s": 1.0, "input_sha256": "x",
             "result": str(tmp_path / "res" / "a.json"), "k": 2.0, "k:std": 0.1},
            {"file": "b.mcap", "status": "error", "error": "bad", "worker": "w",
             "input_sha256": "y", "result": None}]
    write_table(rows, tmp_path / "t.parquet", {"config": "c"})
    schema = pq.read_schema(tmp_path / "t.parquet")
    assert str(schema.field("order").type) == "int64" and str(schema.field("k").type) == "double"
    assert "k:contact" not in schema.names  # no recording carried it
    stored = pq.read_table(tmp_path / "t.parquet").column("result").to_pylist()
    assert stored == [os.path.join("res", "a.json"), None]
    back, settings = read_table(tmp_path / "t.parquet")
    assert settings == {"config": "c"} and back[0]["result"] == rows[0]["result"]
    assert back[1]["k"] is None and back[1]["order"] is None


def test_contact_fraction_follows_the_element_not_its_name():
    truth = [{"name": "X2-X3-stop", "channels": {"X2": 1.0, "X3": -1.0}},
             {"name": "gap", "channels": {"X1": 1.0}}]
    contact = {"X2-X3-stop.neg": 0.2, "X2-X3-stop.pos": 0.1, "gap.pos": 0.05}
    identified = [{"name": "stop", "channels": {"X2": -2.0, "X3": 2.0},
                   "coefficients": ["stop:neg", "stop:pos"]},
                  {"name": "gap", "channels": {"X1": 1.0}, "coefficients": ["gap"]},
                  {"name": "other", "channels": {"X1": 1.0, "X2": 1.0},
                   "coefficients": ["other"]}]
    assert contact_by_coefficient(identified, truth, contact) == {
        "stop:neg": 0.2, "stop:pos": 0.1, "gap": 0.05}


def test_campaign_command_compares_levels_into_rrd_and_json(recordings, tmp_path, capsys):
    from fnsi_lab.viewer.cli import rrd_entities

    root, good, bad = recordings
    out = tmp_path / "c.parquet"
    assert _batch(root, out, "--scheduler", "serial", "--results", str(tmp_path / "res")) == 1
    capsys.readouterr()
    rrd, js, page = tmp_path / "campaign.rrd", tmp_path / "comparison.json", tmp_path / "c.html"
    assert main(["campaign", str(out), "--rrd", str(rrd), "--json", str(js),
                 "--html", str(page)]) == 0
    text = capsys.readouterr().out
    assert "force level(s) (5, 10)" in text and "identification failed" in text
    comparison = json.loads(js.read_text())
    assert comparison["levels"] == [5.0, 10.0]
    assert comparison["frf"]["output"] == "X3"  # the driving point of the config's input
    # one structure: the underlying linear FRFs of both levels coincide (60 dB SNR data)
    assert all(r["deviation"] < 0.02 for r in comparison["frf"]["runs"])
    # the stop is in contact at both levels: both coefficients identifiable
    for values in comparison["coefficients"].values():
        assert [v["not_identifiable"] for v in values] == [None, None]
    # three modes of the chain tracked over both levels, shifting by less than 0.5 %
    assert len(comparison["modes"]) == 3
    for mode in comparison["modes"]:
        f = [v["mean"] for v in mode["frequency_hz"]]
        assert len(f) == 2 and abs(f[1] - f[0]) < 0.005 * f[0]
    entities = rrd_entities(rrd)
    for name in ("/campaign/coefficients/stop_neg/mean", "/campaign/coefficients/stop_pos/runs",
                 "/campaign/frequencies/frequency/mode_3/mean", "/campaign/summary"):
        assert name in entities
    assert sum(e.startswith("/campaign/frf/F-X3/run_") for e in entities) == 2
    text = page.read_text()
    assert text.count("<svg") == 3 and "identification failed" in text
    assert "stop-corrupted.mcap" in text and "stop-rms10.mcap" in text
    # outputs are not overwritten without --force
    assert main(["campaign", str(out), "--rrd", str(rrd)]) == 2


def test_the_table_names_the_unit_of_every_coefficient_and_level(recordings, tmp_path):
    """The written Parquet, read with pyarrow: a unit column per coefficient (the JSON
    result's ``coefficients[].unit``), the level's unit, the units in the field metadata."""
    root, good, _ = recordings
    out = tmp_path / "units.parquet"
    assert main(["batch", str(good[0]), "--config", CONFIG, "--auto", "--orders", ORDERS,
                 "--out", str(out), "--quiet", "--scheduler", "serial"]) == 0
    table = pq.read_table(out)
    row = table.to_pylist()[0]
    result = json.loads((tmp_path / row["result"]).read_text())
    # the recording is in N and m (SWEEP's lumped chain): a stop's stiffness is N/m
    assert result["units"]["force"] == "N"
    assert row["force_unit"] == "N" and row["force_rms"] == float(good[0].stem.split("rms")[1])
    assert table.schema.field("force_rms").metadata == {b"unit": b"N"}
    assert table.schema.field("wall_time_s").metadata == {b"unit": b"s"}
    names = [c["name"] for c in result["coefficients"]]
    assert names == ["stop:neg", "stop:pos"]
    for c in result["coefficients"]:
        assert c["unit"] == "N/m" and row[f"{c['name']}:unit"] == c["unit"]
        assert str(table.schema.field(f"{c['name']}:unit").type) == "string"
        for col in (c["name"], f"{c['name']}:std"):
            assert table.schema.field(col).metadata == {b"unit": b"N/m"}
        assert table.schema.field(f"{c['name']}:contact").metadata == {b"unit": b"1"}
    # the documented columns keep their names and types; units are extra columns
    for col in ("file", "status", "order", "n_modes", "force_rms", "stop:neg", "stop:neg:std"):
        assert col in table.schema.names
    rows, _ = read_table(out)   # the reader's coefficient list is unchanged by the new columns
    from fnsi_lab.campaign.table import coefficient_names
    assert coefficient_names(rows) == ["stop:neg", "stop:pos"]
