"""The promises of issue 29 on a joint that none of fnsi-lab's simulators wrote.

``bench/independent_joint.py`` simulates (from scratch, no ``daq/sim`` code) a 5-DOF chain
with a bolted joint: an Iwan element (10 Jenkins elements, slip forces spread over 2-8 N)
next to a linear bolt stiffness, a one-sided contact and interface wear, driven through a
shaker, accelerations at 500 Hz, 6000-sample periods. Real subprocess CLI runs on its
``.npz`` records, as an outside user would (bench/RESULTS_independent.md has the full table):

- 3 N RMS: the joint never slips (the truth counts no slider motion): a Jenkins element's
  coefficient has no support in the data, so it is never ``identified`` and the answer is the
  linear fit;
- 55 N RMS (the highest level: macro-slip, contact, wear): whatever the answer (Jenkins kept
  or left out), it predicts another level's record (20 N), which neither the fit nor the
  decision (``--validation`` on 35 N) read, no worse than the linear fit of the same data,
  and ``validate`` gives the answer's error on every output;
- 3 N again: ``locate`` places nothing (there is no distortion to place);
- 35 N with two Jenkins elements on the joint (a distributed joint drawn by two): their
  slips are searched apart, without singular fits.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench" / "independent_joint.py"


def _write_campaign(out: Path, levels: list[str]) -> int:
    """``python bench/independent_joint.py --out OUT --levels ...``, in this process."""
    spec = importlib.util.spec_from_file_location("independent_joint", BENCH)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["independent_joint"] = mod   # dataclasses and numba look their module up
    try:
        spec.loader.exec_module(mod)
        return mod.main(["--out", str(out), "--levels", *levels])
    finally:
        del sys.modules["independent_joint"]  # leave no trace for other tests


def _cli(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "fnsi_lab", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def campaign(tmp_path_factory) -> Path:
    """Levels 3, 20, 35, 55 N (commanded RMS) and the configs, as the bench writes them."""
    out = tmp_path_factory.mktemp("indep")
    assert _write_campaign(out, ["3", "20", "35", "55"]) == 0
    return out


def test_stuck_level_coefficient_is_not_identified(campaign: Path):
    truth = json.loads((campaign / "indep-rms3.truth.json").read_text())
    assert truth["run"]["regime"] == "stuck"          # the premise: no slider ever moved
    p = _cli(["ident", "indep-rms3.npz", "--config", "indep-jenkins.yaml", "--auto",
              "--validation", "indep-rms20.npz", "--json", "j3.json", "--quiet"], campaign)
    assert p.returncode == 0, p.stderr
    r = json.loads((campaign / "j3.json").read_text())
    # a spring in series with a slider that never slides is a linear spring: its slip and
    # stiffness are not separable from the linear model, whatever the noise realisation
    assert all(c["verdict"] != "identified" for c in r["coefficients"]), r["coefficients"]
    assert r["nonlinear_vs_linear"]["decision"] == "linear"


def test_highest_level_never_worse_than_linear_fit_on_another_record(campaign: Path):
    truth = json.loads((campaign / "indep-rms55.truth.json").read_text())
    assert "macro-slip" in truth["run"]["regime"]      # the premise: the joint slips fully
    p = _cli(["ident", "indep-rms55.npz", "--config", "indep-jenkins.yaml", "--auto",
              "--validation", "indep-rms35.npz", "--json", "j55.json", "--quiet"], campaign)
    assert p.returncode == 0, p.stderr
    p = _cli(["validate", "j55.json", "indep-rms20.npz", "--json", "v55.json"], campaign)
    assert p.returncode == 0, p.stderr
    v = json.loads((campaign / "v55.json").read_text())
    for o in v["outputs"]:
        ref = o.get("linear_fit_error_db")
        ref = o["linear_error_db"] if ref is None else ref   # a linear answer: its own fit
        assert o["error_db"] is not None, o                  # the answer's error is given
        # never worse than the linear fit: 0.5 dB is 6 % of the error, the most that the
        # 20 N record's own non-periodic part can move it (its periods differ by < 1 %,
        # -40 dB, against errors of -1 to -12 dB of the output)
        assert o["error_db"] <= ref + 0.5, v["outputs"]


def test_locate_places_nothing_where_the_joint_never_slips(campaign: Path):
    # the joint never slips at 3 N: the structure is linear and the distortion analysis says
    # so; the generic columns' F-test had "located" a pair chosen by the noise realisation
    p = _cli(["locate", "indep-rms3.npz", "--config", "indep-linear.yaml", "--json",
              "where3.json", "--quiet"], campaign)
    assert p.returncode == 0, p.stderr
    r = json.loads((campaign / "where3.json").read_text())
    verdicts = [c["verdict"] for c in r["candidates"]]
    assert "located" not in verdicts and "as likely as the best" not in verdicts, verdicts


TWO_JENKINS = """\
band_hz: [2, 22]
transient_periods: 1
output_quantity: acceleration
inputs:
  - {name: F-shaker, driving_point: drive}
