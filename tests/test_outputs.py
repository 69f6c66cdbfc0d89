"""The one JSON encoder (fnsi_lab.outputs.dumps): strict JSON, readable layout, same content."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fnsi_lab.outputs import dumps, json_safe

RESULT_LIKE = {
    "order": np.int64(6), "value": np.float64(3.9), "missing": float("nan"),
    "spectrum": np.array([1.0, np.inf, -2.5]), "lines": np.arange(4), "flags": [True, False],
    "frf": {"re": np.ones((3, 2)).tolist(), "im": [[0.0, float("-inf")]] * 3},
    "poles": [{"frequency_hz": 10.0, "damping": np.float32(0.02)}, {"frequency_hz": 25.0}],
    "shape": np.array([1 + 2j]), "empty": [], "none": {}, "text": ["a", "b"],
}


def test_indented_and_compact_output_hold_the_same_strict_json():
    reference = json.loads(json.dumps(json_safe(RESULT_LIKE), allow_nan=False))
    for text in (dumps(RESULT_LIKE), dumps(RESULT_LIKE, indent=2)):
        assert "NaN" not in text and "Infinity" not in text
        assert json.loads(text) == reference
    assert reference["missing"] is None and reference["spectrum"] == [1.0, None, -2.5]
    assert reference["frf"]["im"][0] == [0.0, None]
    assert reference["shape"] == [{"re": 1.0, "im": 2.0}]


def test_layout_one_member_per_line_arrays_of_numbers_on_one_line():
    lines = dumps(RESULT_LIKE, indent=2).splitlines()
    assert '  "spectrum": [1.0, null, -2.5],' in lines
    assert '  "frf": {' in lines and '    "re": [[1.0, 1.0], [1.0, 1.0], [1.0, 1.0]],' in lines
    assert '  "poles": [' in lines and '      "frequency_hz": 10.0,' in lines


def test_unknown_objects_refused_when_asked():
    with pytest.raises(TypeError, match="object is not JSON serializable"):
        dumps({"x": object()}, unknown="error")


def test_another_output_under_the_same_name_is_refused(tmp_path):
    """check_output_path(outputs=...): two outputs of one command under one name would leave
    only the last one written; refused with --force too, and named as an output (not "an
    input of this command"). '-' (stdout) and None are not files."""
    from fnsi_lab.errors import DataFileError
    from fnsi_lab.outputs import check_output_path

    target = tmp_path / "same"
    with pytest.raises(DataFileError, match=r"--svg .*same: is also the --json output"):
        check_output_path(target, option="--svg", outputs={"--json": str(target)})
    target.write_text("kept")
    with pytest.raises(DataFileError, match="is also the --json output") as info:
        check_output_path(target, option="--svg", force=True, outputs={"--json": target})
    assert "input" not in str(info.value) and target.read_text() == "kept"
    assert check_output_path(tmp_path / "other", option="--svg",
                             outputs={"--json": "-", "--rrd": None, "--x": target}) \
        == tmp_path / "other"
