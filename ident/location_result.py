"""The answer of a localisation (:mod:`ident.locate`, :mod:`ident.locate_stick_slip`): each
candidate location's score and verdict, and the ranked list with what was compared."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

__all__ = ["P_SIGNIFICANT", "LocationScore", "Localisation", "location_name"]

#: A reduction whose F-test p-value is below this is significant (the usual 0.1 % level).
P_SIGNIFICANT = 1e-3


@dataclass
class LocationScore:
    """How much one candidate location explains.

    Attributes
    ----------
    channels : dict str -> float
        Signed location vector ``L`` (``{A: 1, B: -1}``: the element between A and B).
    score : float
        Fraction of the linear model's weighted residual its generic columns remove (0..1).
    significance : float
        ``-log10`` of the F-test p-value of that reduction (3: p = 1e-3).
    f_statistic : float
    rss_ratio_to_best : float
        Its residual over the best candidate's (1 for the best).
    verdict : str
        ``located``, ``as likely as the best``, ``significant`` or ``not significant``.
    stage : {'screen', 'fnsi', 'stick-slip'}
        Which test gave the numbers: the screen of every candidate, the FNSI refinement
        of the screen's best (their ``score`` and residuals are not comparable), or a
        Jenkins element's information criterion (:mod:`ident.locate_stick_slip`: ``score``
        the fraction by which it falls below the linear model's, ``significance`` NaN).
    slip : float or None
        ``stick-slip``: the slip displacement from the data (outputs' length unit).
    note : str
        Why a candidate was not evaluated (e.g. its slip search refused), else empty.
    """

    channels: dict
    score: float
    significance: float
    f_statistic: float
    rss_ratio_to_best: float
    verdict: str
    stage: str = "screen"
    slip: float | None = None
    note: str = ""

    @property
    def name(self) -> str:
        """``A - B`` for a pair, ``A`` for a channel to ground."""
        return location_name(self.channels)

    def to_dict(self) -> dict:
        return {"name": self.name, "channels": dict(self.channels), "score": self.score,
                "significance": self.significance, "f_statistic": self.f_statistic,
                "rss_ratio_to_best": self.rss_ratio_to_best, "verdict": self.verdict,
                "stage": self.stage,
                **({"slip": self.slip} if self.slip is not None else {}),
                **({"note": self.note} if self.note else {})}


@dataclass
class Localisation:
    """Candidates ranked best first (:func:`rank_locations`).

    Attributes
    ----------
    candidates : list of LocationScore
        Sorted by decreasing score.
    order : int
        Order of the linear model whose poles and shapes were used.
    n_lines : int
    columns : tuple of str
        The generic columns of every candidate.
    degrees_of_freedom : (int, int)
        ``(df1, df2)`` of the F-test.
    weighted : bool
        Noise-weighted (the periods gave a noise estimate).
    timings_s : dict
    refined : int
        Candidates re-ranked by FNSI (the first ``refined`` of ``candidates``).
    refine_knots : int
        Spline knots of the refinement (0: the generic columns alone).
    linear_misfit : float or None
        The linear model's residual per real residual in noise variances (weighted data):
        about 1 when only noise is left; far above, the F-tests compare against a residual
        that is mostly model error (transients, drift, distortion) and every candidate's
        columns remove some of it (docs/discovery.md, "Limits").
    linear_criterion : float or None
        ``stick-slip``: the linear model's information criterion the candidates are
        compared with.
    form : {'generic', 'jenkins'}
        The force the candidates were offered (``form='auto'`` says which it kept).
    """

    candidates: list
    order: int
    n_lines: int
    columns: tuple
    degrees_of_freedom: tuple
    weighted: bool
    timings_s: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    refined: int = 0
    refine_knots: int = 0
    linear_misfit: float | None = None
    linear_criterion: float | None = None
    form: str = "generic"

    @property
    def located(self) -> "LocationScore | None":
        """The best candidate when the data locate it (verdict ``located``), else None."""
        return next((c for c in self.candidates if c.verdict == "located"), None)

    @property
    def supported(self) -> list:
        """The candidates the data support: ``located`` and ``as likely as the best``."""
        return [c for c in self.candidates if c.verdict in ("located", "as likely as the best")]

    def to_json(self) -> dict:
        return {"candidates": [c.to_dict() for c in self.candidates], "order": self.order,
                "n_lines": self.n_lines, "columns": list(self.columns),
                "degrees_of_freedom": list(self.degrees_of_freedom), "weighted": self.weighted,
                "p_significant": P_SIGNIFICANT, "refined": self.refined, "form": self.form,
                "refine_knots": self.refine_knots, "linear_misfit": self.linear_misfit,
                "timings_s": dict(self.timings_s),
                "warnings": list(self.warnings),
                **({"linear_criterion": self.linear_criterion}
                   if self.linear_criterion is not None else {})}


def location_name(channels: Mapping[str, float]) -> str:
    """``A - B`` (``+1`` at A, ``-1`` at B), ``A`` alone, else ``+1 A -1 B ...``."""
    items = list(channels.items())
    if len(items) == 1 and items[0][1] == 1:
        return items[0][0]
    if len(items) == 2 and sorted(w for _, w in items) == [-1, 1]:
        a = next(c for c, w in items if w == 1)
        b = next(c for c, w in items if w == -1)
        return f"{a} - {b}"
    return " ".join(f"{w:+g} {c}" for c, w in items)