max_order: 30
nonlinearities:
  - {name: joint-a, kind: jenkins, channels: {bracket: 1, box: -1}, slip: auto}
  - {name: joint-b, kind: jenkins, channels: {bracket: 1, box: -1}, slip: auto}
"""


def test_two_jenkins_elements_on_one_joint_are_searched_apart(campaign: Path):
    # an Iwan joint drawn by two Jenkins elements: both slips started in the middle of the
    # interval gave two equal columns, singular fits (23 scipy warnings here) and, on the
    # GVT-like preset's 35 N, an order sweep unstable at every order (exit 2)
    (campaign / "two.yaml").write_text(TWO_JENKINS)
    p = _cli(["ident", "indep-rms35.npz", "--config", "two.yaml", "--auto", "--json",
              "two35.json", "--quiet"], campaign)
    assert p.returncode == 0, p.stderr
    assert "Singular matrix" not in p.stderr, p.stderr[-2000:]
    r = json.loads((campaign / "two35.json").read_text())
    slips = [e["slip"] for e in r["nonlinearities"] if e.get("kind") == "jenkins"]
    assert len(set(slips)) == len(slips), slips      # never the same column twice


@pytest.fixture(scope="module")
def six_levels(tmp_path_factory) -> Path:
    """The bench's default campaign (3, 6, 10, 20, 35, 55 N: its phases)."""
    out = tmp_path_factory.mktemp("indep6")
    assert _write_campaign(out, ["3", "6", "10", "20", "35", "55"]) == 0
    return out


def test_several_records_are_checked_each_on_its_own(six_levels):
    """10 + 20 + 35 N identified together: pooled over the three records, the simulation
    check had passed a model that predicts the 10 and 20 N records 1-4 dB worse than the
    linear fit. Each record is now simulated on its own, and the model is rejected on the
    first record it predicts worse."""
    proc = _cli(["ident", "indep-rms10.npz", "indep-rms20.npz", "indep-rms35.npz", "--config",
                 "indep-jenkins.yaml", "--auto", "--json", "levels.json", "--quiet"],
                six_levels)
    assert proc.returncode == 0, proc.stderr
    nvl = json.loads((six_levels / "levels.json").read_text())["nonlinear_vs_linear"]
    records = nvl["simulation"]["records"]
    assert [Path(r["record"]).name for r in records] == [
        "indep-rms10.npz", "indep-rms20.npz", "indep-rms35.npz"]
    assert all(r["own"] for r in records)
    assert nvl["decision"] == "linear" and nvl["simulation_rejected"]
    assert "its own record indep-rms" in nvl["statement"]


