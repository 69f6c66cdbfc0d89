"""Which time base fits displacement data better, decided by the data (fixed-order runs).

The identified DT model is fitted at the lines' ``z_k``: ``exp(j 2 pi k / N)``
(``band-limited``) or the bilinear warp ``exp(j 2 atan(w_k T / 2))`` (``bilinear``). The two
are different model classes: an order-n continuous-time system is exactly rational of order
n in the bilinear variable, while band-limited samples of it need extra states on the unit
circle. At a low fixed order that decides the fit, and the coefficients follow it (3-channel
SmallSat at order 10, noise-free: model error 4.3e-7 band-limited against 6.8e-8 bilinear,
NC2-Z LS values +0.06 / +0.12 % against +0.03 / +0.08 %); with noise both fit the noise
floor and the band-limited lines did better (40 dB: -0.08 % against -0.14 % on the positive
stop; docs/ident.md). :func:`choose_time_base` fits both at the requested order and keeps
bilinear only when its model error on the excited lines is clearly lower.

Pure functions over :class:`~fnsi_lab.ident.core.frequency_data.FrequencyData`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from fnsi_lab.ident.core.frequency_data import FrequencyData, TimeBase
from fnsi_lab.ident.core.parallel import parallel_map

__all__ = ["with_time_base", "choose_time_base", "BILINEAR_MARGIN"]

#: Bilinear is chosen when its relative model error is below this fraction of the
#: band-limited one. 0.8: two fits of the same data at a noise floor differ by 10-15 %
#: (SmallSat 3 channels at 40 dB, orders 8-12: 1-12 %), while a model-class gap is a
#: factor (noise-free: 1.1-14x).
BILINEAR_MARGIN = 0.8


def with_time_base(data: FrequencyData, time_base: TimeBase, bilinear_period_s: float | None = None
                   ) -> FrequencyData:
    """The same spectra with the line map of another time base.

    Parameters
    ----------
    data : FrequencyData
    time_base : {'band-limited', 'zoh', 'bilinear'}
    bilinear_period_s : float, optional
        ``T`` of the bilinear map; default ``2 / sqrt(w_min w_max)`` over the lines.

    Returns
    -------
    FrequencyData
        Only ``z``, ``time_base`` and ``bilinear_period_s`` differ.
    """
    N = data.samples_per_period
    if time_base in ("band-limited", "zoh"):
        return replace(data, z=np.exp(2j * np.pi * data.lines / N), time_base=time_base,
                       bilinear_period_s=None)
    w = 2 * np.pi * data.frequencies_hz
    T = float(bilinear_period_s) if bilinear_period_s else 2.0 / np.sqrt(w.min() * w.max())
    return replace(data, z=np.exp(2j * np.arctan(w * T / 2)), time_base="bilinear",
                   bilinear_period_s=T)


def choose_time_base(data: FrequencyData, order: int, *, max_order: int | None = None,
                     block_rows: int | None = None, weighted: bool = True,
                     d_zero: bool = False, margin: float = BILINEAR_MARGIN):
    """Fit ``order`` with the band-limited and the bilinear line maps; keep the better.

    Parameters
    ----------
    data : FrequencyData
        Any time base (its spectra are used).
    order : int
    max_order, block_rows, weighted, d_zero
        As for :func:`ident.core.fnsi.subspace_decomposition` / :func:`ident.core.fnsi.model_at_order`.
    margin : float
        Bilinear wins when its model error is below ``margin`` times the band-limited one.

    Returns
    -------
    data : FrequencyData
        With the chosen line map.
    decomposition : SubspaceDecomposition
    model : StateSpaceModel
    report : dict
        ``{"chosen", "model_error": {time base: V}, "margin"}`` (V over the excited lines).
    """
    from fnsi_lab.ident.core import fnsi
    from fnsi_lab.ident.core.fast_bd import model_error

    mo = max(int(order), int(max_order or order))

    def fit(tb: TimeBase):
        d = with_time_base(data, tb, data.bilinear_period_s if tb == data.time_base else None)
        dec = fnsi.subspace_decomposition(d, max_order=mo, block_rows=block_rows,
                                          weighted=weighted)
        m = fnsi.model_at_order(dec, d, int(order), d_zero=d_zero)
        mask = (np.asarray(d.excited, bool) if np.any(d.excited)
                else np.ones(d.n_lines, bool))
        v = model_error(m, d, mask) if m.stable else np.inf
        return d, dec, m, float(v)

    # the two fits are independent: two threads (the same numbers, about 1.6x on 2 cores)
    bases: tuple[TimeBase, TimeBase] = ("band-limited", "bilinear")
    fits = dict(zip(bases, parallel_map(fit, bases)))
    v_band, v_bil = fits["band-limited"][3], fits["bilinear"][3]
    chosen = "bilinear" if v_bil < margin * v_band else "band-limited"
    d, dec, m, _ = fits[chosen]
    report = {"chosen": chosen, "model_error": {"band-limited": v_band, "bilinear": v_bil},
              "margin": margin}
    return d, dec, m, report
