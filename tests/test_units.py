"""Units from the channel table: JSON coefficients, summary, info, report, CSV (issue 27)."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.core.units import coefficient_unit, length_unit, result_units


@pytest.mark.parametrize("kwargs, unit", [
    (dict(kind="trilinear", clearances=(1.0, 1.0)), "N/mm"),
    (dict(kind="bilinear", clearance=0.5), "N/mm"),
    (dict(kind="polynomial", exponent=3), "N/mm^3"),
    (dict(kind="polynomial", exponent=1), "N/mm"),
    (dict(kind="polynomial", exponent=2.5, signed=True), "N/mm^2.5"),
    (dict(kind="polynomial", exponent=1, argument="velocity"), "N s/mm"),
    (dict(kind="polynomial", exponent=3, argument="velocity"), "N s^3/mm^3"),
    (dict(kind="quadratic_damping"), "N s^2/mm^2"),
    (dict(kind="coulomb"), "N"),
])
def test_a_coefficient_unit_is_the_force_over_its_basis_function(kwargs, unit):
    nl = Nonlinearity(name="k", channels={"x": 1.0}, **kwargs)
    assert coefficient_unit(nl, "N", "mm") == unit


@pytest.mark.parametrize("unit, quantity, length", [
    ("mm", "displacement", "mm"), ("mm/s", "velocity", "mm"), ("m/s^2", "acceleration", "m"),
    ("m/s²", "acceleration", "m"), ("g", "acceleration", "g s^2"), ("", None, "m")])
def test_the_length_unit_under_a_motion_unit(unit, quantity, length):
    assert length_unit(unit, quantity) == length


def test_inputs_without_a_unit_table_are_si_and_say_so():
    nl = Nonlinearity(name="knl", kind="polynomial", channels={"y0": 1.0})
    units = result_units({}, ["u0"], ["y0"], "displacement", [nl])
    assert units["assumed"] and units["frf"] == "m/N" and units["coefficients"] == {"knl": "N/m^3"}


def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "fnsi_lab", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def smallsat(tmp_path_factory) -> dict:
    """The default SmallSat recording (mm, N), identified by the robust pipeline."""
    d = tmp_path_factory.mktemp("units")
    acq = _cli("acquire", "--out", "s.mcap", "--quiet", cwd=d)
    assert acq.returncode == 0, acq.stderr
    ident = _cli("ident", "s.mcap", "--config", "smallsat39", "--auto", "--json", "s.json",
                 cwd=d)
    assert ident.returncode == 0, ident.stderr
    return {"dir": d, "acquire": acq, "ident": ident,
            "result": json.loads((d / "s.json").read_text())}


def test_every_coefficient_of_the_smallsat_json_is_in_n_per_mm(smallsat):
    res = smallsat["result"]
    assert res["units"]["force"] == "N" and res["units"]["output"] == "mm"
    assert res["units"]["frf"] == "mm/N" and not res["units"]["assumed"]
    lists = [res["coefficients"]] + [v["coefficients"] for v in res.values()
                                     if isinstance(v, dict) and isinstance(v.get("coefficients"), list)
                                     and v["coefficients"] and isinstance(v["coefficients"][0], dict)]
    assert len(lists) >= 3  # the answer, the full and the reduced model at least
    for coefficients in lists:
        assert coefficients and all(c["unit"] == "N/mm" for c in coefficients), coefficients
    # the printed summary states it too
    assert "value 116.7" in smallsat["ident"].stdout
    assert all("N/mm" in line for line in smallsat["ident"].stdout.splitlines()
               if "NC2-Z:" in line and "value" in line)


def test_info_states_the_force_unit_of_the_rms(smallsat):
    out = _cli("info", "s.mcap", cwd=smallsat["dir"])
    assert out.returncode == 0 and "rms 100 N," in out.stdout


def test_the_report_and_the_csv_state_units(smallsat):
    d = smallsat["dir"]
    rep = _cli("report", "s.json", "--out", "s.html", cwd=d)
    assert rep.returncode == 0, rep.stderr
    page = (d / "s.html").read_text()
    assert "magnitude (dB re 1 mm/N)" in page
    assert "NC2-Z:neg (N/mm)" in page  # the coefficient spectra's axis
    assert "116.7" in page and " N/mm (error" in page  # the summary's values
    assert "<td>units</td><td>force N, outputs mm, FRF mm/N</td>" in page
    exp = _cli("export", "s.json", "--csv", "tables", cwd=d)
    assert exp.returncode == 0, exp.stderr
    with open(d / "tables" / "coefficients.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["unit"] for r in rows] == ["N/mm", "N/mm"]
    with open(d / "tables" / "coefficient_spectra.csv") as fh:
        header = next(csv.reader(fh))
    assert "NC2-Z:neg_re [N/mm]" in header and "NC2-Z:pos_im [N/mm]" in header
