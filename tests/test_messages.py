"""User-facing messages read as plain English, never as Python reprs (an outside probe found
``['wing', 'payload']``, ``(2.0, 15.0)`` and the like in errors and notes).

Each case runs the real command line on a bad input and checks the one-line error: it names
the values as a lab engineer would write them (``X1, X2``, ``2-15 Hz``), with no list, tuple
or dict repr, no ``None`` and no numpy scalar repr."""

from __future__ import annotations

import re

import pytest

from fnsi_lab.cli import main

#: What a Python repr leaves in a message (a list or tuple of strings, a dict, None, a numpy
#: scalar); ``[2, 15]`` as the user wrote it in YAML is allowed.
REPR = re.compile(r"\['|\('|\{'|\bNone\b|np\.float|np\.int|array\(")

#: The cubic chain's config, one top-level key each (a case replaces or adds keys).
CONFIG = {
    "band_hz": "[3, 150]",
    "transient_periods": "1",
    "output_quantity": "displacement",
    "inputs": "\n  - {name: F-X3, driving_point: X3}",
    "nonlinearities": "\n  - {name: knl, kind: polynomial, exponent: 3, channels: {X2: 1, X3: -1}}",
}


def write_config(path, **change: str):
    """CONFIG with the keys of ``change`` replaced or added, written to ``path``."""
    path.write_text("".join(f"{k}: {v}\n" for k, v in {**CONFIG, **change}.items()))
    return path


def assert_plain(message: str) -> None:
    """No Python repr in ``message``."""
    assert not REPR.search(message), message


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """The 3-DOF cubic chain (conftest.write_cubic_chain: outputs X1, X2, X3, force F-X3)."""
    from conftest import write_cubic_chain

    d = tmp_path_factory.mktemp("messages")
    write_cubic_chain(d / "chain.npz")
    return d


def run_error(capsys, args: list[str]) -> str:
    """The one-line error of ``fnsi-lab ARGS`` (exit 2), checked free of reprs."""
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0, err
    assert_plain(err)
    return err


@pytest.mark.parametrize("change, expect", [
    # a misspelt output in outputs: (was "output channel(s) ['X9'] ... (outputs: ['X1', ...])")
    ({"outputs": "[X1, X9]"}, "output channel(s) 'X9' not in the file (outputs: X1, X2, X3)"),
    # a band upside down (was "got [150.0, 3.0]")
    ({"band_hz": "[150, 3]"}, "got f_min 150, f_max 3 Hz"),
    # a band above Nyquist (was "band_hz [3.0, 400.0] ends above")
    ({"band_hz": "[3, 400]"}, "band_hz 3-400 Hz ends above the Nyquist frequency 250 Hz"),
    # a misspelt kind (was "use one of ['polynomial', 'trilinear', ...]")
    ({"nonlinearities": "[{name: k, kind: cubc, channels: {X2: 1}}]"},
     "use one of polynomial, trilinear"),
    # a misspelt channel of an element (was "outputs ['X1', 'X2', 'X3']")
    ({"nonlinearities": "[{name: k, kind: polynomial, channels: {X7: 1}}]"},
     "identified outputs X1, X2, X3"),
    # outputs given as a mapping (was "got {'X1': 1}")
    ({"outputs": "{X1: 1}"}, "got {X1: 1}"),
    # a list where a number belongs (was "got ['a', 'b']")
    ({"max_order": "[a, b]"}, "got [a, b]"),
    # a typo in a top-level key with no close match (was "known keys: ['auto', ...]")
    ({"zzzzzz": "1"}, "known keys: "),
    # an unknown auto option (was "unknown auto option(s) ['zzz']; allowed: [...]")
    ({"auto": "{zzz: 1}"}, "unknown auto option(s) zzz; allowed: "),
])
def test_ident_config_errors_name_values_in_plain_text(chain, tmp_path, capsys, change, expect):
    """Each bad config gives one line without reprs that says what was wrong, in the user's
    words; the old messages held a list/dict repr (the comment above each case)."""
    cfg = write_config(tmp_path / "c.yaml", **change)
    err = run_error(capsys, ["ident", str(chain / "chain.npz"), "--config", str(cfg),
                             "--order", "4"])
    assert expect in err


