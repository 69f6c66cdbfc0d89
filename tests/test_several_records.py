"""Several records of one structure identified together (`fnsi-lab ident A B C`,
`fnsi_lab.identify([A, B, C])`): the records are the realisations of one input, so one model
(one underlying linear model, one coefficient) answers for every level."""

import json

import numpy as np
import pytest

import fnsi_lab
from fnsi_lab.cli import main
from fnsi_lab.errors import FnsiLabError

from test_cli_probes import CONFIG  # noqa: E402  (the chain's config, cubic X2 - X3)


@pytest.fixture(scope="module")
def levels(tmp_path_factory):
    """The 3-DOF chain with its relative cubic spring (k3 = 1e9 N/m^3) at 10 and 30 N RMS,
    other multisine phases per level, 3 periods of 4096 at 500 Hz, 60 dB noise; and a
    record of another period length."""
    from conftest import write_cubic_chain

    d = tmp_path_factory.mktemp("levels")
    for k, rms in enumerate((10.0, 30.0)):
        write_cubic_chain(d / f"l{k}.npz", rms=rms, periods=3, seed=k + 1, noise=1e-3)
    with np.load(d / "l0.npz") as z:      # the same channels, 2048-sample periods
        np.savez(d / "short.npz", **{k: z[k] for k in z.files if k != "N"}, N=2048)
    (d / "cubic.yaml").write_text(CONFIG.replace("[3, 150]", "[3, 60]"))
    return d