def test_validation_on_the_levels_below_and_above(six_levels):
    """The 35 N Jenkins model checked on the level above alone was kept and then predicted
    the 3-10 N records 2-10 dB worse than the linear fit (bench/RESULTS_independent.md).
    Checked on the level below as well (``--validation`` twice), FNSI's model was rejected:
    on 20 N it predicted an output worse than the linear fit. With its output matrices refit
    on its own motion (docs/ident.md) it predicts both records better than the linear fit
    on every output (measured: 20 N by 1.9-3.0 dB, 55 N by 4.4-7.0 dB) and is kept; both
    records are named in the check."""
    proc = _cli(["ident", "indep-rms35.npz", "--config", "indep-jenkins.yaml", "--auto",
                 "--validation", "indep-rms20.npz", "--validation", "indep-rms55.npz",
                 "--json", "j35.json", "--quiet"], six_levels)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((six_levels / "j35.json").read_text())
    nvl = doc["nonlinear_vs_linear"]
    records = nvl["simulation"]["records"]
    assert [Path(r["record"]).name for r in records] == ["indep-rms20.npz", "indep-rms55.npz"]
    assert doc["output_refit"]["applied"], doc["output_refit"]
    assert nvl["decision"] == "nonlinear", nvl["statement"]
    for record in records:
        assert record["converged"] and record["worse"] == []
        for out in record["outputs"]:   # at least 1 dB better on every output
            assert out["error_db"] < out["linear_fit_error_db"] - 1.0, (record["record"], out)


def test_several_records_and_a_validation_record_are_all_checked(six_levels):
    """``ident 6 10 --validation 20``: the two identified records are checked each on its
    own as well as the validation record. The model predicts 20 N no worse than the linear
    fit, which alone had kept it, but its own 6 N record worse (bracket and box), so the
    answer is the linear fit."""
    proc = _cli(["ident", "indep-rms6.npz", "indep-rms10.npz", "--config",
                 "indep-jenkins.yaml", "--auto", "--validation", "indep-rms20.npz",
                 "--json", "both.json", "--quiet"], six_levels)
    assert proc.returncode == 0, proc.stderr
    nvl = json.loads((six_levels / "both.json").read_text())["nonlinear_vs_linear"]
    records = nvl["simulation"]["records"]
    assert [(Path(r["record"]).name, r["own"]) for r in records] == [
        ("indep-rms6.npz", True), ("indep-rms10.npz", True), ("indep-rms20.npz", False)]
    assert records[0]["worse"] and nvl["decision"] == "linear"
    assert Path(nvl["simulation"]["record"]).name == "indep-rms6.npz"


def test_a_slip_search_smallest_at_the_top_takes_the_minimum_below_it(six_levels):
    """55 N (macro-slip and contact): the criterion is smallest at the top of the slip
    interval, where the element barely slips and its column copies the motion. The search
    takes its clear minimum below (it beats the model without the element), says so, and
    the nested test keeps the element: the underlying linear model is then the joint-free
    structure's (5.386, 10.507, 13.032 Hz in the truth; 1 %: the Iwan joint is ten sliders,
    not one) and another level's record is predicted better than by the linear fit on every
    output (measured 3.8-7.8 dB on 20 N; 2 dB is a third of the error energy, far beyond
    what that record's < 1 % period differences can move)."""
    p = _cli(["ident", "indep-rms55.npz", "--config", "indep-jenkins.yaml", "--auto",
              "--validation", "indep-rms35.npz", "--json", "top55.json", "--quiet"], six_levels)
    assert p.returncode == 0, p.stderr
    r = json.loads((six_levels / "top55.json").read_text())
    assert any("smallest at the top of the search interval" in w and "is taken" in w
               for w in r["warnings"]), r["warnings"]
    assert r["nonlinear_vs_linear"]["decision"] == "nonlinear"
    free = [m["frequency_hz"] for m in json.loads(
        (six_levels / "indep-rms55.truth.json").read_text())["modes_joint_free"]]
    found = [m["frequency_hz"] for m in r["modes"]]
    for f in free[1:4]:
        assert min(abs(g - f) / f for g in found) < 0.01, (f, found)
    p = _cli(["validate", "top55.json", "indep-rms20.npz", "--json", "vtop55.json"], six_levels)
    assert p.returncode == 0, p.stderr
    for o in json.loads((six_levels / "vtop55.json").read_text())["outputs"]:
        assert o["error_db"] < o["linear_fit_error_db"] - 2.0, o


