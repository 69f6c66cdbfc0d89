"""The answer's records: one mode and one coefficient of an identification, frozen and typed.

:class:`~fnsi_lab.ident.pipeline.Identification` lists its answer as :class:`Mode` and
:class:`Coefficient` records. Each is a frozen dataclass (attribute access is the typed way:
``mode.frequency_hz``, ``coef.value``) and a read-only mapping over the same fields, the
keys of the result JSON (``result.modes[0]["frequency_hz"]``, ``c["value"]``,
``c.get("unit")``, ``dict(c)``, ``"unit" in c`` read them as before). ``to_dict()`` gives
the plain dict; :meth:`Identification.to_json` writes it (docs/api.md, "The result").
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

import numpy as np

__all__ = ["Mode", "Coefficient"]


class _Record(Mapping[str, Any]):
    """A read-only mapping over a frozen dataclass's fields.

    Fields named in ``_OPTIONAL`` are keys only when they are not None (the JSON leaves
    them out then); ``extra`` (a mapping field, when the record has one) adds its keys."""

    _OPTIONAL: ClassVar[tuple[str, ...]] = ()

    def _items(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for f in fields(self):  # type: ignore[arg-type]   # every subclass is a dataclass
            value = getattr(self, f.name)
            if f.name == "extra":
                out.update(value)
            elif not (f.name in self._OPTIONAL and value is None):
                out[f.name] = value
        return out

    def __getitem__(self, key: str) -> Any:
        return self._items()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._items())

    def __len__(self) -> int:
        return len(self._items())

    def to_dict(self) -> dict[str, Any]:
        """The record as a plain dict (the keys of the result JSON, in its order)."""
        return self._items()


@dataclass(frozen=True, eq=False)
class Mode(_Record):
    """One physical mode of the answer.

    Attributes
    ----------
    frequency_hz : float
        Natural frequency (Hz).
    damping_ratio : float
        Viscous damping ratio (1).
    stable : bool
        The pole lies inside the unit circle.
    shape : numpy.ndarray
        Complex mode shape, one entry per output, shape ``(n_outputs,)`` (the JSON writes
        it as ``{"re": [...], "im": [...]}``).
    """

    frequency_hz: float
    damping_ratio: float
    stable: bool
    shape: np.ndarray

    def to_json(self) -> dict[str, Any]:
        """The mode as the result JSON writes it (``shape`` split into ``re`` and ``im``)."""
        return dict(self.to_dict(), shape={"re": self.shape.real, "im": self.shape.imag})


@dataclass(frozen=True, eq=False)
class Coefficient(_Record):
    """One nonlinear coefficient of the answer: its value, statistics and verdict
    (docs/ident.md, "Result file"; :mod:`ident.core.coefficients`, :mod:`ident.robust.verdict`).

    Attributes
    ----------
    name : str
        ``element:coefficient`` (``NC2-Z:neg``).
    value : float
        The declared estimate (``ls_value``; ``estimate`` says which).
    estimate : str
        Which statistic ``value`` is (``ls_value``).
    value_error_percent : float or None
        Error of ``value`` against a known truth (simulations).
    mean_real, std_real : float
        Mean and standard deviation of ``Re c_a(w)`` over the excited lines.
    log10_re_im : float
        ``log10 |mean Re / mean Im|``.
    ls_value : float
        Least-squares constant over the excited lines.
    error_percent, ls_error_percent : float or None
        Errors of ``mean_real`` and ``ls_value`` against the truth.
    n_lines, n_antiresonance_lines : int
        Excited lines used, and left out near antiresonances of the denominator.
    band : dict
        The same statistics over every processed line (diagnostic).
    verdict : str or None
        ``identified``, ``weak`` or ``not identifiable`` (:mod:`ident.robust.verdict`).
    verdict_reason : str or None
        Why, in one sentence.
    relative_std : float or None
        ``std_real / |value|``.
    spread : float or None
        The coefficient spread ``rho`` over the lines.
    extra : dict
        Keys the summary holds beyond these fields (written to the JSON as they are).
    curve : dict or None
        ``kind: spline``: the element's force curve on its first coefficient
        (:meth:`ident.core.spline.SplineCurve.to_dict`); not a key when None.
    unit : str or None
        Unit from the channel table (``N/mm``); not a key when None.
    """

    _OPTIONAL: ClassVar[tuple[str, ...]] = ("curve", "unit")
    _FIELDS: ClassVar[tuple[str, ...]] = (
        "name", "value", "estimate", "value_error_percent", "mean_real", "std_real",
        "log10_re_im", "ls_value", "error_percent", "ls_error_percent", "n_lines",
        "n_antiresonance_lines", "band", "verdict", "verdict_reason", "relative_std", "spread")

    name: str
    value: float
    estimate: str
    value_error_percent: float | None
    mean_real: float
    std_real: float
    log10_re_im: float
    ls_value: float
    error_percent: float | None
    ls_error_percent: float | None
    n_lines: int
    n_antiresonance_lines: int
    band: dict[str, Any]
    verdict: str | None = None
    verdict_reason: str | None = None
    relative_std: float | None = None
    spread: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    curve: dict[str, Any] | None = None
    unit: str | None = None

    @classmethod
    def from_summary(cls, summary: Mapping[str, Any], *, unit: str | None = None,
                     curve: dict[str, Any] | None = None) -> Coefficient:
        """The record of a summary dict (:meth:`ident.core.coefficients.CoefficientSummary.to_dict`
        with the verdict's keys); keys that are no field go to ``extra``."""
        known = {k: summary[k] for k in cls._FIELDS if k in summary}
        extra = {k: v for k, v in summary.items()
                 if k not in cls._FIELDS and k not in cls._OPTIONAL}
        return cls(**known, extra=extra, curve=curve if curve is not None
                   else summary.get("curve"), unit=unit if unit is not None
                   else summary.get("unit"))
