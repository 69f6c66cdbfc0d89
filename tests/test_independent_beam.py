"""End-to-end checks of fnsi-lab on bench/independent_beam.py (a beam with a Bouc-Wen lap joint,
a simulator and a joint law none of fnsi-lab's simulators wrote; bench/RESULTS_beam.md).

Real parts: the simulator's records as .npz files, the CLI as a subprocess, its JSON.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
FNSI_LAB = str(Path(sys.executable).with_name("fnsi-lab"))


def _beam_module():
    spec = importlib.util.spec_from_file_location("independent_beam", ROOT / "bench" / "independent_beam.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("independent_beam", module)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def beam():
    return _beam_module()


@pytest.fixture(scope="module")
def records(tmp_path_factory, beam):
    """Two levels: 0.002 N (joint at 1 % of its yield displacement) and 0.3 N (at yield)."""
    out = tmp_path_factory.mktemp("beam")
    assert beam.main(["--out", str(out), "--levels", "0.002", "0.3"]) == 0
    return out


def _cli(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    return subprocess.run([FNSI_LAB, *args], capture_output=True, text=True, env=env, timeout=300)


def _level_and_its_twin(beam, out: Path, level: str, jenkins: str) -> Path:
    """The beam at ``level`` N and the same level's record of other phases and noise
    (``out/v``), with a Jenkins config on the joint whose last fields are ``jenkins``."""
    assert beam.main(["--out", str(out), "--levels", level]) == 0
    assert beam.main(["--out", str(out / "v"), "--levels", level, "--seed", "100"]) == 0
    config = out / "jenkins.yaml"
    config.write_text((out / "beam-linear.yaml").read_text().replace(
        "nonlinearities: []", "nonlinearities:\n  - {name: joint, kind: jenkins, "
        "channels: {jointL: 1, jointR: -1}, " + jenkins))
    return config


def test_locked_joint_simulation_matches_the_exact_frf(beam):
    # The integrator with the joint locked (a linear beam + shaker) against the exact
    # accelerance of the FE model at every excited line, noise-free. The input held at the
    # step's midpoint attenuates by about (w dt)^2 / 24 = 3.5e-4 at 140 Hz (dt = 1/8192 s);
    # the anti-alias filter acts on force and accelerations alike and cancels in the ratio.
    check = beam.check_locked_frf()
    assert check["max_relative_error"] < 1e-3
    assert check["median_relative_error"] < 1e-4


def test_truth_lists_the_joint_and_its_modes(records):
    truth = json.loads((records / "beam-rms0.3.truth.json").read_text())
    stuck = truth["modes_joint_stuck_hz"]
    slipping = truth["modes_joint_slipping_hz"]
    # about 8 modes in 3-140 Hz; the joint softens the modes it loads (post-yield 0.3 k0)
    assert 7 <= len([f for f in stuck if 3 <= f <= 140]) <= 10
    assert slipping[0] <= stuck[0] and min(slipping[4], slipping[5]) < 0.9 * stuck[4]
    assert truth["joint"]["small_amplitude_stiffness_n_m"] == pytest.approx(2.0e4)
    assert 0.5 < truth["run"]["peak_over_yield"] < 2.0


def test_analyse_calls_the_lowest_level_linear_and_the_joint_level_nonlinear(records):
    result = _cli("analyse", str(records / "beam-rms0.002.npz"), str(records / "beam-rms0.3.npz"),
                  "--config", str(records / "beam-linear.yaml"), "--json", str(records / "analyse.json"))
    assert result.returncode == 0, result.stderr
    report = json.loads((records / "analyse.json").read_text())
    verdicts = {Path(r["input"]).name: [o["verdict"] for o in r["outputs"]] for r in report["records"]}
    assert all(v.startswith("linear") for v in verdicts["beam-rms0.002.npz"])
    assert all(v.startswith("nonlinear") for v in verdicts["beam-rms0.3.npz"])
    # the multisine is full-grid 3-140 Hz (2193 lines); at 0.3 N the measured force carries
    # the joint's distortion 20-30 dB below the multisine near the 176 Hz mode beyond the
    # band: it is not excitation (it was taken for 61 excited lines up to 175.6 Hz)
    # input RMS about the mean: the 0.002 N record's load cell carries a DC offset of about
    # twice its multisine (2 % of the 0.3 N level's RMS); measured force RMS 0.0021 N
    truth = json.loads((records / "beam-rms0.002.truth.json").read_text())
    low = next(r for r in report["records"] if Path(r["input"]).name == "beam-rms0.002.npz")
    assert low["input_rms"] == pytest.approx(truth["run"]["measured_force_rms_n"], rel=0.02)
    for record in report["records"]:
        assert record["excitation"]["grid"] == "full"
        assert record["excitation"]["n_excited"] == 2193
        assert record["excitation"]["excited_band_hz"] == [3.0, 140.0]


@pytest.fixture(scope="module")
def third(records, beam):
    """The 0.3 N level with other phases and noise: a record no decision reads."""
    out = records / "v"
    assert beam.main(["--out", str(out), "--levels", "0.3", "--seed", "100"]) == 0
    return out / "beam-rms0.3.npz"


def test_jenkins_on_the_bouc_wen_joint_is_never_worse_than_the_linear_fit(records, third):
    # Issue 29's promises on a joint law fnsi-lab has no element for: the answer keeps the
    # linear fit's modes within 0.5 % unless it says the nonlinear model is significantly
    # better, no coefficient whose std exceeds half its value is `identified`, and on a
    # record no decision read the answer predicts no output worse than the linear fit
    # (0.5 dB: the two linear fits' orders differ by the noise of the order selection).
    config = records / "jenkins.yaml"
    config.write_text((records / "beam-linear.yaml").read_text().replace(
        "nonlinearities: []", "nonlinearities:\n  - {name: joint, kind: jenkins, "
        "channels: {jointL: 1, jointR: -1}, slip: auto}"))
    linear, answer = records / "linear-0.3.json", records / "jenkins-0.3.json"
    for cfg, out in ((records / "beam-linear.yaml", linear), (config, answer)):
        run = _cli("ident", str(records / "beam-rms0.3.npz"), "--config", str(cfg), "--auto",
                   "--json", str(out))
        assert run.returncode == 0, run.stderr
        assert "Traceback" not in run.stderr
    result = json.loads(answer.read_text())
    for c in result["coefficients"]:
        assert c["verdict"] in ("identified", "weak", "not identifiable")
        if c["relative_std"] is not None and c["relative_std"] > 0.5:
            assert c["verdict"] != "identified"
    nested = result["nonlinear_vs_linear"]
    if nested["decision"] != "nonlinear":
        linear_modes = [m["frequency_hz"] for m in json.loads(linear.read_text())["modes"]]
        for f in linear_modes:
            assert min(abs(m["frequency_hz"] - f) / f for m in result["modes"]) < 0.005
    errors = {}
    for name, path in (("linear", linear), ("answer", answer)):
        out = records / f"{name}.val.json"
        run = _cli("validate", str(path), str(third), "--json", str(out))
        assert run.returncode == 0, run.stderr
        errors[name] = [o["error_db"] if o["error_db"] is not None else o["linear_error_db"]
                        for o in json.loads(out.read_text())["outputs"]]
    assert all(a <= b + 0.5 for a, b in zip(errors["answer"], errors["linear"])), errors


def test_a_slowly_converging_balance_is_not_called_no_steady_state(tmp_path, beam, monkeypatch):
    # 3 N (joint 13x its yield displacement), periods of 2048 samples to keep it fast. A
    # Jenkins element at the Bouc-Wen law's yield displacement (40 um) draws its saturated
    # hysteresis: on another realisation it predicts every output 8-10 dB better than the
    # linear fit (measured: -23.0 / -22.9 / -18.7 / -20.4 dB against -12.6 / -13.0 / -7.6 /
    # -10.1); 5 dB is asked. With 8192-sample periods its balance took 56 Newton iterations
    # to 9e-5 and had been called "no periodic steady state" at 4e-6 (bench/RESULTS_beam.md).
    import fnsi_lab
    from fnsi_lab.ident.refine import validation

    monkeypatch.setattr(beam, "SAMPLES_PER_PERIOD", 2048)
    config = _level_and_its_twin(beam, tmp_path, "3", "slip: 4.0e-05}\ncompare_linear: true")
    run = _cli("ident", str(tmp_path / "beam-rms3.npz"), "--config", str(config), "--auto",
               "--json", str(tmp_path / "r.json"))
    assert run.returncode == 0, run.stderr
    strict = fnsi_lab.validate_model(str(tmp_path / "r.json"), str(tmp_path / "v" / "beam-rms3.npz"))
    assert strict.simulation.info["converged"] and strict.simulation.info["tolerance"] == 1e-6
    rows = strict.to_json()["outputs"]
    assert all(r["error_db"] < r["linear_fit_error_db"] - 5 for r in rows), rows
    # a residual the strict tolerance cannot reach: solved again to 1e-4, not refused
    monkeypatch.setattr(validation, "BALANCE_TOLERANCE", 1e-30)
    slow = fnsi_lab.validate_model(str(tmp_path / "r.json"), str(tmp_path / "v" / "beam-rms3.npz"))
    assert slow.simulation.info["converged"] and slow.simulation.info["tolerance"] == 1e-4
    for a, b in zip(slow.to_json()["outputs"], rows):
        assert a["error_db"] == pytest.approx(b["error_db"], abs=0.1)


def test_distortion_at_the_output_level_is_worded_without_a_signed_zero():
    # the Bouc-Wen beam at 1 N: distortion beyond the band within 0.5 dB of the band's
    # output read "-0 dB above the output"
    from fnsi_lab.ident.core.distortion import _verdict
    from fnsi_lab.ident.core.distortion_records import Evidence

    def text(output_db: float) -> str:
        hit = Evidence(kind="mixed", frequency_hz=172.0, band_hz=(170.0, 174.0), level_db=-20.0,
                       noise_db=-80.0, output_db=output_db, p_value=1e-30, significant=True,
                       in_band=False)
        return _verdict([hit], True, True, None)[0]

    assert "at the level of the output at 172 Hz" in text(-19.8)
    assert "3 dB below the output" in text(-17.0)
    assert "3 dB above the output" in text(-23.0)


def test_a_hysteretic_balance_over_thousands_of_lines_converges_in_a_few_newton_steps(
        tmp_path, beam):
    # 1 N (joint 4x its yield displacement), 8192-sample periods: the motion's energy is
    # spread over ~2600 lines, the preconditioner's dense block holds 600. With each weak
    # line's own response read as the mean slope (the stuck fraction), GMRES left 0.9 of
    # the residual after 70 iterations and the balance crawled: 60 Newton steps to 4e-5 and
    # 285 s per validation. With the stick response it converges in 5 steps (2e-11). 15
    # steps and 1e-6 separate the two with margin.
    import fnsi_lab

    config = _level_and_its_twin(beam, tmp_path, "1", "slip: 2.0e-05}")
    run = _cli("ident", str(tmp_path / "beam-rms1.npz"), "--config", str(config), "--order",
               "38", "--json", str(tmp_path / "r.json"))
    assert run.returncode == 0, run.stderr
    result = fnsi_lab.validate_model(str(tmp_path / "r.json"), str(tmp_path / "v" / "beam-rms1.npz"))
    info = result.simulation.info
    assert info["converged"] and info["residual"] < 1e-6 and info["iterations"] <= 15, info


def test_the_stick_response_is_the_exact_response_of_each_line_to_itself():
    # The preconditioner's own-line response of a hysteretic column (the elongation moves
    # by a line's change since its stick phase began) against the response the balance
    # applies (HarmonicBalance._hysteretic_response's rule), line by line.
    from fnsi_lab.ident.core.hysteresis import periodic_play_anchors
    from fnsi_lab.ident.refine.harmonic_balance import _stick_response

    n = 512
    rng = np.random.default_rng(3)
    t = np.arange(n) / n
    delta = sum(rng.normal() * np.cos(2 * np.pi * k * t + rng.uniform(0, 2 * np.pi))
                for k in range(1, 9))
    anchors = periodic_play_anchors(delta, 0.3 * np.std(delta))
    assert 0.1 < np.mean(anchors >= 0) < 0.9            # sticks and slips
    lines = np.arange(1, 40)
    stuck = (anchors >= 0)

    def response(k: int, c: complex) -> complex:
        spec = np.zeros(n // 2 + 1, complex)
        spec[k] = c * n
        x = np.fft.irfft(spec, n=n)
        moved = np.where(stuck, x - x[np.maximum(anchors, 0)], 0.0)
        return np.fft.rfft(moved)[k] / n

    # a real-linear map: c -> P c + Q conj(c); the own-line response is P
    own = np.array([(response(k, 1.0) - 1j * response(k, 1j)) / 2 for k in lines])
    np.testing.assert_allclose(_stick_response(anchors, lines), own, atol=1e-12)


def _steady_spectra(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Force and outputs averaged over the steady periods, on the excited lines 3-140 Hz:
    ``(frequency_hz (F,), U (F,), Y (F, p))``."""
    with np.load(path) as z:
        n, skip = int(z["N"]), int(z["transient_samples"])
        u = z["u"][skip:, 0].reshape(-1, n).mean(axis=0)
        y = z["y"][skip:].reshape(-1, n, z["y"].shape[1]).mean(axis=0)
        f = np.fft.rfftfreq(n, 1 / float(z["fs"]))
    U, Y = np.fft.rfft(u), np.fft.rfft(y, axis=0)
    band = (f >= 3) & (f <= 140)
    lines = band & (np.abs(U) > 0.1 * np.median(np.abs(U[band])))
    return f[lines], U[lines], Y[lines]


