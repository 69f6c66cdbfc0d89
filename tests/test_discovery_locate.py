"""fnsi-lab locate: candidate locations of a nonlinearity ranked by the distortion they explain.

Real recordings (the simulated SmallSat and the aircraft-like GVT, acquired by the CLI) and
subprocess CLI runs; docs/discovery.md, "Localisation".
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import fnsi_lab
from fnsi_lab.ident.locate import (candidate_locations, channel_direction, generic_columns,
                                   read_candidates_file)

CLI = [sys.executable, "-m", "fnsi_lab"]
GVT_CONFIG = """\
band_hz: [2, 15]
transient_periods: 1
output_quantity: acceleration
inputs:
  - {name: F-shaker, driving_point: drive}
nonlinearities: []
max_order: 30
"""


def _run(*args, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run(CLI + [str(a) for a in args], capture_output=True, text=True,
                          cwd=cwd, env={"OPENBLAS_NUM_THREADS": "1", **_env()})


def _env() -> dict:
    import os
    return {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}


@pytest.fixture(scope="module")
def smallsat(tmp_path_factory):
    path = tmp_path_factory.mktemp("smallsat") / "ss.mcap"
    r = _run("acquire", "--out", path)
    assert r.returncode == 0, r.stderr
    return path


@pytest.fixture(scope="module")
def gvt(tmp_path_factory):
    """The aircraft-like GVT at 12 N (joint stuck: linear) and 98 N (slipping, in contact)."""
    folder = tmp_path_factory.mktemp("gvt")
    out = {}
    for level in (12, 98):
        path = folder / f"a{level}.mcap"
        r = _run("acquire", "--config", "aircraft", "--level", level, "--out", path)
        assert r.returncode == 0, r.stderr
        out[level] = path
    cfg = folder / "linear.yaml"
    cfg.write_text(GVT_CONFIG)
    out["config"] = cfg
    return out


def test_candidates_are_channels_and_same_direction_pairs():
    names = ["A-X", "A-Z", "B-Z", "C_Z", "D:+Z"]
    assert channel_direction("NC2W-Z") == "Z" and channel_direction("wing") is None
    pairs = candidate_locations(names, "pairs")
    # A-X pairs with nothing; the four Z channels give 6 pairs, each +1/-1
    assert len(pairs) == 6 and all(sorted(p.values()) == [-1.0, 1.0] for p in pairs)
    assert len(candidate_locations(names, "channels")) == 5
    assert len(candidate_locations(names, "all")) == 11
    # names without a direction: every pair is a candidate (3 channels -> 3 pairs)
    assert len(candidate_locations(["drive", "wing", "payload"], "all")) == 6


def test_generic_columns_hold_nothing_linear():
    """The part linear in (1, x, v) is the linear model's: removed, so an output read as an
    input cannot 'explain' the outputs; a candidate without relative motion gets zeros."""
    t = np.linspace(0, 1, 4096, endpoint=False)[None]
    x = np.sin(2 * np.pi * 3 * t) + 0.3 * np.sin(2 * np.pi * 7 * t)
    v = np.gradient(x, axis=1)
    h = generic_columns(x, v)
    lin = np.stack([np.ones_like(x[0]), x[0] - x[0].mean(), v[0] / np.abs(v).max()], axis=1)
    assert np.abs(lin.T @ h[0]).max() < 1e-8 * h.size   # orthogonal to 1, x and v
    np.testing.assert_allclose(np.sqrt(np.mean(h ** 2, axis=(0, 1))), 1.0, rtol=1e-12)
    assert not np.any(generic_columns(np.zeros_like(x), np.zeros_like(v)))


def test_candidates_file_errors_name_the_file(tmp_path):
    bad = tmp_path / "c.yaml"
    bad.write_text("- {channels: {A: 0}}\n")
    with pytest.raises(fnsi_lab.ident.errors.IdentError, match="c.yaml"):
        read_candidates_file(str(bad))
    good = tmp_path / "g.yaml"
    good.write_text("candidates:\n  - {channels: {A: 1, B: -1}}\n  - {C: 1}\n")
    assert read_candidates_file(str(good)) == [{"A": 1.0, "B": -1.0}, {"C": 1.0}]


def test_smallsat_locates_the_nc2_axial_pair(smallsat, tmp_path):
    """All 273 candidates (39 channels to ground, 3 x 78 same-direction pairs): the stop
    between NC2W-Z and NC2B-Z comes first. The bracket points NC1B/NC3B/NC4B move 3 % of
    the wheel point and the stop's relative motion differs from theirs by about 1 %: the
    measured margin to the next is 2.7 % of residual, so the assertion is on the rank and on
    a margin of at least 1 %, not on the exact ratio."""
    out = tmp_path / "where.json"
    r = _run("locate", smallsat, "--config", "smallsat39", "--json", out)
    assert r.returncode == 0, r.stderr
    assert "located: NC2W-Z - NC2B-Z" in r.stdout
    res = json.loads(out.read_text())
    cands = res["candidates"]
    assert len(cands) == 39 + 3 * 78
    best = cands[0]
    assert best["channels"] == {"NC2W-Z": 1.0, "NC2B-Z": -1.0}
    assert best["verdict"] == "located" and best["stage"] == "fnsi"
    assert cands[1]["rss_ratio_to_best"] > 1.01
    # refined candidates first, each sorted; every key documented in docs/discovery.md
    refined = cands[:res["refined"]]
    assert [c["rss_ratio_to_best"] for c in refined] == sorted(c["rss_ratio_to_best"]
                                                               for c in refined)
    assert set(best) >= {"channels", "score", "significance", "verdict", "stage"}
    # a second run refuses to overwrite the result (exit 2, one line naming the option)
    r2 = _run("locate", smallsat, "--config", "smallsat39", "--json", out)
    assert r2.returncode == 2 and "--json" in r2.stderr


def test_aircraft_gvt_joint_located_at_98N_and_nothing_at_12N(gvt):
    """3 accelerometers (drive, wing, payload) and their pairs. At 98 N the friction +
    clearance joint slips and touches: the wing-payload pair must come first and be located.
    At 12 N the joint never slips (docs/aircraft.md: the record is linear): no candidate may
    be located, whatever the ranking (that is the test that the significance is not a
    threshold tuned to the nonlinear case)."""
    hi = fnsi_lab.locate(gvt[98], gvt["config"], form="generic")
    assert hi.candidates[0].channels == {"wing": 1.0, "payload": -1.0}
    assert hi.located is not None and hi.located.name == "wing - payload"
    lo = fnsi_lab.locate(gvt[12], gvt["config"])     # form auto: both forms, nothing located
    assert lo.located is None and lo.form == "generic"
    assert all(c.verdict == "not significant" for c in lo.candidates[:lo.refined])
    assert any(w.startswith("form auto: a Jenkins element") for w in lo.warnings)


def test_form_auto_offers_few_candidates_a_jenkins_element_first(gvt, tmp_path):
    """6 candidates (3 channels and their pairs): the default form tries the stick-slip
    element first and keeps its ranking when it locates the joint (a test on other periods);
    `nonlinearities: auto` then puts its spline there."""
    loc = fnsi_lab.locate(gvt[98], gvt["config"])
    assert loc.form == "jenkins" and loc.to_json()["form"] == "jenkins"
    assert loc.located is not None and loc.located.name == "wing - payload"
    assert loc.candidates[0].stage == "stick-slip" and loc.candidates[0].slip > 0
    cfg = tmp_path / "auto.yaml"
    cfg.write_text(GVT_CONFIG.replace("nonlinearities: []", "nonlinearities: auto"))
    res = fnsi_lab.identify(gvt[98], str(cfg)).to_json()
    (element,) = res["nonlinearities"]
    assert element["kind"] == "spline"
    assert element["channels"] == {"wing": 1.0, "payload": -1.0}
    assert res["localisation"]["form"] == "jenkins"
    # a friction joint's displacement curve is not determined by the data: no clearance is
    # read off it (it suggested a 4 um gap at 84 N), the located Jenkins element is offered
    assert all(c["verdict"] == "not identifiable" for c in res["coefficients"])
    (suggestion,) = res["suggestions"]
    assert suggestion["kind"] == "jenkins" and suggestion["slip"] > 0
    (item,) = res["suggested_config"]["config"]["nonlinearities"]
    assert item == {"name": element["name"], "kind": "jenkins",
                    "channels": {"wing": 1, "payload": -1}, "slip": "auto"}


def test_nonlinearities_auto_with_nothing_located_answers_linear(gvt, tmp_path):
    """`nonlinearities: auto` on the linear 12 N record: nothing is located, so the answer
    is the linear fit (exit 0), with the localisation and one line saying why; it used to
    stop with an error and lose the linear answer."""
    cfg = tmp_path / "auto.yaml"
    cfg.write_text(GVT_CONFIG.replace("nonlinearities: []", "nonlinearities: auto"))
    out, sugg = tmp_path / "auto.json", tmp_path / "sugg.yaml"
    r = _run("ident", gvt[12], "--config", cfg, "--auto", "--json", out, "--suggest", sugg)
    assert r.returncode == 0, r.stderr
    # no element, no shape: the suggestion is skipped with a note, the result is written
    assert not sugg.exists() and "--suggest: nothing written" in r.stderr
    res = json.loads(out.read_text())
    nvl = res["nonlinear_vs_linear"]
    assert nvl["test"] == "localisation" and nvl["decision"] == "linear"
    assert res["nonlinearities"] == [] and res["coefficients"] == []
    assert all(c["verdict"] != "located" for c in res["localisation"]["candidates"])
    assert len(res["modes"]) >= 6     # the stuck structure's modes in 2-15 Hz (9 in truth)
    assert "the answer is the linear fit" in r.stdout


def test_candidates_from_a_file_through_the_cli(gvt, tmp_path):
    cands = tmp_path / "cands.yaml"
    cands.write_text("- {channels: {wing: 1, payload: -1}}\n- {channels: {drive: 1}}\n")
    out = tmp_path / "r.json"
    r = _run("locate", gvt[98], "--config", gvt["config"], "--candidates", cands,
             "--json", out)
    assert r.returncode == 0, r.stderr
    res = json.loads(out.read_text())
    assert [c["name"] for c in res["candidates"]] == ["wing - payload", "drive"]
    bad = _run("locate", gvt[98], "--config", gvt["config"], "--candidates",
               tmp_path / "missing.yaml")
    assert bad.returncode == 2 and "missing.yaml" in bad.stderr


def test_noisy_smallsat_with_periods_still_locates_the_stop(tmp_path):
    """40 dB white noise on every channel, 4 steady periods (the noise estimate weights the
    screen and the refinement; a full covariance from 4 periods is rank-deficient, so the
    variances are used): the NC2 pair stays first and located (the screen put it 8th of
    273, the refinement of the best 12 first; the next residual measured 1.019x). (One steady period has no noise estimate: then noisy,
    barely moving channels win, docs/discovery.md "Limits".)"""
    from fnsi_lab.daq.config import packaged_experiment

    text = packaged_experiment("smallsat.yaml").read_text()
    text = text.replace("snr_db: null", "snr_db: 40").replace("periods: 6", "periods: 9")
    exp = tmp_path / "ss40.yaml"
    exp.write_text(text)
    rec = tmp_path / "ss40.mcap"
    r = _run("acquire", "--config", exp, "--out", rec)
    assert r.returncode == 0, r.stderr
    loc = fnsi_lab.locate(rec, "smallsat39")
    assert loc.weighted
    assert loc.candidates[0].channels == {"NC2W-Z": 1.0, "NC2B-Z": -1.0}
    assert loc.located is not None