def test_plain_helpers():
    """The shared helpers: names, bands, numbers and echoed values in plain text."""
    import numpy as np

    from fnsi_lab import plain

    assert plain.names(["wing", "payload"]) == "wing, payload"
    assert plain.names(("wing",), quote=True) == "'wing'"
    assert plain.names([]) == "none"
    assert plain.names(list("abcdefg"), limit=3) == "a, b, c, ... (7 in all)"
    assert plain.band_hz((2.0, 15.0)) == "2-15 Hz"
    assert plain.band_hz(np.array([0.596, 199.7])) == "0.596-199.7 Hz"
    assert plain.number(np.float64(1 / 3)) == "0.3333"
    assert plain.number(np.int64(11264)) == "11264"
    assert plain.quantity(0.00012345678, "m") == "0.0001235 m"
    assert plain.value(["wing", 2.0]) == "[wing, 2]"
    assert plain.value({"wing": 1, "payload": -1}) == "{wing: 1, payload: -1}"
    assert plain.value(None) == "nothing"
    assert plain.weights({"wing": 1.0, "payload": -1.0}) == "wing +1, payload -1"
    assert plain.shape((11264, 2)) == "11264 x 2"


@pytest.mark.parametrize("old, new, expect", [
    # was "got [5.0, -1.0]"
    ("  rms: 5.0                # N\n", "  levels: [5, -1]\n", "every level must be an RMS > 0, got 5, -1"),
    # was "band [50.0, 5.0] is not increasing"
    ("band_hz: [5, 50]", "band_hz: [50, 5]", "band 50-5 Hz is not increasing"),
    # was "use one of ['aircraft', 'can', ...]"
    ("kind: simulated", "kind: simulatd", "use one of aircraft, can, replay, serial, simulated"),
    # was "use one of ['X1', 'X2', 'X3']"
    ("quantity: displacement", "quantity: {X9: displacement}", "use one of X1, X2, X3"),
    # was "got ['a']"
    ("phases: random", "phases: [a]", "expected text, got [a]"),
])
def test_acquire_config_errors_name_values_in_plain_text(tmp_path, capsys, old, new, expect):
    """The packaged lumped experiment with one field spoilt: one line, no repr."""
    from importlib.resources import files

    text = (files("fnsi_lab.daq") / "data" / "lumped.yaml").read_text()
    assert old in text
    cfg = tmp_path / "acq.yaml"
    cfg.write_text(text.replace(old, new))
    err = run_error(capsys, ["acquire", "--config", str(cfg), "--out", str(tmp_path / "a.mcap"),
                             "--quiet", "--no-info"])
    assert expect in err
    assert not (tmp_path / "a.mcap").exists()


def test_analyse_misspelt_output_names_it_and_the_outputs(chain, tmp_path, capsys):
    """``analyse --output`` with a name the record lacks (was "--output: --output ['X9'] not
    among the outputs ['X1', 'X2', 'X3']")."""
    err = run_error(capsys, ["analyse", str(chain / "chain.npz"), "--output", "X9",
                             "--report", str(tmp_path / "a.html"), "--quiet"])
    assert "--output: 'X9' not among the outputs (X1, X2, X3)" in err


def test_import_of_forces_only_lists_the_channels(tmp_path, capsys):
    """A CSV whose channels are all forces (was "inputs: ['F1', 'F2'], outputs: []")."""
    import numpy as np

    t = np.arange(64) / 100.0
    rows = "\n".join(f"{a:.4f},{np.sin(a):.6f},{np.cos(a):.6f}" for a in t)
    src = tmp_path / "forces.csv"
    src.write_text("time [s],F1 [N],F2 [N]\n" + rows + "\n")
    err = run_error(capsys, ["import", str(src), "--out", str(tmp_path / "r.mcap")])
    assert "(inputs: F1, F2; outputs: none)" in err


