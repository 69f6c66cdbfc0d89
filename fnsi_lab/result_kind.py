"""Which fnsi-lab command wrote a JSON file: so that a command reading an ``ident --json``
result (``validate``, ``report``) can refuse another command's JSON in one line that names it.

The layouts are those documented in docs/ident.md (``ident --json``), docs/discovery.md
(``analyse --json``: ``"kind": "distortion analysis"``; ``locate --json``: ``candidates``)
and docs/validate.md (``validate --json``: ``outputs[].error_db``).
"""

from __future__ import annotations

from typing import Any, Mapping

__all__ = ["json_kind", "not_an_ident_result"]

#: What each recognised JSON is, for the messages.
_WRITERS = {"analyse": "an `fnsi-lab analyse --json` output (distortion analysis)",
            "locate": "an `fnsi-lab locate --json` output (localisation candidates)",
            "validate": "an `fnsi-lab validate --json` output (validation errors)"}


def json_kind(data: Any) -> str | None:
    """The command that wrote ``data`` (a parsed JSON file), when recognisable.

    Returns
    -------
    {'ident', 'analyse', 'locate', 'validate'} or None
        ``ident`` for an identification result (``state_space``, or ``order`` with
        ``modes``/``frf`` as older results have); None for anything else.
    """
    if not isinstance(data, Mapping):
        return None
    if data.get("kind") == "distortion analysis":
        return "analyse"
    if "candidates" in data:
        return "locate"
    outputs = data.get("outputs")
    if (isinstance(outputs, list) and outputs and isinstance(outputs[0], Mapping)
            and "error_db" in outputs[0]):
        return "validate"
    if "state_space" in data or ("order" in data and ("modes" in data or "frf" in data)):
        return "ident"
    return None


def not_an_ident_result(data: Any, name: str) -> str | None:
    """One line saying why ``data`` (read from ``name``) is not an ``ident --json`` result,
    or None when it is one (an older result without ``state_space`` included: the reader says
    what it lacks).
    """
    kind = json_kind(data)
    if kind == "ident":
        return None
    fix = "fix: give the JSON that `fnsi-lab ident REC --auto --json RESULT.json` wrote"
    if kind in _WRITERS:
        return f"{name}: not an `fnsi-lab ident --json` result: it is {_WRITERS[kind]} ({fix})"
    return f"{name}: not an `fnsi-lab ident --json` result (neither 'state_space' nor 'modes' in it; {fix})"