def test_a_linear_answer_predicts_another_realisation_as_well_as_the_record_allows(tmp_path, beam):
    # 0.002 N: the joint at 1 % of its yield displacement, linear within the 50 dB noise.
    # The floor: the identified record's own measured FRF applied to the other realisation's
    # force (it carries the noise of both records): -51.3 / -53.2 / -53.3 / -50.8 dB. FNSI's
    # C left its linear answer 10-16 dB above it (-35.0 / -43.0 / -38.8 / -40.2 dB); with C
    # and D by least squares for its poles it is -49.1 / -52.3 / -54.6 / -52.5, within 2.2
    # dB of it. 5 dB above the floor separates the two with margin.
    import fnsi_lab

    _level_and_its_twin(beam, tmp_path, "0.002", "slip: 2.0e-05}")
    run = _cli("ident", str(tmp_path / "beam-rms0.002.npz"), "--config",
               str(tmp_path / "beam-linear.yaml"), "--auto", "--json", str(tmp_path / "l.json"))
    assert run.returncode == 0, run.stderr
    check = fnsi_lab.validate_model(str(tmp_path / "l.json"), str(tmp_path / "v" / "beam-rms0.002.npz"))
    _, U1, Y1 = _steady_spectra(tmp_path / "beam-rms0.002.npz")
    _, U2, Y2 = _steady_spectra(tmp_path / "v" / "beam-rms0.002.npz")
    floor = 10 * np.log10(np.sum(np.abs(Y2 - Y1 / U1[:, None] * U2[:, None]) ** 2, axis=0)
                          / np.sum(np.abs(Y2) ** 2, axis=0))
    rows = check.to_json()["outputs"]
    assert len(rows) == floor.size
    for row, limit in zip(rows, floor):
        assert row["linear_error_db"] < limit + 5.0, (row, floor)