def test_ident_summary_prints_an_explicit_criterion_band_in_hz(chain, tmp_path, capsys):
    """``auto: {ic_band: [3, 60]}``: the summary's criterion line says ``band 3-60 Hz`` (was
    the tuple ``band (3.0, 60.0)``)."""
    cfg = write_config(tmp_path / "c.yaml", auto="{ic_band: [3, 60]}")
    assert main(["ident", str(chain / "chain.npz"), "--config", str(cfg), "--auto",
                 "--orders", "2:10"]) == 0
    out = capsys.readouterr().out
    line = next(s for s in out.splitlines() if s.startswith("information criterion"))
    assert "band 3-60 Hz)" in line, line
    assert_plain(out)


def test_excitation_prints_its_wav_scale_in_7_digits(tmp_path, capsys):
    """The WAV full scale as a 24-bit mantissa holds it (was the float repr,
    ``digital 1.0 = 16.146643787758904 N``); the sidecar's file.full_scale keeps every digit."""
    import json

    out = tmp_path / "d.wav"
    assert main(["excitation", "--config", "lumped", "--out", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    scale = json.loads((tmp_path / "d.json").read_text())["file"]
    m = re.search(r"digital 1\.0 = (\S+) N", text)
    assert m and len(m.group(1).replace(".", "").lstrip("0")) <= 7, text
    assert float(m.group(1)) == pytest.approx(scale["full_scale"], rel=1e-6)
    assert scale["scale"] == f"digital 1.0 = {m.group(1)} N"


def test_report_writes_a_suggested_stop_without_list_reprs():
    """The HTML report's spline section lists a suggestion's clearances as numbers (was
    ``clearances ['1.5', '1.3']``, a list of strings)."""
    import html

    import numpy as np

    from fnsi_lab.viewer.report import render_report

    x = np.linspace(-3.4, 3.4, 201)
    f = 100 * np.where(x > 1.3, x - 1.3, 0) + 120 * np.where(x < -1.5, x + 1.5, 0)
    curve = {"element": "NC2-Z", "argument": "displacement", "x": x, "force": f,
             "std": np.full(x.size, 0.5), "knots": [-2.0, -1.0, 1.0, 2.0]}
    result = {"coefficients": [{"name": "NC2-Z:x0", "value": 1.0, "curve": curve}],
              "suggestions": [{"element": "NC2-Z", "argument": "displacement",
                               "kind": "trilinear", "clearances": [1.5, 1.3],
                               "values": [120.0, 100.0], "misfit": 0.0}],
              "suggested_config": {"yaml": "nonlinearities:\n- {name: NC2-Z, kind: trilinear}\n"}}
    page = html.unescape(render_report(result))
    assert "clearances [1.5, 1.3]" in page
    assert "['" not in page


def test_replay_names_the_recorded_outputs_in_plain_text(tmp_path, capsys):
    """``replay --ident`` with an output the experiment did not record (was "its output
    channels: ['X1', 'X2', 'X3']")."""
    rec = tmp_path / "lumped.mcap"
    assert main(["acquire", "--config", "lumped", "--out", str(rec), "--quiet",
                 "--no-info"]) == 0
    capsys.readouterr()
    cfg = tmp_path / "lo.yaml"
    cfg.write_text("band_hz: [5, 50]\noutputs: [X1, X9]\n")
    err = run_error(capsys, ["replay", str(rec), "--ident", str(cfg),
                             "--rrd", str(tmp_path / "x.rrd")])
    assert "(its output channels: X1, X2, X3)" in err


def test_info_of_an_imported_record_says_what_it_does_not_declare(tmp_path, capsys):
    """An imported CSV with its period but no transient periods: ``fnsi-lab info`` said
    "declared 4, None transient"."""
    import numpy as np

    t = np.arange(4 * 256) / 1000.0
    u = np.sin(2 * np.pi * 7.8125 * t)
    src = tmp_path / "run.csv"
    src.write_text("time [s],F1 [N],X1 [m]\n"
                   + "".join(f"{a:.4f},{b:.6f},{0.1 * b:.6f}\n" for a, b in zip(t, u)))
    rec = tmp_path / "run.mcap"
    assert main(["import", str(src), "--out", str(rec), "--samples-per-period", "256"]) == 0
    capsys.readouterr()
    assert main(["info", str(rec)]) == 0
    out = capsys.readouterr().out
    assert "(declared 4, transient not declared)" in out
    assert_plain(out)


def test_report_gives_the_identified_band_in_hz(chain, tmp_path, capsys):
    """The HTML report's summary row of the band reads ``3-150 Hz`` (was ``[3.0, 150.0]``)."""
    import html

    cfg = write_config(tmp_path / "c.yaml")
    res, page = tmp_path / "r.json", tmp_path / "r.html"
    assert main(["ident", str(chain / "chain.npz"), "--config", str(cfg), "--order", "6",
                 "--json", str(res), "--quiet"]) == 0
    assert main(["report", str(res), "--out", str(page)]) == 0
    text = html.unescape(page.read_text())
    row = re.search(r"identification band hz</t[hd]><td>([^<]*)<", text)
    assert row and row.group(1) == "3-150 Hz", row
    assert_plain(re.sub(r"<(svg|script|style).*?</\1>", "", text, flags=re.S))


def test_array_file_of_mismatched_lengths_gives_sizes_not_tuples(tmp_path, capsys):
    """u and y of different lengths in an array file: "u is 100 x 1 and y 90 x 2" (was
    "u (100, 1) and y (90, 2)")."""
    import numpy as np

    src = tmp_path / "bad.npz"
    np.savez(src, u=np.ones(100), y=np.ones((90, 2)), fs=100.0, N=10)
    err = run_error(capsys, ["ident", str(src), "--order", "2"])
    assert "u is 100 x 1 and y 90 x 2" in err
    assert "(100, 1)" not in err


@pytest.mark.parametrize("args, expect", [
    (["locate", "x.npz", "--form", "xyz"], "invalid choice: 'xyz' (choose from auto, generic, jenkins)"),
    (["identt"], "invalid choice: 'identt' (choose from acquire, info, "),
])
def test_a_bad_choice_lists_the_choices_plainly(capsys, args, expect):
    """argparse's refusal of a choice (Python 3.11 wrote "(choose from 'auto', 'generic',
    ...)"): the choices as words, exit 2."""
    with pytest.raises(SystemExit) as exit_:
        main(args)
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert expect in err
    assert_plain(err)


def test_one_used_period_is_named_once(chain, tmp_path, capsys):
    """Two periods, one of them transient: "period 2 of 2 used" (was "periods 2-2 of 2")."""
    cfg = write_config(tmp_path / "c.yaml")
    assert main(["ident", str(chain / "chain.npz"), "--config", str(cfg), "--order", "4"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("periods: period 2 of 2 used; 1 configured as transient"), out[:200]


def test_validation_record_with_other_channels(chain, tmp_path, capsys):
    """``ident A --validation B`` where B lacks the identified outputs: the fix names the
    outputs and forces it needs as names (it printed ``['X1', 'X2', 'X3']``)."""
    import numpy as np

    with np.load(chain / "chain.npz") as f:
        arrays = {k: f[k] for k in f.files}
    arrays["channels"] = np.array(["A1", "A2", "A3"])
    np.savez(tmp_path / "other.npz", **arrays)
    err = run_error(capsys, ["ident", str(chain / "chain.npz"), "--config",
                             str(write_config(tmp_path / "c.yaml")), "--validation",
                             str(tmp_path / "other.npz"), "--auto"])
    assert "other.npz" in err and "X1, X2, X3" in err and "F-X3" in err


@pytest.mark.parametrize("bad_n", [1.5, 0, -4, float("nan")])
def test_an_array_file_with_a_broken_period_length(chain, tmp_path, capsys, bad_n):
    """An array file whose ``N`` is no whole number >= 1 is refused by name (``N = 1.5`` had
    become one sample per period, and the error then blamed band_hz)."""
    import numpy as np

    with np.load(chain / "chain.npz") as f:
        arrays = {k: f[k] for k in f.files}
    arrays["N"] = np.array(bad_n)
    np.savez(tmp_path / "bad.npz", **arrays)
    err = run_error(capsys, ["ident", str(tmp_path / "bad.npz"), "--auto"])
    assert "bad.npz" in err and "'N' (samples per period) must be a whole number" in err
