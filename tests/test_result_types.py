"""The typed, frozen result (ident.core.result, ident.pipeline.Identification; issue 28 item 3):
records read as attributes and as read-only mappings, the identification is never patched,
and to_json() writes the records' fields as the documented keys. Data: the 3-DOF chain with
a relative cubic spring (daq.sim.lumped), 1 % output noise, order 6.
"""

from __future__ import annotations

import dataclasses
from functools import lru_cache

import numpy as np
import pytest

import fnsi_lab
from fnsi_lab.daq.multisine import multisine
from fnsi_lab.daq.sim import lumped_model, simulate
from fnsi_lab.ident.pipeline import Identification
from fnsi_lab.ident.core.result import Coefficient, Mode
from fnsi_lab.outputs import json_safe

FS, N, PERIODS = 1024.0, 4096, 4
CUBIC = {"band_hz": [3, 120], "transient_periods": 1,
         "inputs": [{"name": "F", "driving_point": "X3"}],
         "nonlinearities": [{"name": "knl", "kind": "polynomial", "exponent": 3,
                             "channels": {"X2": 1, "X3": -1}, "truth": 1.0e9}]}
#: the documented keys of a coefficient in the result JSON, in their order (docs/ident.md)
COEFFICIENT_KEYS = ["name", "value", "estimate", "value_error_percent", "mean_real",
                    "std_real", "log10_re_im", "ls_value", "error_percent", "ls_error_percent",
                    "n_lines", "n_antiresonance_lines", "band", "verdict", "verdict_reason",
                    "relative_std", "spread"]


def _arrays() -> dict:
    ms = multisine(N, FS, (3, 60), 5.0, n_periods=PERIODS + 1, seed=11)
    u = ms.signal[0][:, None]
    y = simulate(lumped_model("cubic"), u, FS, periodic=N,
                 quantities=("displacement",)).displacement
    y = y + 0.01 * y.std(axis=0) * np.random.default_rng(5).standard_normal(y.shape)
    return {"u": u, "y": y, "fs": FS, "N": N, "channels": np.array(["X1", "X2", "X3"]),
            "input_channels": np.array(["F"])}


@lru_cache(maxsize=None)
def chain() -> Identification:
    return fnsi_lab.identify(_arrays(), CUBIC, order=6)


def test_identification_is_frozen_and_typed():
    r = chain()
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.model = None  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.output_error = None  # type: ignore[misc]
    assert r.method == "order" and r.decomposition is not None and r.auto is None
    assert all(isinstance(m, Mode) for m in r.modes)
    assert all(isinstance(c, Coefficient) for c in r.coefficients)
    # the lists are the caller's: changing one leaves the answer alone
    r.modes.clear()
    assert len(r.modes) == 3   # the chain's three modes


def test_mode_reads_as_attributes_and_as_a_mapping():
    m = chain().modes[0]
    assert m["frequency_hz"] == m.frequency_hz and m.get("damping_ratio") == m.damping_ratio
    assert list(m) == ["frequency_hz", "damping_ratio", "stable", "shape"] and len(m) == 4
    assert "shape" in m and "unit" not in m and m.get("unit") is None
    assert m["shape"].dtype.kind == "c" and m["shape"].shape == (3,)
    with pytest.raises(TypeError):
        m["frequency_hz"] = 1.0  # type: ignore[index]
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.frequency_hz = 1.0  # type: ignore[misc]
    with pytest.raises(KeyError):
        m["value"]
    # the chain's first mode lies in the excited band 3-60 Hz
    assert 3 < m.frequency_hz < 60 and 0 < m.damping_ratio < 0.2


def test_coefficient_reads_as_attributes_and_as_a_mapping():
    c = chain().coefficients[0]
    assert list(c) == COEFFICIENT_KEYS + ["unit"]
    assert c["value"] == c.value and c.get("unit") == c.unit == "N/m^3"
    assert dict(c) == c.to_dict() and {**c}["verdict"] == c.verdict
    assert c == c.to_dict()   # a mapping compares as its dict
    # the cubic spring is 1e9 N/m^3 (daq.sim.lumped); 1 % noise on 4 periods: within 2 %
    assert abs(c.value / 1e9 - 1) < 0.02 and c.verdict == "identified"
    with pytest.raises(TypeError):
        c["value"] = 0.0  # type: ignore[index]
    assert "curve" not in c and c.get("curve") is None


def test_json_writes_the_records_fields():
    r = chain()
    doc = r.to_json()
    assert doc["coefficients"] == json_safe([c.to_dict() for c in r.coefficients])
    assert list(doc["coefficients"][0]) == COEFFICIENT_KEYS + ["unit"]
    assert doc["modes"] == json_safe([m.to_json() for m in r.modes])
    assert list(doc["modes"][0]) == ["frequency_hz", "damping_ratio", "stable", "shape"]
    assert set(doc["modes"][0]["shape"]) == {"re", "im"}


def test_unknown_summary_keys_are_kept():
    summary = dict(chain().coefficients[0].to_dict(), new_rule=0.5)
    summary.pop("unit")
    c = Coefficient.from_summary(summary, unit="N/m^3")
    assert c["new_rule"] == 0.5 and c.extra == {"new_rule": 0.5}
    assert list(c) == COEFFICIENT_KEYS + ["new_rule", "unit"]


def test_nested_test_is_built_once_with_its_linear_fit():
    r = chain()
    compared = fnsi_lab.identify(_arrays(), {**CUBIC, "compare_linear": True}, order=6)
    test = compared.nested
    assert test is not None and isinstance(test.linear, Identification)
    with pytest.raises(dataclasses.FrozenInstanceError):
        test.decision = "linear"  # type: ignore[misc]
    # the cubic spring is supported (the chain has one): the answer keeps its own modes
    assert test.decision == "nonlinear" and not test.undetermined
    assert [m.frequency_hz for m in compared.modes] == [m.frequency_hz for m in r.modes]
    # every coefficient not identifiable: the same test keeps the linear fit's answer
    assert test.require_coefficients(["not identifiable"]).decision == "linear"
    assert test.decision == "nonlinear"