def test_the_slips_second_minimum_is_tried_when_the_first_leaves_the_spring_undetermined(
        tmp_path, beam):
    # The beam at 3 N alone (joint at 18x its yield displacement): the slip's information
    # criterion has two minima of nearly one value, 6.6e-3 at 498 um (the element slipping
    # 0.24 % of the period: its column nearly copies the motion) and 7.4e-3 at 32 um (near the
    # law's 40 um yield, slipping half of it). The lower one left the spring `not
    # identifiable` and the answer the linear fit; the next one gives the law's hysteretic
    # stiffness (1 - alpha) k0 = 14e3 N/m within 5 % (13.7e3) and predicts another
    # realisation 7.7-12.3 dB better than the linear fit (bench/RESULTS_beam.md, defect 6).
    # The limits: 20 % on the stiffness (the Jenkins element is not the Bouc-Wen law; its
    # standard deviation over the lines is 11 %), 3 dB on the prediction.
    # The config has a stop beside it (clearances: auto; the law has no clearance), as a lab
    # writes for a joint with friction and clearance: the joint search refused the slip, then
    # the stop on its own; the Jenkins element is now searched again on its own, takes the
    # 498 um minimum, and ends as above (the Jenkins config alone takes the same two steps
    # after the first; one run covers both, the suite's time is counted).
    import fnsi_lab

    config = _level_and_its_twin(beam, tmp_path, "3", "slip: auto}\n  - {name: gap, kind: "
                                 "trilinear, channels: {jointL: 1, jointR: -1}, clearances: auto}")
    run = _cli("ident", str(tmp_path / "beam-rms3.npz"), "--config", str(config), "--auto",
               "--json", str(tmp_path / "j.json"))
    assert run.returncode == 0, run.stderr
    doc = json.loads((tmp_path / "j.json").read_text())
    assert doc["nonlinear_vs_linear"]["decision"] == "nonlinear"
    (joint,) = doc["nonlinearities"]
    first = doc["parameter_search"]["alternatives"][0]   # the minimum it replaced
    assert 2e-5 < joint["slip"] < 6e-5 and first["value"] > 2e-4
    assert first["objective"] < doc["parameter_search"]["objective"]
    (spring,) = doc["coefficients"]
    assert spring["verdict"] == "identified" and spring["value"] == pytest.approx(14e3, rel=0.2)
    assert "next minimum" in run.stdout + run.stderr
    assert [r["name"] for r in doc["nonlinear_vs_linear"]["refused"]] == ["gap"]
    assert "'joint' was searched again on its own and kept" in run.stdout + run.stderr
    check = fnsi_lab.validate_model(str(tmp_path / "j.json"), str(tmp_path / "v" / "beam-rms3.npz"))
    for row in check.to_json()["outputs"]:
        assert row["error_db"] < row["linear_fit_error_db"] - 3.0, row
