"""Hysteretic friction: the Jenkins element (a spring in series with a Coulomb slider).

A bolted joint that sticks and slips is not a function of the present displacement and
velocity: its force depends on where the joint last slipped. The simplest law with that
memory is the Jenkins element, a spring ``k`` in series with a slider that slips at
``F_s``. With ``slip = F_s / k`` (m) the spring's elongation ``z`` follows the play
operator of the relative displacement ``delta``::

    z[n] = clip(z[n-1] + delta[n] - delta[n-1], -slip, +slip)

and the force is ``k z``: ``k`` times ``delta`` (less the slip so far) while the joint
sticks, ``+-F_s`` while it slips. Closed loops in the force-displacement plane, the
energy per cycle ``4 F_s (A - slip)`` for an amplitude ``A > slip``, and a linear spring
(no dissipation) for ``A <= slip``.

FNSI reads basis functions on one period of the averaged, periodic motion, so the element
is evaluated in its periodic steady state: the play operator is run over the period twice
and the second pass kept. After one pass the state no longer depends on the start (the
pass has crossed the period's largest and smallest ``delta``, which wipe out any earlier
memory), so the second pass is exactly periodic.

docs/method.md §2.6, docs/discovery.md (bolted joints).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["periodic_play", "periodic_play_slope", "periodic_play_anchors"]


@njit(cache=True, nogil=True)
def _play_two_passes(delta: np.ndarray, slip: float) -> tuple[np.ndarray, np.ndarray]:
    """The play operator over two passes of one period; returns (z, stuck) of the second."""
    n = delta.shape[0]
    z_out = np.empty(n)
    stuck = np.empty(n)
    z = 0.0
    previous = delta[n - 1]
    for p in range(2):
        for i in range(n):
            trial = z + delta[i] - previous
            previous = delta[i]
            if trial > slip:
                z, moving = slip, 0.0
            elif trial < -slip:
                z, moving = -slip, 0.0
            else:
                z, moving = trial, 1.0
            if p == 1:
                z_out[i] = z
                stuck[i] = moving
    return z_out, stuck


@njit(cache=True, nogil=True)
def _anchors(delta: np.ndarray, slip: float) -> np.ndarray:
    """Per sample of the second pass: the last slipping sample before it (its stick phase's
    start), -1 on a slipping sample, ``n - 1`` throughout when it never slips."""
    n = delta.shape[0]
    out = np.empty(n, np.int64)
    z = 0.0
    previous = delta[n - 1]
    anchor = n - 1
    for p in range(2):
        for i in range(n):
            trial = z + delta[i] - previous
            previous = delta[i]
            if trial > slip or trial < -slip:
                z = slip if trial > slip else -slip
                anchor = i
                if p == 1:
                    out[i] = -1
            else:
                z = trial
                if p == 1:
                    out[i] = anchor
    return out


def periodic_play_anchors(delta: np.ndarray, slip: float) -> np.ndarray:
    """Where each stick phase of the periodic cycle began: the memory of the element.

    While the joint sticks, ``z[n] = z[a] + delta[n] - delta[a]`` with ``a`` the last
    slipping sample (``z[a] = +-slip``), so a perturbation of the motion moves ``z`` by
    ``d_delta[n] - d_delta[a]``; while it slips ``z`` does not move. This is the exact
    directional derivative the harmonic balance's Newton steps need (the tangent of
    :func:`periodic_play_slope` alone drops the ``- d_delta[a]`` term).

    Parameters
    ----------
    delta : ndarray, shape (n_samples,)
        One period of the relative displacement, as in :func:`periodic_play`.
    slip : float

    Returns
    -------
    ndarray of int, shape (n_samples,)
        ``a`` per sample, ``-1`` where the joint slips.
    """
    d = np.ascontiguousarray(delta, dtype=float)
    if d.size == 0:
        return np.zeros(0, np.int64)
    return _anchors(d, float(slip))


def periodic_play(delta: np.ndarray, slip: float) -> np.ndarray:
    """Elongation of a Jenkins element's spring in periodic steady state.

    Parameters
    ----------
    delta : ndarray, shape (n_samples,)
        One period of the relative displacement across the joint (m, or the outputs'
        length unit), samples in time order; the period wraps from the last sample to the
        first.
    slip : float
        Slip displacement ``F_s / k`` (same unit as ``delta``), > 0.

    Returns
    -------
    z : ndarray, shape (n_samples,)
        The spring's elongation, in ``[-slip, slip]``; the joint's force is ``k z``.
    """
    d = np.ascontiguousarray(delta, dtype=float)
    if d.size == 0:
        return d.copy()
    return _play_two_passes(d, float(slip))[0]


def periodic_play_slope(delta: np.ndarray, slip: float) -> np.ndarray:
    """Tangent ``dz / d(delta)`` along the periodic cycle: 1 where the joint sticks, 0
    where it slips (the linearisation the harmonic balance needs; a finite difference of
    the whole record is 0, since a constant shift of ``delta`` leaves ``z`` unchanged).

    Parameters
    ----------
    delta : ndarray, shape (n_samples,)
        One period of the relative displacement, as in :func:`periodic_play`.
    slip : float
        Slip displacement (same unit as ``delta``).

    Returns
    -------
    ndarray, shape (n_samples,)
    """
    d = np.ascontiguousarray(delta, dtype=float)
    if d.size == 0:
        return d.copy()
    return _play_two_passes(d, float(slip))[1]
