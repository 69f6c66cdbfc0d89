"""Defects an outside probe of the command line found (2026-11-28), each kept fixed: a crash
on a duplicated basis element, the band of an array file without a config, the order sweep
a short record cannot hold, a misspelt driving point or candidate channel, options that
contradict each other, and a summary that printed another answer than the result file."""

import json
import re

import numpy as np
import pytest

import fnsi_lab
from fnsi_lab.cli import main
from fnsi_lab.errors import FnsiLabError

CONFIG = """\
band_hz: [3, 150]
transient_periods: 1
output_quantity: displacement
inputs:
  - {name: F-X3, driving_point: X3}
nonlinearities:
  - {name: knl, kind: polynomial, exponent: 3, channels: {X2: 1, X3: -1}}
"""


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """The 3-DOF cubic chain (conftest.write_cubic_chain), 2 periods, and its config."""
    from conftest import write_cubic_chain

    d = tmp_path_factory.mktemp("probes")
    write_cubic_chain(d / "chain.npz")
    (d / "cubic.yaml").write_text(CONFIG)
    return d


def test_auto_summary_prints_the_answer_of_the_file(chain, tmp_path, capsys):
    """Every coefficient row marked as the answer prints the JSON's value and verdict (the
    Silverbox's summary had printed the sweep's 3.98159 where the file says 3.97128)."""
    out = tmp_path / "r.json"
    assert main(["ident", str(chain / "chain.npz"), "--config", str(chain / "cubic.yaml"),
                 "--auto", "--orders", "2:16", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    doc = json.loads(out.read_text())
    marked = [line for line in text.splitlines() if "<- answer" in line]
    assert len(marked) == len(doc["coefficients"]) == 1
    (c,) = doc["coefficients"]
    value = float(re.search(r"value (\S+)", marked[0]).group(1))
    assert value == pytest.approx(c["value"], rel=1e-5)
    assert f"[{c['verdict']}" in marked[0]


def test_a_duplicated_element_is_not_identifiable_not_a_crash(chain, tmp_path):
    """The same element twice: its columns are collinear (variance inflation infinite), the
    coefficients not identifiable; it was a ZeroDivisionError."""
    cfg = tmp_path / "dup.yaml"
    cfg.write_text(CONFIG + "  - {name: knl2, kind: polynomial, exponent: 3, "
                            "channels: {X2: 1, X3: -1}}\n")
    res = fnsi_lab.identify(str(chain / "chain.npz"), str(cfg), order=6).to_json()
    assert [c["verdict"] for c in res["coefficients"]] == ["not identifiable"] * 2
    assert all("collinear" in c["verdict_reason"] for c in res["coefficients"])


def test_array_file_without_config_processes_the_excited_band(chain):
    """No config and no excited lines in the file: the band is the drive's multisine (3-60
    Hz), not 0 Hz to Nyquist."""
    res = fnsi_lab.identify(str(chain / "chain.npz"), order=6).to_json()
    lo, hi = res["band_hz"]
    assert lo == pytest.approx(3.0, abs=0.15) and hi == pytest.approx(60.0, abs=0.15)
    assert res["n_lines"] == res["n_excited_lines"]


def test_the_order_sweep_stops_where_the_lines_do():
    """One output, 323 lines and a 12-knot spline (13 extended inputs: the Silverbox with
    `nonlinearities: auto`): the default sweep to 60 needs 61 block rows, 854 > 646 real
    columns, which stopped the identification. The sweep is cut at the largest order the
    lines hold (45: 46 block rows x 14 = 644), with a warning; the SmallSat's 2008 lines and
    39 outputs keep the whole sweep."""
    from types import SimpleNamespace

    from fnsi_lab.ident.fit import _feasible_sweep

    def session(lines, m_e, p):
        return SimpleNamespace(data=SimpleNamespace(n_lines=lines, n_extended_inputs=m_e,
                                                    n_outputs=p), warnings=[])

    s = session(323, 13, 1)
    kept = _feasible_sweep(s, range(2, 61), None)
    assert kept[-1] == 45 and kept[0] == 2
    assert s.warnings == ["order sweep cut at 45 (asked up to 60): 323 lines hold no more "
                          "with 13 extended inputs (fewer basis columns, e.g. knots, or a "
                          "wider band allow more)"]
    big = session(2008, 3, 39)
    assert _feasible_sweep(big, range(2, 61), None) == list(range(2, 61)) and not big.warnings


def test_misspelt_names_are_refused_naming_them(chain, tmp_path):
    """A driving point or a candidate channel that is no output: one line naming it and the
    outputs (the driving point used to pass unseen without a basis; the candidate ended in an
    internal message)."""
    cfg = tmp_path / "dp.yaml"
    cfg.write_text(CONFIG.replace("driving_point: X3", "driving_point: X9").replace(
        "nonlinearities:\n  - {name: knl, kind: polynomial, exponent: 3, "
        "channels: {X2: 1, X3: -1}}\n", "nonlinearities: []\n"))
    with pytest.raises(FnsiLabError, match=r"driving_point 'X9' is not an output"):
        fnsi_lab.identify(str(chain / "chain.npz"), str(cfg), order=6)
    cands = tmp_path / "cands.yaml"
    cands.write_text("- {channels: {X2: 1, X33: -1}}\n")
    with pytest.raises(FnsiLabError, match=r"cands.yaml: candidate .*X33 not among the outputs"):
        fnsi_lab.locate(str(chain / "chain.npz"), str(chain / "cubic.yaml"), candidates=cands,
                        order=6)
    # the file's format is accepted as a list too
    loc = fnsi_lab.locate(str(chain / "chain.npz"), str(chain / "cubic.yaml"), form="generic",
                          candidates=[{"channels": {"X2": 1, "X3": -1}}, {"X1": 1}],
                          order=6, refine=0)
    assert {c.name for c in loc.candidates} == {"X2 - X3", "X1"}


def test_contradicting_options_are_refused_before_any_work(chain, tmp_path, capsys):
    npz, cfg = str(chain / "chain.npz"), str(chain / "cubic.yaml")
    assert main(["ident", npz, "--config", cfg, "--auto", "--order", "6"]) == 2
    assert "--order and --auto" in capsys.readouterr().err
    same = tmp_path / "same.out"
    assert main(["ident", npz, "--config", cfg, "--order", "6", "--json", str(same),
                 "--suggest", str(same)]) == 2
    assert "both name" in capsys.readouterr().err and not same.exists()
    out = tmp_path / "r.json"
    assert main(["ident", npz, "--config", cfg, "--order", "6", "--json", str(out),
                 "--suggest", str(tmp_path / "s.yaml")]) == 2
    assert "--suggest needs a kind: spline" in capsys.readouterr().err
    assert not out.exists()      # refused before the identification, nothing half-written


def test_export_refuses_one_name_for_the_uff_file_and_the_csv_folder(chain, tmp_path, capsys):
    """`export --uff X --csv X` wrote the UFF file, then failed on the folder (exit 2 after
    writing): now refused before anything is written."""
    res = tmp_path / "r.json"
    assert main(["ident", str(chain / "chain.npz"), "--config", str(chain / "cubic.yaml"),
                 "--order", "6", "--json", str(res), "--quiet"]) == 0
    target = tmp_path / "out.uff"
    assert main(["export", str(res), "--uff", str(target), "--csv", str(target)]) == 2
    assert "both name" in capsys.readouterr().err and not target.exists()


def test_a_spline_is_ordered_by_the_criterion_alone(chain, tmp_path):
    """The coefficient-consistency gate reads the split between force and basis columns; a
    spline's hinge slopes spread with the curve's shape and the gate kept degenerate low
    orders (docs/robust.md): with a spline the selected order is the criterion's."""
    cfg = tmp_path / "spline.yaml"
    cfg.write_text(CONFIG.replace("kind: polynomial, exponent: 3", "kind: spline, knots: 6"))
    res = fnsi_lab.identify(str(chain / "chain.npz"), str(cfg), orders="2:16").to_json()
    assert res["order_selection"] == "ic" and res["selected_order"] == res["ic_order"]
    cubic = fnsi_lab.identify(str(chain / "chain.npz"), str(chain / "cubic.yaml"),
                              orders="2:16").to_json()
    assert cubic["order_selection"] == "consistent"
