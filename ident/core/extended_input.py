"""The extended input: the basis functions evaluated on the averaged motion, scaled.

:func:`basis_spectra` (Fourier coefficients of the basis functions on the processed lines,
evaluated on the band-limited fine grid of :class:`ident.core.frequency_data.BasisMotion`,
docs/method.md §8.4) and :func:`with_basis` (``E = [P; sigma_1 H_1; ...]`` rebuilt for a
basis from the kept motion, without the time data; docs/method.md §1.2 steps 3-4).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.ident.core.basis import Nonlinearity, coefficient_names, evaluate_basis
from fnsi_lab.ident.core.frequency_data import BasisMotion, FrequencyData
from fnsi_lab.ident.errors import DeadBasisError, IdentError


def basis_spectra(basis: Sequence[Nonlinearity], motion: BasisMotion) -> tuple[np.ndarray, np.ndarray]:
    """Fourier coefficients of the basis functions on the processed lines.

    Parameters
    ----------
    basis : sequence of Nonlinearity
        Elements with every parameter known; their channels must be in ``motion.channels``.
    motion : BasisMotion

    Returns
    -------
    H : complex ndarray, shape (R * F0, s)
        Unscaled spectra (numpy DFT over the fine period divided by its length), the lines of
        each realization in turn.
    rms : ndarray, shape (s,)
        RMS of each basis function over the fine periods of every realization.
    """
    q, qd = motion.displacement, motion.velocity
    h = np.stack([evaluate_basis(basis, q[r], None if qd is None else qd[r], motion.channels)
                  for r in range(q.shape[0])])                   # (R, N_fine, s)
    rms = np.sqrt(np.mean(h ** 2, axis=(0, 1)))
    H = np.fft.rfft(h, axis=1)[:, motion.lines] / h.shape[1]
    return H.reshape(-1, h.shape[2]), rms


def with_basis(data: FrequencyData, basis: Sequence[Nonlinearity]) -> FrequencyData:
    """The same data with the extended input built for ``basis`` (forces kept).

    Parameters
    ----------
    data : FrequencyData
        Prepared by :func:`ident.core.periodic.prepare_frequency_data` with a ``motion``
        holding the channels of ``basis`` (``basis=`` or ``motion_for=`` there).
    basis : sequence of Nonlinearity

    Returns
    -------
    FrequencyData
        ``E = [P; sigma_1 H_1; ...]`` with ``sigma_a = rms(p) / rms(h_a)``.

    Raises
    ------
    IdentError
        No motion kept, or a channel of ``basis`` not measured.
    DeadBasisError
        A basis function identically zero on these data.
    """
    from dataclasses import replace

    basis = tuple(basis)
    m = data.n_inputs
    if not basis:
        return replace(data, E=data.E[:, :m], input_scale=data.input_scale[:m], basis_names=())
    for nl in basis:
        nl.location_vector(data.output_names)        # ChannelError naming the outputs
    motion = data.motion
    if motion is None or not all(c in motion.channels for nl in basis for c in nl.channels):
        raise IdentError("these frequency data do not hold the motion of the basis channels "
                         "(prepare them with basis= or motion_for=)")
    if motion.velocity is None and any(nl.needs_velocity for nl in basis):
        raise IdentError("these frequency data hold no velocities for the velocity-dependent "
                         "basis functions (prepare them with basis= or motion_for=)")
    H, rms_h = basis_spectra(basis, motion)
    names = coefficient_names(basis)
    if np.any(rms_h == 0):
        dead = [n for n, v in zip(names, rms_h) if v == 0]
        raise DeadBasisError(f"basis functions {plain.names(dead, quote=True)} are identically "
                             "zero on these data "
                             "(clearance larger than the motion, or wrong channels)",
                             dead=tuple(dead))
    sigma = np.concatenate([np.ones(m), motion.force_rms / rms_h])
    E = np.concatenate([data.E[:, :m], H * sigma[m:]], axis=1)
    return replace(data, E=E, input_scale=sigma, basis_names=names)
