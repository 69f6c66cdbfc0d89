"""Model-order selection by the information criterion (docs/method.md §3, §8.3; seed §3, Eq. 6-8).

Pure functions over arrays. The model error of order ``n`` is the steady-state output error,
computed exactly in the frequency domain (docs/method.md §3 shortcut: ``Y_ss(k) = G_d(z_k) E(k)``,
:func:`ident.core.fnsi.steady_state_output`), normalised by the output energy on the same lines:

    V(n) = sum_{k in K_V} ||Y(k) - Y_ss(k)||^2 / sum_{k in K_V} ||Y(k)||^2        (Eq. 7)
    I(n) = V(n) (1 + n / F)                                                    (Eq. 8)

with ``F = |K_V|`` the number of lines where V is evaluated. Unstable models are excluded
(``I = +inf``) and flagged. ``argmin I`` is the selected order.

Options
-------
``criterion='seed'`` is Eq. 8. The others count parameters instead of states, with
``n_theta = n (m_e + p) + p m_e`` (``p m_e`` dropped when ``D = 0``) and ``N_r = 2 F p`` real
residuals: ``criterion='aic'``, ``I = V (1 + 2 n_theta / N_r)``; ``criterion='mdl'``
(Rissanen's minimum description length, the default of :mod:`ident.robust.auto`),
``I = V exp(n_theta ln(N_r) / N_r)``, i.e. ``ln I = ln V + n_theta ln(N_r) / N_r``. Eq. 8's
penalty is 3 % at n = 60 and F = 2000 (docs/method.md §3), so wherever V has reached its floor (noise,
model error) its minimum falls at an arbitrary order; MDL's grows with the data and is
consistent.

``band='auto'`` (default) evaluates V over the excited lines when the outputs are few
(``p <= FEW_OUTPUTS``) and over all processed lines otherwise: with few outputs, the extra
states of high orders fit the harmonic content of the basis functions outside the excited
band and V keeps falling there (docs/method.md §8.3). ``'processed'``, ``'excited'`` or an explicit
``(f_min, f_max)`` in Hz are also accepted.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.ident.errors import IdentError

Criterion = Literal["seed", "aic", "mdl"]
CRITERIA: tuple[str, ...] = ("seed", "aic", "mdl")
IcBand = Literal["auto", "processed", "excited"]
IC_BANDS: tuple[str, ...] = ("auto", "processed", "excited")
#: ``band='auto'`` uses the excited lines when there are at most this many outputs (docs/method.md §8.3:
#: 3 outputs need the excited band, 39 do well on the processed band). Fixed a priori.
FEW_OUTPUTS = 8

__all__ = ["InformationCriterion", "relative_model_error", "information_criterion",
           "parameter_count", "ic_line_mask", "select_order", "select_order_consistent",
           "FIT_FACTOR", "FIT_FLOOR",
           "CRITERIA", "IC_BANDS", "FEW_OUTPUTS"]


def relative_model_error(Y, Y_hat, mask=None) -> float:
    """``V = sum ||Y - Y_hat||^2 / sum ||Y||^2`` over the lines in ``mask`` (docs/method.md §3).

    Parameters
    ----------
    Y, Y_hat : complex ndarray, shape (F, p)
    mask : bool ndarray, shape (F,), optional

    Returns
    -------
    float
    """
    Y = np.asarray(Y)
    Y_hat = np.asarray(Y_hat)
    if Y.shape != Y_hat.shape:
        raise IdentError(f"Y {Y.shape} and Y_hat {Y_hat.shape} differ in shape")
    if mask is not None:
        Y = Y[mask]
        Y_hat = Y_hat[mask]
    den = float(np.sum(np.abs(Y) ** 2))
    if den <= 0:
        raise IdentError("the output has no energy on the lines of the information criterion")
    return float(np.sum(np.abs(Y - Y_hat) ** 2) / den)


def parameter_count(order: int, n_outputs: int, n_extended_inputs: int, *, d_zero: bool = False) -> int:
    """``n_theta = n (m_e + p) + p m_e`` (``p m_e`` dropped if ``D = 0``), option ``aic``."""
    return int(order * (n_extended_inputs + n_outputs) + (0 if d_zero else n_outputs * n_extended_inputs))


def information_criterion(v, order, n_lines: int, *, criterion: Criterion = "seed",
                          n_outputs: int | None = None, n_extended_inputs: int | None = None,
                          d_zero: bool = False):
    """``I(n)`` from ``V(n)`` (seed Eq. 8, or the AIC-style option).

    Parameters
    ----------
    v : float or ndarray
        Relative model error ``V(n)``.
    order : int or int ndarray
        ``n`` (same shape as ``v``).
    n_lines : int
        ``F``, lines in the error.
    criterion : {'seed', 'aic', 'mdl'}
    n_outputs, n_extended_inputs : int
        Needed by ``'aic'`` and ``'mdl'``.
    d_zero : bool
        ``'aic'`` and ``'mdl'``: D not estimated.

    Returns
    -------
    float or ndarray
    """
    if criterion not in CRITERIA:
        raise IdentError(f"criterion={criterion!r} is not one of {', '.join(map(repr, CRITERIA))}")
    v = np.asarray(v, float)
    n = np.asarray(order, float)
    if criterion == "seed":
        return v * (1.0 + n / n_lines)
    if n_outputs is None or n_extended_inputs is None:
        raise IdentError(f"criterion={criterion!r} needs n_outputs and n_extended_inputs")
    ntheta = n * (n_extended_inputs + n_outputs) + (0 if d_zero else n_outputs * n_extended_inputs)
    n_res = 2.0 * n_lines * n_outputs
    if criterion == "mdl":
        return v * np.exp(ntheta * np.log(n_res) / n_res)
    return v * (1.0 + 2.0 * ntheta / n_res)


def ic_line_mask(frequencies_hz, excited, n_outputs: int, band="auto"):
    """Lines on which V is evaluated (docs/method.md §8.3).

    Parameters
    ----------
    frequencies_hz : ndarray, shape (F,)
    excited : bool ndarray, shape (F,)
    n_outputs : int
    band : {'auto', 'processed', 'excited'} or (float, float)

    Returns
    -------
    mask : bool ndarray, shape (F,)
    resolved : str or (float, float)
        ``'processed'``, ``'excited'`` or the explicit band.
    """
    f = np.asarray(frequencies_hz, float)
    exc = np.asarray(excited, bool)
    if isinstance(band, str):
        if band not in IC_BANDS:
            raise IdentError(f"ic band={band!r} is not one of {plain.names(IC_BANDS)} "
                             "or a (f_min, f_max) pair in Hz")
        if band == "auto":
            band = "excited" if n_outputs <= FEW_OUTPUTS else "processed"
        if band == "processed":
            return np.ones(f.size, bool), "processed"
        if not exc.any():
            raise IdentError("no excited line: the information criterion cannot use the excited band")
        lo, hi = f[exc].min(), f[exc].max()
        return (f >= lo) & (f <= hi), "excited"
    lo, hi = float(band[0]), float(band[1])
    mask = (f >= lo) & (f <= hi)
    if not mask.any():
        raise IdentError(f"the information-criterion band {plain.band_hz(band)} holds no processed line")
    return mask, (lo, hi)


def select_order(orders: Sequence[int], ic, stable) -> int:
    """``argmin I`` over the stable orders (unstable ones never selected).

    Raises
    ------
    IdentError
        If no order is stable.
    """
    ic = np.where(np.asarray(stable, bool), np.asarray(ic, float), np.inf)
    if not np.any(np.isfinite(ic)):
        raise IdentError("every model of the order sweep is unstable: no order can be selected "
                         "(fix: lower the largest order or check the data)")
    return int(np.asarray(orders)[int(np.argmin(ic))])


#: The consistency gate only chooses among orders whose model error ``V(n)`` is within this
#: factor of ``V`` at the criterion's own order (see :func:`select_order_consistent`) ...
FIT_FACTOR = 2.0
#: ... or below this (relative) error: a model that leaves less than 1 % of the output's
#: energy on the lines (20 dB below it) explains the data in any lab's sense, however much
#: lower ``V`` creeps at high orders (noise-free 3-channel SmallSat: 1e-6 to 2e-8, where the
#: gate must move the order; docs/robust.md).
FIT_FLOOR = 1e-2


def select_order_consistent(orders: Sequence[int], ic, stable, spread,
                            spread_factor: float = 3.0, *, model_error=None,
                            fit_factor: float = FIT_FACTOR,
                            fit_floor: float = FIT_FLOOR) -> tuple[int, np.ndarray]:
    """``argmin I`` over the stable orders whose nonlinear coefficients are consistent.

    Parameters
    ----------
    orders : sequence of int
    ic : ndarray
        ``I(n)`` (``inf`` for excluded orders).
    stable : bool ndarray
    spread : ndarray
        Coefficient spread ``rho(n)`` (:func:`ident.core.coefficients.coefficient_spread`); NaN or
        inf where unknown.
    spread_factor : float
        An order is consistent when ``rho(n) <= spread_factor * min rho``.
    model_error : ndarray, optional
        ``V(n)``. When given, only orders with ``V(n) <= max(fit_factor * V(argmin I),
        fit_floor)`` are admissible, and ``min rho`` is taken over them.
    fit_factor, fit_floor : float

    Returns
    -------
    order : int
    consistent : bool ndarray
        The gate, per order.

    Notes
    -----
    The information criterion measures the fit; it cannot see how the fit splits between
    the force and the basis-function columns. With few outputs, high orders keep lowering V
    while the split degrades (the extra poles trade ``G_p`` for ``G_a`` along the
    describing function), and ``argmin I`` then returned c_a off by -100 % on the
    3-channel SmallSat. The seed itself confirms its IC order by the flatness of c_a (its
    Fig. 6, Table 2); this makes that check automatic.

    A coefficient that is consistent only at an order whose model explains the data much
    worse is the basis column standing in for the modes that order lacks, not a
    determined coefficient: on the aircraft-like GVT at 26 N (another multisine
    realisation) a cubic spring was consistent at order 3 only, whose model error was 22x
    that at the criterion's order 31: one mode left of nine, the coefficient "identified".
    Over 96 identifications (Silverbox, SmallSat 3 and 39 channels with and without noise,
    the aircraft-like GVT at 14 levels with five joint models, an independent Iwan joint at
    six levels with three), every answer kept as nonlinear had the gate at the criterion's
    own order (``V`` ratio 1.000); the gate moved ``V`` by more than 2x only where every
    coefficient ended ``not identifiable``, but for that one. Hence ``fit_factor`` 2, and
    ``fit_floor`` (:data:`FIT_FLOOR`) so that the gate still moves noise-free models whose
    ``V`` differs by decades at negligible levels.
    """
    ic = np.where(np.asarray(stable, bool), np.asarray(ic, float), np.inf)
    rho = np.asarray(spread, float)
    ok = np.isfinite(ic) & np.isfinite(rho)
    if model_error is not None and np.isfinite(ic).any():
        v = np.asarray(model_error, float)
        ok &= v <= max(float(fit_factor) * float(v[int(np.argmin(ic))]), float(fit_floor))
    if not ok.any():
        return select_order(orders, ic, stable), np.zeros(ic.size, bool)
    gate = ok & (rho <= float(spread_factor) * float(np.min(rho[ok])))
    return int(np.asarray(orders)[int(np.argmin(np.where(gate, ic, np.inf)))]), gate


@dataclass(frozen=True)
class InformationCriterion:
    """Information criterion over an order sweep.

    Attributes
    ----------
    orders : int ndarray, shape (q,)
    model_error : ndarray, shape (q,)
        ``V(n)`` (relative), computed for unstable models too (for diagnosis).
    value : ndarray, shape (q,)
        ``I(n)``, ``+inf`` for unstable models.
    stable : bool ndarray, shape (q,)
    selected_order : int
    n_lines : int
        ``F``.
    band : str or (float, float)
        Lines used for V.
    criterion : str
    """

    orders: np.ndarray
    model_error: np.ndarray
    value: np.ndarray
    stable: np.ndarray
    selected_order: int
    n_lines: int
    band: object
    criterion: str

    @classmethod
    def from_errors(cls, orders, v, stable, n_lines, *, band="processed", criterion="seed",
                    n_outputs=None, n_extended_inputs=None, d_zero=False) -> "InformationCriterion":
        """Build from ``V(n)`` and stability flags (see :func:`information_criterion`)."""
        orders = np.asarray(orders, int)
        v = np.asarray(v, float)
        stable = np.asarray(stable, bool)
        val = information_criterion(v, orders, n_lines, criterion=criterion, n_outputs=n_outputs,
                                    n_extended_inputs=n_extended_inputs, d_zero=d_zero)
        val = np.where(stable & np.isfinite(val), val, np.inf)
        return cls(orders=orders, model_error=v, value=val, stable=stable,
                   selected_order=select_order(orders, val, stable), n_lines=int(n_lines),
                   band=band, criterion=criterion)

    def to_list(self) -> list[dict]:
        """JSON-able ``[{order, value, seed_value, model_error, stable}]``.

        ``value`` is ``I(n)`` of :attr:`criterion` and ``seed_value`` the seed's
        ``V(n)(1 + n/F)`` (both None for excluded, unstable orders).
        """
        seed = information_criterion(self.model_error, self.orders, self.n_lines)
        return [{"order": int(n), "value": None if not np.isfinite(i) else float(i),
                 "seed_value": float(e) if s and np.isfinite(e) else None,
                 "model_error": float(v), "stable": bool(s)}
                for n, i, e, v, s in zip(self.orders, self.value, seed, self.model_error,
                                         self.stable)]
