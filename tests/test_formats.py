"""Lab file formats (issue 17): import TDMS / UFF 58 / CSV, export UFF 55 / 58 and CSV.

Files are written and read back with the libraries themselves (npTDMS, pyuff): a simulated
nonlinear test (3-DOF chain with a cubic spring, 0.1 % sensor noise, float32 samples as a
DAQ delivers them)
is stored as .npz, TDMS, UFF 58 and CSV; each is imported and identified, and every
identification must be identical to the .npz one. The .npz result is exported and read
back with pyuff.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math

import numpy as np
import pytest

from fnsi_lab.cli import main

nptdms = pytest.importorskip("nptdms")
pyuff = pytest.importorskip("pyuff")

FS_HZ, N, PERIODS = 512.0, 2048, 4
#: Cubic spring of daq.sim.lumped ('cubic'), N/m^3.
K3_TRUE = 1.0e9


def _config(transient_periods: int | None) -> dict:
    cfg = {"band_hz": [3, 150], "output_quantity": "displacement",
           "inputs": [{"name": "F-X3", "driving_point": "X3"}],
           "nonlinearities": [{"name": "knl", "kind": "polynomial", "exponent": 3,
                               "channels": {"X2": 1, "X3": -1}}]}
    if transient_periods is not None:
        cfg["transient_periods"] = transient_periods
    return cfg


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """The simulated test as float32 arrays, and the same data in every lab format."""
    sim = pytest.importorskip("fnsi_lab.daq.sim")
    from fnsi_lab.daq.multisine import multisine

    model = sim.lumped_model("cubic")
    ms = multisine(N, FS_HZ, (5, 60), 20.0, n_periods=PERIODS, seed=1)
    u = np.asarray(ms.signal, np.float32).reshape(-1, 1)
    y = sim.simulate(model, u.astype(float), FS_HZ, periodic=N).get("displacement")
    # sensor noise 0.1 % of each channel's RMS (the noise weighting then means something)
    rng = np.random.default_rng(7)
    y = (y + 1e-3 * y.std(axis=0) * rng.standard_normal(y.shape)).astype(np.float32)
    names_out = list(model.measured_names)          # X1, X2, X3 (m)
    names_in = list(model.input_names)              # F-X3 (N)
    d = tmp_path_factory.mktemp("lab")
    files = {"npz": d / "run.npz", "tdms": d / "run.tdms", "uff": d / "run.uff",
             "csv": d / "run.csv"}
    np.savez(files["npz"], u=u, y=y, fs=FS_HZ, N=N, channels=np.array(names_out),
             input_channels=np.array(names_in))
    columns = [(names_in[0], "N", u[:, 0])] + [(n, "m", y[:, j]) for j, n in enumerate(names_out)]
    # TDMS as LabVIEW writes it: waveform channels with unit_string and wf_increment, the
    # multisine period as a file property.
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter
    with TdmsWriter(str(files["tdms"])) as w:
        w.write_segment([RootObject({"samples_per_period": N}), GroupObject("Measured Data")]
                        + [ChannelObject("Measured Data", n, x, properties={
                            "unit_string": unit, "wf_increment": 1.0 / FS_HZ,
                            "wf_start_offset": 0.0}) for n, unit, x in columns])
    # UFF 58 time records (function type 1), one per channel; force = data type 13.
    sets = [pyuff.prepare_58(func_type=1, id1=n, rsp_node=k + 1, rsp_dir=1, ref_node=0,
                             ref_dir=0, data=x.astype(float), x=np.arange(x.size) / FS_HZ,
                             abscissa_spacing=1, abscissa_spec_data_type=17,
                             ordinate_spec_data_type=13 if unit == "N" else 8,
                             ordinate_axis_units_lab=unit, orddenom_spec_data_type=0,
                             z_axis_spec_data_type=0)
            for k, (n, unit, x) in enumerate(columns)]
    pyuff.UFF(str(files["uff"])).write_sets(sets, mode="overwrite")
    # CSV: time column, 'name [unit]' header, float32 values in shortest round-trip text.
    with open(files["csv"], "w", newline="") as fh:
        wr = csv.writer(fh)
        wr.writerow(["time [s]"] + [f"{n} [{unit}]" for n, unit, _ in columns])
        for i in range(u.shape[0]):
            wr.writerow([repr(i / FS_HZ)] + [repr(float(x[i])) for _, _, x in columns])
    return {"u": u, "y": y, "files": files, "names_out": names_out, "names_in": names_in,
            "dir": d}


@pytest.fixture(scope="module")
def imported(lab):
    """Each lab file imported with the CLI (N from the file for TDMS, from the option else)."""
    recs = {}
    for kind in ("tdms", "uff", "csv"):
        out = lab["dir"] / f"{kind}.mcap"
        args = ["import", str(lab["files"][kind]), "--out", str(out), "--inputs", "F-X3",
                "--transient-periods", "1", "--quiet"]
        if kind != "tdms":
            args += ["--samples-per-period", str(N)]
        assert main(args) == 0
        recs[kind] = out
    return recs


@pytest.fixture(scope="module")
def identified(lab, imported):
    import fnsi_lab

    results = {"npz": fnsi_lab.identify(str(lab["files"]["npz"]), _config(1), order=6)}
    for kind, rec in imported.items():
        # the transient period comes from the recording's metadata here
        results[kind] = fnsi_lab.identify(str(rec), _config(None), order=6)
    return results


# ---------------------------------------------------------------------------- import
@pytest.mark.parametrize("kind", ["tdms", "uff", "csv"])
def test_import_keeps_samples_channels_rate_and_provenance(lab, imported, kind):
    from fnsi_lab.daq.recording.reader import open_recording, read_periodic

    with open_recording(imported[kind]) as rec:
        x = rec.read_samples()
        assert [c.name for c in rec.channels] == lab["names_in"] + lab["names_out"]
        assert [c.quantity for c in rec.channels] == ["force"] + ["displacement"] * 3
        assert [c.unit for c in rec.channels] == ["N", "m", "m", "m"]
        assert rec.sample_rate_hz == FS_HZ
        src = rec.metadata["source"]
        raw = lab["files"][kind].read_bytes()
        assert src["kind"] == "import" and src["format"] == {"uff": "uff58"}.get(kind, kind)
        assert src["sha256"] == hashlib.sha256(raw).hexdigest()
        assert src["file"].endswith(lab["files"][kind].name)
        assert src["options"]["inputs"] == ["F-X3"]
    # float32 samples survive TDMS, UFF 58 ASCII (12 digits) and CSV bit for bit
    assert np.array_equal(x, np.column_stack([lab["u"], lab["y"]]))
    pr = read_periodic(imported[kind])
    assert (pr.samples_per_period, pr.transient_periods, pr.n_periods) == (N, 1, PERIODS)


def test_imported_recording_works_with_info(imported, capsys):
    assert main(["info", str(imported["uff"])]) == 0
    text = capsys.readouterr().out
    assert "source import" in text and f"N = {N}" in text and "1 transient" in text


def test_imported_recording_replays(imported, tmp_path):
    # the live identification service reads it like an acquisition (period and transient
    # periods from the import's excitation record)
    rrd = tmp_path / "replay.rrd"
    assert main(["replay", str(imported["csv"]), "--method", "frf", "--rrd", str(rrd),
                 "--quiet"]) == 0
    assert rrd.stat().st_size > 0


@pytest.mark.parametrize("kind", ["tdms", "uff", "csv"])
def test_identification_identical_to_npz(identified, kind):
    ref, got = identified["npz"], identified[kind]
    assert got.order == ref.order == 6
    for a, b in zip(ref.modes, got.modes, strict=True):
        assert a["frequency_hz"] == b["frequency_hz"]
        assert a["damping_ratio"] == b["damping_ratio"]
        assert np.array_equal(a["shape"], b["shape"])
    for a, b in zip(ref.coefficients, got.coefficients, strict=True):
        assert a["value"] == b["value"] and a["mean_real"] == b["mean_real"]
    ja, jb = ref.to_json(), got.to_json()
    assert ja["frf"] == jb["frf"] and ja["coefficient_spectra"] == jb["coefficient_spectra"]


def test_identification_is_physical(identified):
    # the shared answer is the simulated structure: the cubic spring to 1 % (measured 0.03 %
    # with 0.1 % sensor noise and 3 steady-state periods of 4 s)
    value = identified["npz"].coefficients[0]["value"]
    assert abs(value / K3_TRUE - 1) < 0.01


def test_uff_even_increment_with_six_digits_gives_the_round_rate(tmp_path):
    from fnsi_lab.daq.formats import read_lab_file
    from fnsi_lab.daq.formats.table import rate_from_increment

    # 51.2 kHz: pyuff writes dt = 1.953125e-05 as E13.5 -> 1.95312e-05 (51200.13 Hz)
    x = np.sin(np.arange(64) / 3.0)
    path = tmp_path / "fast.uff"
    pyuff.UFF(str(path)).write_sets([pyuff.prepare_58(
        func_type=1, id1="acc", rsp_node=1, rsp_dir=3, ref_node=0, ref_dir=0, data=x,
        x=np.arange(64) / 51200.0, abscissa_spacing=1, abscissa_spec_data_type=17,
        ordinate_spec_data_type=12, ordinate_axis_units_lab="m/s^2",
        orddenom_spec_data_type=0, z_axis_spec_data_type=0)], mode="overwrite")
    table = read_lab_file(path)
    assert table.sample_rate_hz == 51200.0
    assert table.channels[0].quantity == "acceleration"
    assert (table.channels[0].node, table.channels[0].direction) == ("1", "+Z")
    # an increment too short to be a rounded reciprocal is exact
    assert rate_from_increment(0.003, path="p", field="f") == pytest.approx(1000 / 3, rel=1e-15)
    assert rate_from_increment(1 / 3000, path="p", field="f") == 3000.0


def test_binary_uff58_import(lab, tmp_path):
    from fnsi_lab.daq.formats import read_lab_file

    # dataset 58b (binary doubles), as Testlab and other DAQ software write large records
    x = np.column_stack([lab["u"], lab["y"]])
    names = lab["names_in"] + lab["names_out"]
    path = tmp_path / "binary.uff"
    pyuff.UFF(str(path)).write_sets([pyuff.prepare_58(
        binary=1, func_type=1, id1=n, rsp_node=j + 1, rsp_dir=-2, ref_node=0, ref_dir=0,
        data=x[:, j].astype(float), x=np.arange(x.shape[0]) / FS_HZ, abscissa_spacing=1,
        abscissa_spec_data_type=17, ordinate_spec_data_type=13 if j == 0 else 8,
        ordinate_axis_units_lab="N" if j == 0 else "m", orddenom_spec_data_type=0,
        z_axis_spec_data_type=0) for j, n in enumerate(names)], mode="add")
    # ('add' into a new file: pyuff 2.5's binary writer truncates the file per set on
    # 'overwrite')
    table = read_lab_file(path)
    assert table.names == tuple(names) and table.sample_rate_hz == FS_HZ
    assert np.array_equal(table.data.astype(np.float32), x)
    assert [c.quantity for c in table.channels] == ["force"] + ["displacement"] * 3
    assert {(c.node, c.direction) for c in table.channels[1:]} == {("2", "-Y"), ("3", "-Y"),
                                                                  ("4", "-Y")}


def test_csv_layouts_of_spreadsheet_exports(tmp_path):
    from fnsi_lab.daq.formats import plan_import, read_lab_file

    x = np.array([[0.5, 1.25e-3, -2.0e-4], [-0.25, 1.5e-3, 3.0e-4], [1.0, -1.0e-3, 0.0]])
    # semicolon-separated with decimal commas, units in a second header line, rate and
    # period in '#' lines
    eu = tmp_path / "eu.csv"
    eu.write_text("# sample_rate_hz: 2048\n# samples_per_period: 3\nForce;NC1-Z;NC2:-Y\n"
                  "N;mm;mm\n" + "".join(";".join(f"{v:.6g}".replace(".", ",") for v in row)
                                         + "\n" for row in x))
    # tab-separated, units in brackets, a time column giving the rate
    tab = tmp_path / "tab.txt"
    tab.write_text("time (s)\tForce [N]\tNC1-Z [mm]\tNC2:-Y [mm]\n" + "".join(
        "\t".join(f"{v:.6g}" for v in (k / 2048, *row)) + "\n" for k, row in enumerate(x)))
    for path in (eu, tab):
        table = read_lab_file(path)
        np.testing.assert_array_equal(table.data, x)
        assert table.sample_rate_hz == 2048.0
        assert [c.unit for c in table.channels] == ["N", "mm", "mm"]
        assert [(c.node, c.direction) for c in table.channels] == [("", ""), ("NC1", "+Z"),
                                                                  ("NC2", "-Y")]
        plan = plan_import(table, samples_per_period=3)
        assert [c.quantity for c in plan.channels] == ["force", "displacement", "displacement"]
    assert read_lab_file(eu).samples_per_period == 3


def test_interrupted_import_leaves_no_file(lab, tmp_path):
    from fnsi_lab.daq.formats import plan_import, read_lab_file, write_recording

    table = read_lab_file(lab["files"]["tdms"])
    plan = plan_import(table, inputs=["F-X3"])

    def interrupt(done: int, total: int) -> None:
        raise KeyboardInterrupt

    out = tmp_path / "cut.mcap"
    with pytest.raises(KeyboardInterrupt):
        write_recording(table, plan, out, on_block=interrupt)
    assert list(tmp_path.iterdir()) == []


def test_node_and_direction_from_names():
    from fnsi_lab.daq.formats import parse_node_direction

    assert parse_node_direction("NC2-Z") == ("NC2", "+Z")
    assert parse_node_direction("12:-x") == ("12", "-X")
    assert parse_node_direction("P7_-Y") == ("P7", "-Y")
    assert parse_node_direction("hub RZ") == ("hub", "+RZ")
    assert parse_node_direction("X1") is None and parse_node_direction("F-X3") is None


def _error_line(capsys, args) -> str:
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    return err


def test_import_errors_are_one_line(lab, tmp_path, capsys):
    out = str(tmp_path / "x.mcap")
    # a cell that is not a number: line and column named
    bad = tmp_path / "bad.csv"
    bad.write_text("time [s],F [N],X1 [m]\n0,1,2\n0.001,1,abc\n0.002,1,2\n")
    err = _error_line(capsys, ["import", str(bad), "--out", out])
    assert "line 3" in err and "'X1'" in err and "'abc'" in err
    # no force unit and no --inputs
    volts = tmp_path / "volts.csv"
    volts.write_text("# sample_rate_hz: 100\nA [V],B [V]\n" + "1,2\n" * 8)
    err = _error_line(capsys, ["import", str(volts), "--out", out])
    assert "--inputs" in err
    # an output whose unit says nothing: named, with the option to fix it
    err = _error_line(capsys, ["import", str(volts), "--out", out, "--inputs", "A"])
    assert "'B'" in err and "--output-quantity" in err
    assert main(["import", str(volts), "--out", out, "--inputs", "A", "--output-quantity",
                 "acceleration", "--quiet"]) == 0
    # refuse to overwrite
    err = _error_line(capsys, ["import", str(volts), "--out", out, "--inputs", "A",
                               "--output-quantity", "acceleration"])
    assert "--force" in err
    # a sample rate that disagrees with the file
    err = _error_line(capsys, ["import", str(lab["files"]["uff"]), "--out", out, "--force",
                               "--fs", "1000"])
    assert "512" in err and "1000" in err
    # an unknown input name lists the channels
    err = _error_line(capsys, ["import", str(lab["files"]["tdms"]), "--out", out, "--force",
                               "--inputs", "F9"])
    assert "'F9'" in err and "X1" in err
    # a period that disagrees with the file's property
    err = _error_line(capsys, ["import", str(lab["files"]["tdms"]), "--out", out, "--force",
                               "--samples-per-period", "1024"])
    assert "2048" in err and "1024" in err
    # not a TDMS file at all
    junk = tmp_path / "junk.tdms"
    junk.write_bytes(b"not a tdms file at all")
    err = _error_line(capsys, ["import", str(junk), "--out", out, "--force"])
    assert "junk.tdms" in err and "TDMS" in err


def test_tdms_channels_of_different_lengths(tmp_path, capsys):
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    path = tmp_path / "ragged.tdms"
    with TdmsWriter(str(path)) as w:
        w.write_segment([RootObject({}), GroupObject("g"),
                         ChannelObject("g", "F", np.ones(10), properties={"unit_string": "N"}),
                         ChannelObject("g", "X", np.ones(9), properties={"unit_string": "m"})])
    err = _error_line(capsys, ["import", str(path), "--out", str(tmp_path / "r.mcap"),
                               "--fs", "100"])
    assert "'X'" in err and "9 samples" in err


# ---------------------------------------------------------------------------- export
@pytest.fixture(scope="module")
def result_json(lab, identified):
    from fnsi_lab.outputs import write_json

    path = lab["dir"] / "result.json"
    write_json(identified["npz"].to_json(), path)
    return path


def _read_uff(path):
    sets = pyuff.UFF(str(path)).read_sets()
    return ([s for s in sets if s["type"] == 55], [s for s in sets if s["type"] == 58])


def test_export_uff_reads_back_through_pyuff(result_json, tmp_path):
    res = json.loads(result_json.read_text())
    out = tmp_path / "lumped.uff"
    mapping = ["X1=1:+X", "X2=2:+X", "X3=3:+X", "F-X3=3:+X"]
    assert main(["export", str(result_json), "--uff", str(out), "--map", *mapping,
                 "--quiet"]) == 0
    modes, frfs = _read_uff(out)
    assert len(modes) == len(res["modes"]) == 3
    for k, (ds, mode) in enumerate(zip(modes, res["modes"])):
        lam = ds["eig"]
        f = abs(lam) / (2 * math.pi)
        zeta = -lam.real / abs(lam)
        assert ds["mode_n"] == k + 1 and ds["analysis_type"] == 3
        assert abs(f - mode["frequency_hz"]) <= 1e-9 * mode["frequency_hz"]
        assert abs(zeta - mode["damping_ratio"]) <= 1e-9
        assert abs(zeta - mode["damping_ratio"]) <= 1e-9 * mode["damping_ratio"]
        shape = np.array(mode["shape"]["re"]) + 1j * np.array(mode["shape"]["im"])
        assert list(ds["node_nums"]) == [1, 2, 3]
        # shapes are written with >= 7 significant digits (12-character fields)
        np.testing.assert_allclose(ds["r1"], shape, rtol=0, atol=1e-7 * np.abs(shape).max())
        assert not np.any(ds["r2"]) and not np.any(ds["r3"])
    kinds = ("measured", "model", "underlying_linear")
    assert len(frfs) == len(kinds) * 3
    f = np.array(res["frf"]["frequency_hz"])
    for ds in frfs:
        kind = ds["id1"].split(" FRF")[0]
        i = int(ds["rsp_node"]) - 1
        h = (np.array(res["frf"][kind]["re"]) + 1j * np.array(res["frf"][kind]["im"]))[:, i, 0]
        assert ds["func_type"] == 4 and ds["rsp_dir"] == 1
        assert (ds["ref_node"], ds["ref_dir"]) == (3, 1)
        np.testing.assert_allclose(ds["x"], f, rtol=1e-10)
        np.testing.assert_allclose(ds["data"], h, rtol=1e-11, atol=0)


def test_export_nodes_from_names_and_negative_directions(result_json, tmp_path):
    from fnsi_lab.export import load_result

    # the same result with lab-style channel names: node and direction from the names
    res = json.loads(result_json.read_text())
    names = {"X1": "NC1-Z", "X2": "NC2:-Z", "X3": "12-Y", "F-X3": "12:+Y"}
    res["outputs"] = [names[n] for n in res["outputs"]]
    res["inputs"] = [names[n] for n in res["inputs"]]
    res["frf"]["outputs"], res["frf"]["inputs"] = res["outputs"], res["inputs"]
    path = tmp_path / "named.json"
    path.write_text(json.dumps(res))
    out = tmp_path / "named.uff"
    assert main(["export", str(path), "--uff", str(out), "--quiet"]) == 0
    modes, frfs = _read_uff(out)
    shapes = load_result(path).shapes
    # 12 keeps its number; NC1 and NC2 are numbered 1 and 2
    for ds, shape in zip(modes, shapes):
        assert list(ds["node_nums"]) == [1, 2, 12]
        np.testing.assert_allclose(ds["r3"][:2], [shape[0], -shape[1]], rtol=0,
                                   atol=1e-7 * np.abs(shape).max())
        np.testing.assert_allclose(ds["r2"][2], shape[2], rtol=0, atol=1e-7 * np.abs(shape).max())
    dirs = {(d["rsp_node"], d["rsp_dir"]) for d in frfs}
    assert dirs == {(1, 3), (2, -3), (12, 2)}
    assert {(d["ref_node"], d["ref_dir"]) for d in frfs} == {(12, 2)}


def test_import_ident_export_keeps_uff_nodes(lab, imported, tmp_path):
    # the command-line flow: UFF 58 -> import -> ident --json -> export; the response nodes
    # and directions of the UFF records (1..4, +X) travel in the recording's channel table
    yaml = pytest.importorskip("yaml")
    cfg = tmp_path / "ident.yaml"
    cfg.write_text(yaml.safe_dump(_config(None)))
    result = tmp_path / "result.json"
    assert main(["ident", str(imported["uff"]), "--config", str(cfg), "--order", "6",
                 "--json", str(result), "--quiet"]) == 0
    out = tmp_path / "from-uff.uff"
    assert main(["export", str(result), "--uff", str(out), "--quiet"]) == 0
    modes, frfs = _read_uff(out)
    assert all(list(ds["node_nums"]) == [2, 3, 4] for ds in modes)
    assert {(d["rsp_node"], d["rsp_dir"]) for d in frfs} == {(2, 1), (3, 1), (4, 1)}
    assert {(d["ref_node"], d["ref_dir"]) for d in frfs} == {(1, 1)}


def test_export_csv_tables(result_json, tmp_path):
    res = json.loads(result_json.read_text())
    folder = tmp_path / "tables"
    assert main(["export", str(result_json), "--csv", str(folder), "--quiet"]) == 0
    with open(folder / "modes.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [float(r["frequency_hz"]) for r in rows] == [m["frequency_hz"] for m in res["modes"]]
    assert [float(r["damping_ratio"]) for r in rows] == [m["damping_ratio"] for m in res["modes"]]
    with open(folder / "mode_shapes.csv") as fh:
        shapes = list(csv.DictReader(fh))
    assert len(shapes) == 3 * len(res["outputs"])
    assert float(shapes[1]["re"]) == res["modes"][0]["shape"]["re"][1]
    with open(folder / "coefficient_spectra.csv") as fh:
        spectra = list(csv.DictReader(fh))
    cs = res["coefficient_spectra"]
    assert [float(r["frequency_hz"]) for r in spectra] == cs["frequency_hz"]
    # every column states its unit: the .npz carried none, so SI (N, m) was assumed
    unit = res["units"]["coefficients"]["knl"]
    assert res["units"]["assumed"] and unit.startswith("N/m")
    assert [float(r[f"knl_re [{unit}]"]) for r in spectra] == cs["values"]["knl"]["re"]
    with open(folder / "coefficients.csv") as fh:
        coef = list(csv.DictReader(fh))
    assert float(coef[0]["value"]) == res["coefficients"][0]["value"]
    assert coef[0]["unit"] == unit == res["coefficients"][0]["unit"]
    # a second export into the same folder is refused without --force
    assert main(["export", str(result_json), "--csv", str(folder), "--quiet"]) == 2
    assert main(["export", str(result_json), "--csv", str(folder), "--quiet", "--force"]) == 0


def test_export_errors_are_one_line(result_json, tmp_path, capsys):
    out = str(tmp_path / "x.uff")
    err = _error_line(capsys, ["export", str(result_json), "--uff", out])
    assert "X1" in err and "--map" in err          # names that do not say node/direction
    err = _error_line(capsys, ["export", str(result_json), "--uff", out, "--map", "X1=1:+Q"])
    assert "'+Q'" in err and "--map X1" in err
    err = _error_line(capsys, ["export", str(result_json), "--uff", out, "--map", "X1=0:+Z"])
    assert "'0'" in err
    res = json.loads(result_json.read_text())
    del res["modes"][1]["shape"]
    broken = tmp_path / "old.json"
    broken.write_text(json.dumps(res))
    err = _error_line(capsys, ["export", str(broken), "--csv", str(tmp_path / "t")])
    assert "modes[1].shape" in err