def test_the_own_motion_refit_predicts_another_level_better(six_levels, monkeypatch):
    """The 20 N Jenkins answer checked on the 10 N record (``--validation``): its output
    matrices refit on its own motion (docs/ident.md) predict that record better than FNSI's
    (4.5 dB in summed error energy) and are kept; on the 6 N record, which neither the fit
    nor the choice read, the refit model is better than FNSI's on every output too
    (measured: -16.7 / -11.1 / -14.8 dB -> -18.7 / -18.5 / -19.1 dB; the linear fit -9.7 /
    -8.5 / -9.5), with the same poles."""
    import fnsi_lab
    import fnsi_lab.ident.pipeline as pipeline

    record, config = str(six_levels / "indep-rms20.npz"), str(six_levels / "indep-jenkins.yaml")
    check = str(six_levels / "indep-rms10.npz")
    refit = fnsi_lab.identify(record, config=config, validation=check)
    evidence = refit.to_json()["output_refit"]
    assert evidence["applied"], evidence
    assert evidence["validation_error_refit"] < evidence["validation_error_fnsi"]
    # the model in the answer (and its JSON) is the refit one: validated on its own record
    # it gives the error the refit reports
    own = fnsi_lab.validate_model(refit, record).to_json()["outputs"]
    assert [o["error_db"] for o in own] == pytest.approx(evidence["error_db_after"], abs=0.01)
    monkeypatch.setattr(pipeline, "refit_on_its_record", lambda session, model: model)
    fnsi = fnsi_lab.identify(record, config=config, validation=check)
    assert not fnsi.to_json().get("output_refit", {}).get("applied")
    assert fnsi.nested.decision == refit.nested.decision == "nonlinear"
    assert fnsi.model.poles.natural_frequency_hz.tolist() == \
        refit.model.poles.natural_frequency_hz.tolist()
    other = six_levels / "indep-rms6.npz"
    with_refit = fnsi_lab.validate_model(refit, other).to_json()["outputs"]
    without = fnsi_lab.validate_model(fnsi, other).to_json()["outputs"]
    for a, b in zip(with_refit, without):
        assert a["error_db"] < b["error_db"] - 1.0, (a, b)
        assert a["error_db"] < a["linear_fit_error_db"] - 5.0, a


def test_friction_and_a_stop_left_to_the_data_fall_back_on_the_friction_element(six_levels):
    # 20 N, a Jenkins element and a stop both left to the data (the Iwan joint has no
    # clearance): the search refused the slip (top of its interval) and kept the stop at a
    # clearance whose contact stiffnesses no line determines: the answer was the linear fit,
    # where the Jenkins element alone is kept. The Jenkins element is now searched on its own
    # as a second candidate: kept, and on the 10 and 35 N records 1.9-8.2 dB better than the
    # 20 N linear fit (-19.5 / -11.0 / -15.6 against -11.3 / -9.2 / -10.7; -5.8 / -4.7 / -5.5
    # against -2.7 / -2.7 / -2.8). The limit: never worse than that linear fit, as above.
    config = (six_levels / "indep-jenkins.yaml").read_text() + (
        "  - {name: gap, kind: trilinear, channels: {bracket: 1, box: -1}, clearances: auto}\n")
    (six_levels / "js.yaml").write_text(config)
    p = _cli(["ident", "indep-rms20.npz", "--config", "js.yaml", "--auto", "--json",
              "js20.json"], six_levels)
    assert p.returncode == 0, p.stderr
    r = json.loads((six_levels / "js20.json").read_text())
    assert r["nonlinear_vs_linear"]["decision"] == "nonlinear"
    assert [c["name"] for c in r["coefficients"]] == ["joint"]
    assert [e["name"] for e in r["nonlinear_vs_linear"]["refused"]] == ["gap"]
    assert "searched on its own instead" in p.stdout + p.stderr
    for level in ("10", "35"):
        p = _cli(["validate", "js20.json", f"indep-rms{level}.npz", "--json", f"v{level}.json"],
                 six_levels)
        assert p.returncode == 0, p.stderr
        for o in json.loads((six_levels / f"v{level}.json").read_text())["outputs"]:
            assert o["error_db"] <= o["linear_fit_error_db"] + 0.5, o
