"""A verdict for every nonlinear coefficient: ``identified``, ``weak`` or ``not identifiable``.

A coefficient is printed as the answer only when the data determine it. Three things say
whether they do (docs/ident.md, "Is the coefficient determined by the data?"):

- its **standard deviation over the excited lines**, ``std_real / |value|`` (the spread of
  ``Re c_a(w)``, the ``+-`` printed next to it);
- the **consistency of its spectrum**: ``rho``, the relative RMS departure of the
  reciprocity relation ``G_a = -c_a L_a^T G_p`` from one real constant
  (:func:`ident.core.coefficients.coefficient_spread`), and ``log10 |Re/Im|`` of the mean;
- the **conditioning of the regression**: how collinear the basis column is with the
  forces and the other basis columns (:mod:`ident.core.regressors`).

Thresholds (measured on simulated data with a known answer, Monte Carlo over noise seeds;
``bench/verdicts.py``, bench/RESULTS.md "Coefficient verdicts", tests/test_ident_verdict.py):

- ``rho`` tracked the coefficient's error (3-DOF chain, cubic spring at five force levels
  and a two-sided stop at three, 1 % output noise, 8 seeds each): ``|error| <= 1.4 rho``
  wherever ``rho > 0.1``; below, the error has a floor of a few percent that ``rho`` does
  not see (the stop: 7 % at ``rho = 0.054``; the SmallSat, docs/robust.md: ``rho ~ 1e-3``
  at 0.1 %, ``~1e-2`` at 1 %). ``identified`` asks ``rho <= 0.15`` (the cubic spring at
  1 N: ``rho`` 0.03-0.13, errors within 6.2 %; at 0.5 N: 0.19-0.55, errors up to 30 %),
  ``not identifiable`` starts at ``rho > 0.5``.
- ``std_real > |value|``: the lines do not agree on the sign: ``not identifiable``; above half
  the value never ``identified`` (the hard rule of issue 29).
- ``log10 |Re/Im| < 1``: the seed's "unreliable" (docs/method.md §2.3): at best ``weak``;
  below 0 (the imaginary part dominates): ``not identifiable``.
- a basis column whose variance inflation against the other extended-input columns
  (:mod:`ident.core.regressors`) exceeds 1e4 shares its coefficient with them: ``not
  identifiable``; above 100: at best ``weak`` (the chain's cubic and stop columns: 1.04-1.1;
  the SmallSat's NC2-Z: 1.1; the Silverbox: 1.05).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

__all__ = ["IDENTIFIED", "WEAK", "NOT_IDENTIFIABLE", "VerdictThresholds", "Verdict",
           "coefficient_verdict", "not_supported"]

IDENTIFIED, WEAK, NOT_IDENTIFIABLE = "identified", "weak", "not identifiable"
_RANK = {IDENTIFIED: 0, WEAK: 1, NOT_IDENTIFIABLE: 2}


@dataclass(frozen=True)
class VerdictThresholds:
    """Where the verdict changes (module docstring: how they were measured).

    Attributes
    ----------
    spread_identified, spread_weak : float
        ``rho`` at most this for ``identified`` / ``weak``.
    std_identified, std_weak : float
        ``std_real / |value|`` at most this for ``identified`` (0.5: the hard rule) / ``weak``.
    re_im_identified, re_im_weak : float
        ``log10 |Re/Im|`` at least this for ``identified`` / ``weak``.
    inflation_identified, inflation_weak : float
        Variance inflation of the column against the other extended-input columns.
    """

    spread_identified: float = 0.15
    spread_weak: float = 0.5
    std_identified: float = 0.5
    std_weak: float = 1.0
    re_im_identified: float = 1.0
    re_im_weak: float = 0.0
    inflation_identified: float = 100.0
    inflation_weak: float = 1e4


@dataclass(frozen=True)
class Verdict:
    """The verdict on one coefficient and the numbers behind it.

    Attributes
    ----------
    verdict : {'identified', 'weak', 'not identifiable'}
    reason : str
        One sentence in words (what limits it, with the number and the threshold).
    relative_std : float
        ``std_real / |value|``.
    spread : float
        ``rho`` (:func:`ident.core.coefficients.coefficient_spread`).
    """

    verdict: str
    reason: str
    relative_std: float
    spread: float

    def to_dict(self) -> dict:
        return {"verdict": self.verdict, "verdict_reason": self.reason,
                "relative_std": self.relative_std, "spread": self.spread}


def _finite(x) -> float:
    try:
        x = float(x)
    except (TypeError, ValueError):
        return float("nan")
    return x


def coefficient_verdict(summary: dict, spread: float, *, inflation: float | None = None,
                        thresholds: VerdictThresholds = VerdictThresholds()) -> Verdict:
    """Judge one coefficient.

    Parameters
    ----------
    summary : dict
        :meth:`ident.core.coefficients.CoefficientSummary.to_dict` (``value``, ``std_real``,
        ``log10_re_im``).
    spread : float
        ``rho`` of the coefficient.
    inflation : float, optional
        Of its basis column (:func:`ident.core.regressors.regressor_conditioning`).
    thresholds : VerdictThresholds

    Returns
    -------
    Verdict
        The worst of the criteria decides; the reason names every criterion that kept it
        from ``identified``.
    """
    t = thresholds
    value = _finite(summary.get("value"))
    std = _finite(summary.get("std_real"))
    re_im = _finite(summary.get("log10_re_im"))
    rho = _finite(spread)
    rel = abs(std / value) if value not in (0.0,) and math.isfinite(value) else float("inf")
    if not math.isfinite(rel):
        rel = float("inf")
    if not math.isfinite(value):
        return Verdict(NOT_IDENTIFIABLE, "no finite value (the model gives no basis column "
                       "response at the driving point)", rel, rho)
    findings: list[tuple[str, str]] = []   # (verdict, reason)

    def grade(bad_weak: bool, bad_ident: bool, text: str) -> None:
        if bad_weak:
            findings.append((NOT_IDENTIFIABLE, text))
        elif bad_ident:
            findings.append((WEAK, text))

    grade(not rel <= t.std_weak, not rel <= t.std_identified,
          f"its standard deviation over the excited lines is {100 * rel:.3g} % of the value "
          f"(identified needs <= {100 * t.std_identified:g} %, weak <= {100 * t.std_weak:g} %)")
    grade(not rho <= t.spread_weak, not rho <= t.spread_identified,
          f"its spectrum departs from one real constant by {100 * rho:.3g} % (rho; identified "
          f"needs <= {100 * t.spread_identified:g} %, weak <= {100 * t.spread_weak:g} %)")
    grade(not re_im >= t.re_im_weak, not re_im >= t.re_im_identified,
          f"log10|Re/Im| of its spectrum is {re_im:.2f} (identified needs >= "
          f"{t.re_im_identified:g}, weak >= {t.re_im_weak:g})")
    if inflation is not None and not math.isnan(_finite(inflation)):
        grade(not inflation <= t.inflation_weak, not inflation <= t.inflation_identified,
              f"its basis column is collinear with the other columns (variance inflation "
              f"{inflation:.3g}; identified needs <= {t.inflation_identified:g})")
    if not findings:
        return Verdict(IDENTIFIED, f"consistent spectrum (rho {100 * rho:.2g} %, standard "
                       f"deviation {100 * rel:.2g} % of the value, log10|Re/Im| {re_im:.2f})",
                       rel, rho)
    worst = max(findings, key=lambda f: _RANK[f[0]])[0]
    reasons = [r for v, r in findings if v == worst] + [r for v, r in findings if v != worst]
    return Verdict(worst, "; ".join(reasons), rel, rho)


def not_supported(verdict: dict, statement: str) -> dict:
    """A coefficient's verdict when the nested test finds the nonlinear terms unsupported.

    Parameters
    ----------
    verdict : dict
        The coefficient's dict with ``verdict`` and ``verdict_reason``.
    statement : str
        Why (``nonlinear_vs_linear``'s statement).

    Returns
    -------
    dict
        The same dict, ``not identifiable`` with ``statement`` first in the reason.
    """
    out = dict(verdict)
    before = out.get("verdict_reason")
    out["verdict"] = NOT_IDENTIFIABLE
    out["verdict_reason"] = statement + (f" (on its own: {verdict.get('verdict')}, {before})"
                                         if before and verdict.get("verdict") != NOT_IDENTIFIABLE
                                         else (f"; {before}" if before else ""))
    return out


def worst(verdicts: Sequence[str]) -> str | None:
    """The worst of several verdicts (None for none)."""
    return max(verdicts, key=lambda v: _RANK.get(v, 0)) if verdicts else None
