"""Stabilisation diagram: classify each pole against the previous order (docs/method.md §4).

Pure functions over arrays. For every order ``n`` and every pole of order ``n`` in the band,
look for a pole of the previous order in the sweep:

- frequency: ``|f - f'| / f <= freq_tol`` (default 1 %),
- damping: ``|z - z'| / z <= damping_tol`` (default 5 %),
- mode shape: ``MACX(psi, psi') >= mac_tol`` (default 0.98).

Classes (seed Fig. 5/8 legend; pyvib/Noël semantics):

=============  =======================================  ==========
class          meaning                                  seed mark
=============  =======================================  ==========
``new``        no previous pole within ``freq_tol``     dot
``frequency``  stable in frequency only                 cross
``damping``    frequency and damping                    square
``mode``       frequency and MACX                       circle
``stable``     frequency, damping and MACX              triangle
=============  =======================================  ==========

Unstable poles (``zeta < 0``) keep their class and carry ``unstable=True``. When several
previous poles lie within the frequency tolerance, the one with the highest MACX is used.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.ident.errors import IdentError

STAB_CLASSES: tuple[str, ...] = ("new", "frequency", "damping", "mode", "stable")

__all__ = ["macx", "macx_matrix", "StabilisationOrder", "StabilisationDiagram",
           "classify_stabilisation", "STAB_CLASSES"]


def macx(psi1, psi2) -> float:
    """MACX of two complex shapes (Vacher, Jacquier, Bucharles, ISMA 2010; docs/method.md §4).

    ``(|psi1^H psi2| + |psi1^T psi2|)^2 / ((psi1^H psi1 + |psi1^T psi1|)(psi2^H psi2 + |psi2^T psi2|))``.
    Equals MAC for real shapes; invariant to a complex scaling of either shape and to
    conjugation of either shape.
    """
    return float(macx_matrix(np.asarray(psi1)[:, None], np.asarray(psi2)[:, None])[0, 0])


def macx_matrix(psi1, psi2) -> np.ndarray:
    """MACX between every column of ``psi1`` (p, q1) and of ``psi2`` (p, q2): shape (q1, q2)."""
    a = np.asarray(psi1, dtype=complex)
    b = np.asarray(psi2, dtype=complex)
    num = (np.abs(a.conj().T @ b) + np.abs(a.T @ b)) ** 2
    da = np.sum(np.abs(a) ** 2, axis=0) + np.abs(np.sum(a * a, axis=0))
    db = np.sum(np.abs(b) ** 2, axis=0) + np.abs(np.sum(b * b, axis=0))
    den = da[:, None] * db[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(den > 0, num / den, 0.0)
    return out


@dataclass(frozen=True)
class StabilisationOrder:
    """Classified poles of one order.

    Attributes
    ----------
    order : int
    frequency_hz, damping_ratio : ndarray, shape (q,)
        In-band poles of this order (one per conjugate pair), sorted by frequency.
    classes : tuple of str, length q
        One of :data:`STAB_CLASSES`.
    unstable : bool ndarray, shape (q,)
    mac : ndarray, shape (q,)
        MACX with the matched previous pole (nan if ``new``).
    index : int ndarray, shape (q,)
        Index of the pole in the input arrays of this order.
    """

    order: int
    frequency_hz: np.ndarray
    damping_ratio: np.ndarray
    classes: tuple
    unstable: np.ndarray
    mac: np.ndarray
    index: np.ndarray


@dataclass(frozen=True)
class StabilisationDiagram:
    """Stabilisation diagram over a sweep of orders (docs/method.md §4).

    Attributes
    ----------
    orders : tuple of StabilisationOrder
    band_hz : (float, float)
    freq_tol, damping_tol, mac_tol : float
    """

    orders: tuple
    band_hz: tuple
    freq_tol: float
    damping_tol: float
    mac_tol: float

    def by_order(self, order: int) -> StabilisationOrder:
        """The entry of one order."""
        for o in self.orders:
            if o.order == order:
                return o
        raise IdentError(f"order {order} is not in the stabilisation diagram")

    def to_list(self) -> list[dict]:
        """JSON-able: ``[{order, poles: [{frequency_hz, damping_ratio, class, unstable, mac}]}]``."""
        out = []
        for o in self.orders:
            out.append({"order": int(o.order), "poles": [
                {"frequency_hz": float(f), "damping_ratio": float(z), "class": c,
                 "unstable": bool(u), "mac": None if not np.isfinite(m) else float(m)}
                for f, z, c, u, m in zip(o.frequency_hz, o.damping_ratio, o.classes,
                                         o.unstable, o.mac)]})
        return out


def classify_stabilisation(orders: Sequence[int], frequency_hz: Sequence, damping_ratio: Sequence,
                           mode_shapes: Sequence, *, band_hz=(0.0, np.inf),
                           freq_tol: float = 0.01, damping_tol: float = 0.05,
                           mac_tol: float = 0.98, lookback: int = 1) -> StabilisationDiagram:
    """Classify every in-band pole of every order against the previous order of the sweep.

    Parameters
    ----------
    orders : sequence of int, length n_orders
        Increasing model orders.
    frequency_hz : sequence of ndarray, each shape (q_n,)
        Natural frequencies (Hz) of the modes of each order (one per conjugate pair).
    damping_ratio : sequence of ndarray, each shape (q_n,)
    mode_shapes : sequence of complex ndarray, each shape (p, q_n)
        Output mode shapes; any scaling.
    band_hz : (float, float)
        Only poles with ``band_hz[0] <= f <= band_hz[1]`` are classified and reported.
    freq_tol, damping_tol, mac_tol : float
        docs/method.md §4 defaults 1 %, 5 %, 0.98.
    lookback : int
        Compare with each of the ``lookback`` previous orders of the sweep and keep the best
        class (rank stable > mode > damping > frequency > new). 1 (default) is the classic
        diagram; 2 helps sweeps over every integer order, where an odd order must spend a
        state on a real pole and is a poor reference for the pairs of the next even order.

    Returns
    -------
    StabilisationDiagram

    Notes
    -----
    The first order of the sweep has no predecessor: all its poles are ``new``. The
    previous-order candidates are taken over all frequencies (not only in band), so a pole
    crossing the band edge is still matched.
    """
    for name, v in (("freq_tol", freq_tol), ("damping_tol", damping_tol), ("mac_tol", mac_tol)):
        if not (np.isfinite(v) and v >= 0):
            raise IdentError(f"{name} must be a finite number >= 0, got {plain.value(v)}")
    if not (len(orders) == len(frequency_hz) == len(damping_ratio) == len(mode_shapes)):
        raise IdentError("orders, frequency_hz, damping_ratio and mode_shapes differ in length")
    if int(lookback) < 1:
        raise IdentError(f"lookback must be >= 1, got {plain.value(lookback)}")
    rank = {"new": 0, "frequency": 1, "damping": 2, "mode": 3, "stable": 4}
    f1, f2 = float(band_hz[0]), float(band_hz[1])
    out = []
    history: list = []
    for n, f, z, psi in zip(orders, frequency_hz, damping_ratio, mode_shapes):
        f = np.asarray(f, float).ravel()
        z = np.asarray(z, float).ravel()
        psi = np.asarray(psi, complex).reshape(-1, f.size) if f.size else np.zeros((0, 0))
        sel = np.flatnonzero((f >= f1) & (f <= f2))
        sel = sel[np.argsort(f[sel])]
        classes = ["new"] * sel.size
        macs = np.full(sel.size, np.nan)
        for pf, pz, ppsi in history[-int(lookback):]:
            if not (pf.size and sel.size):
                continue
            M = macx_matrix(psi[:, sel], ppsi)                      # (q, q_prev)
            for r, i in enumerate(sel):
                close = np.abs(f[i] - pf) <= freq_tol * f[i]
                if not close.any():
                    continue
                cand = np.flatnonzero(close)
                k = cand[np.argmax(M[r, cand])]
                ok_z = abs(z[i] - pz[k]) <= damping_tol * abs(z[i]) if z[i] != 0 else pz[k] == 0
                ok_m = M[r, k] >= mac_tol
                c = ("stable" if (ok_z and ok_m) else "damping" if ok_z
                     else "mode" if ok_m else "frequency")
                if rank[c] > rank[classes[r]] or (rank[c] == rank[classes[r]]
                                                  and not M[r, k] <= macs[r]):
                    classes[r] = c
                    macs[r] = M[r, k]
        out.append(StabilisationOrder(order=int(n), frequency_hz=f[sel], damping_ratio=z[sel],
                                      classes=tuple(classes), unstable=z[sel] < 0, mac=macs,
                                      index=sel))
        history.append((f, z, psi))
    return StabilisationDiagram(orders=tuple(out), band_hz=(f1, f2), freq_tol=freq_tol,
                                damping_tol=damping_tol, mac_tol=mac_tol)