def test_two_levels_give_one_model(levels, tmp_path, capsys):
    """Through the command line: both records are realisations of one identification; the
    cubic coefficient comes out within 1 % of the truth (60 dB noise: measured on each
    level alone within 0.1-0.3 %), the result names both records."""
    out = tmp_path / "both.json"
    assert main(["ident", str(levels / "l0.npz"), str(levels / "l1.npz"), "--config",
                 str(levels / "cubic.yaml"), "--order", "6", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["n_realizations"] == 2
    assert doc["input"] == f"{levels / 'l0.npz'} + {levels / 'l1.npz'}"
    (c,) = doc["coefficients"]
    assert c["value"] == pytest.approx(1.0e9, rel=0.01) and c["verdict"] == "identified"


def test_records_of_another_plan_are_refused(levels):
    """Another period length: one line naming the record and the fix, before any work."""
    with pytest.raises(FnsiLabError, match=r"short.npz: 6 period\(s\) of 2048 samples, .*l0.npz: 3 of 4096"):
        fnsi_lab.identify([str(levels / "l0.npz"), str(levels / "short.npz")],
                          str(levels / "cubic.yaml"), order=6)


def test_levels_locate_together(levels, capsys):
    """`fnsi-lab locate A B`: the candidates judged on both levels at once; the cubic spring
    between X2 and X3 comes first and is located."""
    out = levels / "where.json"
    assert main(["locate", str(levels / "l0.npz"), str(levels / "l1.npz"), "--config",
                 str(levels / "cubic.yaml"), "--form", "generic", "--order", "6",
                 "--json", str(out), "--force"]) == 0
    best = json.loads(out.read_text())["candidates"][0]
    assert best["name"] == "X2 - X3" and best["verdict"] == "located"


def test_records_that_cannot_be_one_input_are_refused(levels, tmp_path):
    """The same file twice (its noise counted as independent twice), another multisine grid
    in a file that does not declare its lines (the drive carries no power on half of the
    declared grid), other declared units: one line naming the record, before any work."""
    from fnsi_lab.ident.core.io import input_from_arrays, stack_records
    from fnsi_lab.inputs import load_input

    cfg = str(levels / "cubic.yaml")
    with pytest.raises(FnsiLabError, match=r"l0.npz: given twice"):
        fnsi_lab.identify([str(levels / "l0.npz")] * 2, cfg, order=6)
    base = load_input(str(levels / "l0.npz"))
    declared = replace_lines(base, np.arange(25, 492))          # 3-60 Hz on 4096 at 500 Hz
    with np.load(levels / "l1.npz") as z:
        u = np.fft.rfft(z["u"][:, 0].reshape(-1, 4096), axis=1)
        u[:, 1::2] = 0                                            # odd lines gone
        odd = {**{k: z[k] for k in z.files}, "u": np.fft.irfft(u, n=4096, axis=1).reshape(-1, 1)}
    with pytest.raises(FnsiLabError, match=r"excites other lines than"):
        stack_records([declared, input_from_arrays(odd, "odd.npz")])
    # the other level's file, undeclared, drives every declared line: stacked
    assert stack_records([declared, load_input(str(levels / "l1.npz"))]).u.shape[0] == 2
    other = load_input(str(levels / "l1.npz"))
    mm = _with_units(declared, "mm")
    m = _with_units(other, "m")
    with pytest.raises(FnsiLabError, match=r"channel X1 in m, .* in mm"):
        stack_records([mm, m])


def replace_lines(inp, lines):
    from dataclasses import replace

    return replace(inp, excited_lines=np.asarray(lines))


def _with_units(inp, unit):
    from dataclasses import replace

    return replace(inp, channel_units={c: unit for c in inp.output_channels})


def test_a_validation_record_with_nothing_to_predict_is_refused(levels, tmp_path):
    """`validation=` a file of one period (its only period the transient one): refused before
    any work, where it used to end as a model "without a steady state"."""
    with np.load(levels / "l1.npz") as z:
        np.savez(tmp_path / "one.npz", **{k: z[k] for k in z.files if k not in ("u", "y")},
                 u=z["u"][:4096], y=z["y"][:4096])
    with pytest.raises(FnsiLabError, match=r"one.npz: 1 period\(s\) .* none left to predict"):
        fnsi_lab.identify(str(levels / "l0.npz"), str(levels / "cubic.yaml"), order=6,
                          validation=str(tmp_path / "one.npz"))


def test_validation_records_not_used_and_a_period_mismatch_say_so_plainly(levels, tmp_path):
    """`validation=[A, B]` with `compare_linear: false`: the warning names both records in
    plain words ("records A and B were not used", not "record A, B was"); a validation
    record of another period length names the fix."""
    cfg = tmp_path / "nocompare.yaml"
    cfg.write_text((levels / "cubic.yaml").read_text() + "compare_linear: false\n")
    with np.load(levels / "l1.npz") as z:
        np.savez(tmp_path / "l2.npz", **{k: z[k] for k in z.files})
    r = fnsi_lab.identify(str(levels / "l0.npz"), str(cfg), order=6,
                          validation=[str(levels / "l1.npz"), str(tmp_path / "l2.npz")])
    (line,) = [w for w in r.to_json()["warnings"] if "not used" in w]
    assert line.startswith(f"the validation records {levels / 'l1.npz'} and "
                           f"{tmp_path / 'l2.npz'} were not used: compare_linear: false"), line
    fixed = tmp_path / "fixed.yaml"
    fixed.write_text((levels / "cubic.yaml").read_text() + "samples_per_period: 4096\n")
    with pytest.raises(FnsiLabError, match=r"short.npz: N=2048 in the file but "
                                           r"samples_per_period=4096 \(fix: "):
        fnsi_lab.identify(str(levels / "l0.npz"), str(fixed), order=6,
                          validation=str(levels / "short.npz"))


def test_every_mismatch_of_every_record_is_named_at_once(levels):
    """Two records that differ from the first in different ways (another sample rate;
    another output quantity and another channel set): one line naming each record and each
    mismatch, so the user mends them all in one go."""
    from dataclasses import replace

    from fnsi_lab.ident.core.io import stack_records
    from fnsi_lab.inputs import load_input

    base = load_input(str(levels / "l0.npz"))
    other = load_input(str(levels / "l1.npz"))
    fast = replace(other, sample_rate_hz=2 * other.sample_rate_hz, path="fast.npz")
    velocity = replace(other, output_quantity="velocity", path="vel.npz",
                       output_channels=tuple(f"V{i}" for i, _ in enumerate(other.output_channels)))
    if base.output_quantity is None:
        base = replace(base, output_quantity="displacement")
    with pytest.raises(FnsiLabError) as err:
        stack_records([base, fast, velocity])
    text = str(err.value)
    assert "\n" not in text
    assert "fast.npz: sampled at" in text
    assert "vel.npz: velocity outputs" in text and "vel.npz: " in text.split("velocity outputs")[1]
