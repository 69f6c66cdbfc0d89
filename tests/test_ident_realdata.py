"""Identification on real and lab-realistic data (issue 11).

Real parts: the vendored Silverbox measurement (bench/data/silverbox-schroeder), the lab
simulator (daq.sim.lab: DAC hold, anti-alias filter, coloured noise, hum, offsets, one period
per realisation) and the public entry point fnsi_lab.identify.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import fnsi_lab
from fnsi_lab.daq.multisine import multisine
from fnsi_lab.daq.sim.lab import LabRealism, duffing_model, lab_experiment
from fnsi_lab.ident.core import fnsi
from fnsi_lab.ident.robust.auto_result import confidence_statement
from fnsi_lab.ident.core.basis import Nonlinearity
from fnsi_lab.ident.core.coefficients import nonlinear_coefficients, summarize_coefficients
from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.core.excitation import detect_excited_lines
from fnsi_lab.ident.core.periodic import cut_realizations, prepare_frequency_data

SILVERBOX = Path(__file__).resolve().parents[1] / "bench" / "data" / "silverbox-schroeder"
FS = 610.35
K3 = Nonlinearity("k3", "polynomial", {"y0": 1}, exponent=3)
CUBIC = {"band_hz": [0.5, 200.0], "inputs": [{"name": "u0", "driving_point": "y0"}],
         "nonlinearities": [{"name": "k3", "kind": "polynomial", "channels": {"y0": 1},
                             "exponent": 3}]}
#: the Silverbox's linear part (order-2 model of the record) with its cubic coefficient
DUFFING = (5.33e-6, 2.2e-4, 0.98, 3.9)


def _lab(R=2, N=8192, **kw):
    ms = multisine(N, FS, (0.05, 200.0), 0.03, n_realizations=R, seed=3, grid="odd")
    return lab_experiment(duffing_model(*DUFFING), ms, LabRealism(**kw), seed=3)


# ------------------------------------------------------------------------ excited lines
def test_odd_multisine_with_hum_detected_exactly():
    N = 8192
    ms = multisine(N, FS, (0.05, 200.0), 1.0, seed=1, grid="odd")
    t = np.arange(N) / FS
    # hum off the DFT grid at 50 and 150 Hz, 1 % and 0.3 % of the RMS (leaks onto neighbours)
    x = ms.signal[0] + 0.01 * np.sin(2 * np.pi * 50.0 * t + 1) + 0.003 * np.sin(2 * np.pi * 150.0 * t)
    pw = np.abs(np.fft.rfft(x)) ** 2
    g = detect_excited_lines(pw, FS, N)
    assert g.kind == "odd"
    np.testing.assert_array_equal(g.lines, ms.excited_lines)
    # the old rule (power above 1e-4 of the largest line) counts the hum too
    assert np.sum(pw > 1e-4 * pw.max()) > ms.excited_lines.size


def test_full_multisine_hum_outside_band_is_not_excitation():
    N, fs = 8192, 1000.0
    ms = multisine(N, fs, (5.0, 45.0), 100.0, seed=2)
    t = np.arange(N) / fs
    x = ms.signal[0] + 5 * np.sin(2 * np.pi * 150.3 * t) + 3 * np.sin(2 * np.pi * 60.2 * t)
    g = detect_excited_lines(np.abs(np.fft.rfft(x)) ** 2, fs, N)
    assert g.kind == "full"
    np.testing.assert_array_equal(g.lines, ms.excited_lines)


def test_shaped_design_near_mains_is_kept():
    """A design falling 20 dB across the band: lines near 50/100 Hz are judged locally."""
    N, fs = 8192, 1000.0
    k = np.arange(41, 1230)                                  # 5-150 Hz, full grid
    X = np.zeros(N // 2 + 1, complex)
    X[k] = np.exp(2j * np.pi * np.random.default_rng(1).random(k.size)) * np.logspace(0, -1, k.size)
    g = detect_excited_lines(np.abs(X) ** 2, fs, N)
    np.testing.assert_array_equal(g.lines, k)


def test_a_band_after_a_force_drop_out_is_kept():
    """A shaker's force drops by tens of dB at a lightly damped driving-point resonance and
    may stay lower above it: the band after the drop-out is still excitation, only a faint
    run far beyond the band (the force's own distortion) is not."""
    N, fs = 4096, 1024.0
    pw = np.full(N // 2 + 1, 1e-12)
    pw[10:200] = 1.0
    pw[200:203] = 1e-5            # 3 lines 50 dB down (below the 30 dB candidate level)
    pw[203:300] = 0.05            # 13 dB lower above the resonance
    g = detect_excited_lines(pw, fs, N)
    np.testing.assert_array_equal(g.lines, np.r_[10:200, 203:300])
    assert g.faint.size == 0
    pw[400:420] = 0.005           # 23 dB down, 100 lines beyond the band's end
    g = detect_excited_lines(pw, fs, N)
    np.testing.assert_array_equal(g.faint, np.arange(400, 420))
    np.testing.assert_array_equal(g.lines, np.r_[10:200, 203:300])


# ------------------------------------------------------------------------ noise, hum, layout
def test_noise_level_from_the_non_excited_lines():
    """One period per realisation: the off-grid lines give the noise variance of Y(k)."""
    N, R, sigma = 4096, 4, 1e-3
    rec = _lab(R=R, N=N)                                     # noise-free lab record
    rng = np.random.default_rng(0)
    y = rec.y + sigma * rng.standard_normal(rec.y.shape)   # white, known variance
    data = prepare_frequency_data(u=rec.u, y=y, sample_rate_hz=FS, samples_per_period=N,
                                  basis=[K3], band_hz=(0.5, 200.0), output_names=["y0"])
    assert data.noise_source == "non-excited lines"
    assert data.noise_cov is None                            # not used for weighting by default
    true_var = sigma ** 2 / N                                # of the numpy DFT / N
    est = data.noise_var[data.excited, 0]
    # median over +-16 noise lines x 4 realisations (132 values): about +-10 % (1 sigma)
    assert np.median(est) == pytest.approx(true_var, rel=0.25)
    # a full multisine leaves no off-grid line in its band: said plainly
    ms = multisine(N, FS, (0.5, 200.0), 0.03, seed=1)
    u = ms.signal[0][:, None]
    full = prepare_frequency_data(u=u, y=u + sigma * rng.standard_normal(u.shape),
                                  sample_rate_hz=FS, samples_per_period=N, band_hz=(0.5, 200.0))
    assert full.noise_source == "none" and full.noise_var is None


def test_mains_lines_left_out_only_when_hum_is_there():
    clean = _lab(R=1, N=1024, snr_db=60)
    hum = _lab(R=1, N=1024, snr_db=60, hum_hz=50.0, hum_level=0.02)
    kw = dict(sample_rate_hz=FS, samples_per_period=1024, basis=[K3], band_hz=(0.5, 200.0),
              output_names=["y0"])
    d0 = prepare_frequency_data(u=clean.u, y=clean.y, **kw)
    d1 = prepare_frequency_data(u=hum.u, y=hum.y, **kw)
    assert d0.excitation["mains_dropped_hz"] == []
    assert d1.excitation["mains_dropped_hz"] == [50.0, 150.0]
    gone = np.setdiff1d(d0.lines, d1.lines) * FS / 1024
    assert gone.size > 0 and np.all(np.minimum(abs(gone - 50), abs(gone - 150)) <= 3.1 * FS / 1024)


@pytest.mark.parametrize("hum_hz", [None, 50.0, 49.9])
def test_hum_on_a_full_multisine_is_found(hum_hz):
    """A full multisine excites every line, so no off-grid line shows the hum: the 3-DOF
    chain with a stop (5-60 Hz, processed 3-150 Hz, 8 periods, pink noise 60 dB) with hum at
    3 % of each channel's RMS gave contact stiffnesses -9 % / +32 % with the true
    clearances (50.0 Hz, synchronous with the 8 s period), -0.9 % / -1.0 % (49.9 Hz,
    drifting). The synchronous hum's jump on the excited 50 Hz line, the drifting hum's
    period-to-period spread, and the 150 Hz harmonic above the noise beyond the excitation
    find it; without those lines -0.02 % / -0.05 % and -0.21 % / -0.19 %. Without hum
    nothing is dropped (measured +0.13 % / -0.04 %)."""
    hum = hum_hz is not None
    from fnsi_lab.daq.sim import lumped_model
    from fnsi_lab.ident.config import load_ident_config, packaged_config

    model = lumped_model("trilinear")
    fs, N = 1024.0, 8192
    ms = multisine(N, fs, (5, 60), 20.0, seed=1)
    lab = LabRealism(snr_db=60, input_snr_db=60, noise_colour="pink", periods=8,
                     transient_periods=2, **(dict(hum_hz=hum_hz, hum_level=0.03) if hum else {}))
    rec = lab_experiment(model, ms, lab, seed=0)
    cfg = replace(load_ident_config(packaged_config("lumped-stop")), transient_periods=0)
    src = {"u": rec.u[0], "y": rec.y[0], "fs": fs, "N": N, "quantity": "displacement",
           "channels": list(model.measured_names), "input_channels": list(model.input_names)}
    src = {**src, "u": src["u"].reshape(-1, 1), "y": src["y"].reshape(-1, 3)}
    res = fnsi_lab.identify(src, cfg, order=6).to_json()
    assert res["excitation"]["mains_dropped_hz"] == ([50.0, 150.0] if hum else [])
    values = np.array([c["value"] for c in res["coefficients"]])
    # the 60 dB noise alone moves them by up to 0.13 %; 0.5 % leaves room for the seed
    assert np.allclose(values, (2.0e4, 1.5e4), rtol=5e-3)


def test_cut_realizations_from_one_long_record():
    N, gap = 64, 10
    parts, starts = [], []
    for r in range(3):
        starts.append(sum(p.shape[0] for p in parts))
        parts.append(np.full((gap, 2), -1.0))                # transient / pause
        parts.append(np.tile(np.arange(N, dtype=float)[:, None] + 100 * r, (2, 2)))
    x = np.concatenate(parts)
    out = cut_realizations(x, starts, N, transient_samples=gap)
    assert out.shape == (3, 2, N, 2)
    np.testing.assert_array_equal(out[2, 1, :, 0], np.arange(N) + 200)
    with pytest.raises(IdentError):
        cut_realizations(x, [5, 3], N)
    with pytest.raises(IdentError):
        cut_realizations(x, starts, N, transient_samples=gap, periods=3)


def test_offset_removed_for_an_odd_element_under_an_odd_multisine():
    """A sensor offset in y would act as y^2 and stiffness terms in y^3: removed, reported."""
    rec = _lab(R=1, N=2048)
    off = 0.2 * np.std(rec.y)
    kw = dict(sample_rate_hz=FS, samples_per_period=2048, basis=[K3], band_hz=(0.5, 200.0),
              output_names=["y0"])
    vals = []
    for y, remove in ((rec.y, None), (rec.y + off, None), (rec.y + off, False)):
        d = prepare_frequency_data(u=rec.u, y=y, remove_offsets=remove, **kw)
        m = fnsi.model_at_order(fnsi.subspace_decomposition(d, max_order=2), d, 2)
        vals.append(summarize_coefficients(nonlinear_coefficients(m, d, [K3],
                                                                  driving_point="y0"))[0].value)
        if remove is None:
            assert d.offsets["removed"] is True
    assert vals[1] == pytest.approx(vals[0], rel=1e-6)       # the offset changes nothing
    assert abs(vals[2] / vals[0] - 1) > 1e-3                  # kept, it biases c


# ------------------------------------------------------------------------ coefficients
def test_coefficient_does_not_depend_on_the_ct_reading():
    rec = _lab(R=1, N=2048, snr_db=50)
    d = prepare_frequency_data(u=rec.u, y=rec.y, sample_rate_hz=FS, samples_per_period=2048,
                               basis=[K3], band_hz=(0.5, 200.0), output_names=["y0"],
                               time_base="band-limited")
    out = {}
    for tb in ("band-limited", "zoh"):
        dtb = replace(d, time_base=tb)
        m = fnsi.model_at_order(fnsi.subspace_decomposition(dtb, max_order=2), dtb, 2)
        out[tb] = (summarize_coefficients(nonlinear_coefficients(m, dtb, [K3], driving_point="y0"))[0],
                   m.frf(np.array([68.0]))[0, 0, 0])
    # the CT readings differ (half-sample delay of the ZOH inverse) ...
    assert abs(out["zoh"][1] / out["band-limited"][1] - 1) > 1e-2
    # ... c_a, read where the data are, does not
    assert out["zoh"][0].value == pytest.approx(out["band-limited"][0].value, rel=1e-9)
    assert out["zoh"][0].to_dict()["value"] == out["zoh"][0].ls_value


# ------------------------------------------------------------------------ whole identifications
def test_silverbox_periods_one_mode_and_consistent_value():
    """Each of the 10 steady periods alone: one mode, and the cubic coefficient agrees.

    The issue's target is a spread <= 0.40 % for ``--auto`` and ``--order 2`` (the peer
    implementation: 0.42 %); measured 0.23 % and 0.19 % (bench/RESULTS.md, Real data), 1.03 %
    for --auto before the answer was re-estimated with the rows of its order.
    """
    z = np.load(SILVERBOX / "schroeder.npz")
    N = int(z["N"])
    u = z["u"].reshape(-1, 1, N, 1)
    y = z["y"].reshape(-1, 1, N, 1)
    ref = fnsi_lab.identify({"u": u[1:, 0][None], "y": y[1:, 0][None], "fs": float(z["fs"]),
                             "N": N}, CUBIC, order=2).coefficients[0]["value"]
    values = {"auto": [], "order 2": []}
    for r in range(1, 11):                                   # one steady period each
        src = {"u": u[r], "y": y[r], "fs": float(z["fs"]), "N": N}
        res = fnsi_lab.identify(src, CUBIC)
        values["order 2"].append(fnsi_lab.identify(src, CUBIC, order=2).coefficients[0]["value"])
        values["auto"].append(res.coefficients[0]["value"])
        assert len(res.modes) == 1 and 67.5 < res.modes[0]["frequency_hz"] < 69.0
        assert res.order <= 4
        if r == 1:
            j = res.to_json()
            assert j["excitation"]["grid"] == "odd"
            assert j["excitation"]["mains_dropped_hz"] == [50.0, 150.0]
            assert j["noise"]["source"] == "non-excited lines"
            assert j["offsets"]["removed"] is True
    for how, v in values.items():
        v = np.array(v)
        assert np.std(v, ddof=1) / np.mean(v) <= 0.004, how
        # one period has a tenth of the data of the 10-period reference
        assert np.mean(v) == pytest.approx(ref, rel=0.01), how


def test_total_time_counts_the_whole_identification():
    """``timings_s.total`` is the whole identification's time, not the order sweep's: the
    robust pipeline's own ``total`` (0.27 s on the GVT at 40 N) had replaced it while the
    linear fit alone took 5.9 s. On the Silverbox with the linear fit run (compare_linear:
    true), the total is at least the sum of the stages it holds."""
    z = np.load(SILVERBOX / "schroeder.npz")
    src = {"u": z["u"], "y": z["y"], "fs": float(z["fs"]), "N": int(z["N"])}
    t = fnsi_lab.identify(src, {**CUBIC, "compare_linear": True}).to_json()["timings_s"]
    assert t["linear_fit"] > 0 and t["auto"] > 0
    stages = t["linear_fit"] + t["auto"] + t["prepare"] + t["coefficients"]
    assert t["total"] >= stages, t


def test_lab_duffing_auto_answers_one_mode_near_the_truth():
    rec = _lab(R=1, dac_hold=True, antialias_order=6, snr_db=60, input_snr_db=60,
               noise_colour="pink", hum_hz=50.0, hum_level=0.03, offset=0.05)
    for r in range(1):
        src = {"u": rec.u[r], "y": rec.y[r], "fs": FS, "N": 8192}
        auto = fnsi_lab.identify(src, CUBIC)
        fixed = fnsi_lab.identify(src, CUBIC, order=2)
        assert len(auto.modes) == 1 and auto.order <= 4
        assert abs(auto.modes[0]["frequency_hz"] / 68.25 - 1) < 2e-3
        assert auto.auto.confidence["level"] != "ambiguous"
        # measured over 10 realisations: |error| <= 0.6 % (bench/RESULTS.md, Real data)
        for res in (auto, fixed):
            assert res.coefficients[0]["value"] == pytest.approx(DUFFING[3], rel=0.01)


def test_confidence_is_not_clear_when_the_answer_keeps_extra_poles():
    base = dict(kept_not_stabilised=[], dropped_fully_stable=[])
    assert confidence_statement(100.0, 1, base)["level"] == "clear"
    c = confidence_statement(100.0, 1, dict(base, extra_in_answer=1))
    assert c["level"] == "moderate" and "not physical" in c["statement"]
    assert confidence_statement(100.0, 1, dict(base, unresolved=[50.0]))["level"] == "moderate"


def test_simulated_source_lab_disturbances_from_the_experiment_yaml():
    """source.options.lab: pink noise, hum and offsets on every recorded channel."""
    import yaml

    from fnsi_lab.daq.config import parse_experiment
    from fnsi_lab.daq.sim.source import SimulatedSource

    base = yaml.safe_load((Path(__file__).resolve().parents[1] / "daq" / "data"
                           / "lumped.yaml").read_text())
    base["excitation"].update(periods=3, transient_periods=2, realizations=1)
    src = {}
    for label, lab in (("clean", None), ("lab", {"noise_colour": "pink", "hum_hz": 50,
                                                  "hum_level": 0.05, "offset": 0.1})):
        cfg = dict(base)
        cfg["source"] = {"kind": "simulated",
                         "options": dict(base["source"]["options"], snr_db=60,
                                         **({"lab": lab} if lab else {}))}
        s = SimulatedSource.from_config(parse_experiment(cfg))
        src[label] = (s.simulate_realization(0), [c.name for c in s._channels])
    clean, lab = src["clean"][0], src["lab"][0]
    n = 4096
    per = lab[-n:] - clean[-n:]
    rms = np.sqrt(np.mean(clean[-n:] ** 2, axis=0))
    # offset: 10 % of each channel's RMS (the hum and noise average out over the period)
    np.testing.assert_allclose(per.mean(axis=0) / rms, 0.1, atol=0.01)
    # hum: the 50 Hz line (on the grid: 1000 Hz / 4096 * 204.8 -> leaks) stands out
    spec = np.abs(np.fft.rfft(per - per.mean(axis=0), axis=0))
    k50 = int(round(50 * n / 1000))
    assert np.all(spec[k50 - 1:k50 + 2].max(axis=0) > 20 * np.median(spec, axis=0))


def test_user_arrays_with_realization_starts_and_excited_lines():
    """One long record (pauses between realisations) and the excited lines in the file."""
    rec = _lab(R=2, N=1024, snr_db=60)
    gap, N = 300, 1024
    u = np.concatenate([np.concatenate([np.zeros((gap, 1)), np.tile(rec.u[r, 0], (2, 1))])
                        for r in range(2)])
    y = np.concatenate([np.concatenate([np.zeros((gap, 1)), np.tile(rec.y[r, 0], (2, 1))])
                        for r in range(2)])
    src = {"u": u, "y": y, "fs": FS, "N": N, "realization_starts": [0, gap + 2 * N],
           "transient_samples": gap + N, "excited_lines": rec.excited_lines}
    res = fnsi_lab.identify(src, CUBIC, order=2)
    j = res.to_json()
    assert j["n_realizations"] == 2 and j["n_periods"] == 1
    assert j["excitation"]["source"] == "given" and j["excitation"]["grid"] == "odd"
    assert j["time_base_choice"]["chosen"] in ("band-limited", "bilinear")
    assert res.coefficients[0]["value"] == pytest.approx(DUFFING[3], rel=0.01)
    with pytest.raises(fnsi_lab.errors.FnsiLabError):
        fnsi_lab.identify(dict(src, excited_lines=[0, 5]), CUBIC, order=2)
