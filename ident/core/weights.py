"""Per-line noise weights of the FNSI least squares (docs/method.md §1.3-1.4).

The inverse noise covariance of the outputs per line, smoothed over neighbouring lines, as
the subspace step's SVD weighting and the B, D least squares read it.
"""

from __future__ import annotations

import numpy as np

from fnsi_lab.ident.core.averaging import smooth_lines
from fnsi_lab.ident.core.frequency_data import FrequencyData

#: The full noise covariance (cross-channel terms) is inverted only when the periods give at
#: least this many degrees of freedom per output (an inverse Wishart estimate is unbiased
#: only for P - 1 > p + 1 and very noisy near it); otherwise per-channel variances are used.
_FULL_COV_PERIODS_PER_OUTPUT = 2
#: Half-width (lines) of the moving average of the per-channel noise variances.
_NOISE_SMOOTHING_LINES = 8
#: Lines per chunk when accumulating weighted normal equations (bounds memory).
LINE_CHUNK = 256


def inverse_covariance(data: FrequencyData, weighted: bool) -> np.ndarray | None:
    """Per-line weight ``Q_k = Sigma_Y(k)^{-1}``: shape (F, p, p), or (F, p) real when diagonal,
    or None (identity).

    The sample covariance of ``P`` periods has ``P - 1`` degrees of freedom; unless
    ``P - 1 >= 2 p`` only its diagonal (per-channel variances) is used, averaged over
    +-8 neighbouring lines (the noise spectrum is smooth; a 5-period estimate per line
    scatters by +-45 % and weighting by its inverse raised the coefficient error of a
    noisy 5-output chain from 1-3 % to 12-25 %, docs/ident.md). Variances are floored at
    ``1e-8`` times their mean so that lines with (numerically) no noise do not dominate.
    Cached on the (immutable) data object.
    """
    cov = data.noise_cov
    if not weighted or cov is None:
        return None
    cache = data.__dict__.setdefault("_ident_cache", {})
    if "inv_cov" in cache:
        return cache["inv_cov"]
    var = np.real(cov if cov.ndim == 2 else np.einsum("kii->ki", cov))  # (F, p) variances only
    mean_var = float(np.mean(var))
    q: np.ndarray | None
    if not mean_var > 0:
        q = None
    else:
        floor = 1e-8 * mean_var
        p = cov.shape[1]
        if (cov.ndim == 2 or data.n_periods - 1 < _FULL_COV_PERIODS_PER_OUTPUT * p
                or not np.any(cov - np.einsum("ki,ij->kij", np.einsum("kii->ki", cov), np.eye(p)))):
            # per-channel variances, smoothed over neighbouring lines: from P periods each
            # line's estimate has only P - 1 degrees of freedom and its inverse would weight
            # the lines at random (the noise spectrum itself is smooth)
            q = 1.0 / (smooth_lines_per_block(var, data.lines, _NOISE_SMOOTHING_LINES) + floor)
        else:
            q = np.linalg.inv(cov + floor * np.eye(p))
    cache["inv_cov"] = q
    return q


def smooth_lines_per_block(values: np.ndarray, lines: np.ndarray, half_width: int) -> np.ndarray:
    """:func:`ident.core.averaging.smooth_lines` within each block of stacked realizations.

    ``values`` has shape (F, ...); blocks of stacked realizations (``lines`` restarting) are
    smoothed separately; the window shrinks at the block edges.
    """
    if half_width <= 0 or values.shape[0] < 2:
        return values
    starts = np.flatnonzero(np.r_[True, np.diff(lines) <= 0])
    ends = np.r_[starts[1:], lines.size]
    return np.concatenate([smooth_lines(values[a:b], half_width) for a, b in zip(starts, ends)])


def cov_for_svd(data: FrequencyData, weighted: bool) -> np.ndarray | None:
    """Regularized per-line covariance used in ``C_Y`` (the inverse of the B, D weights)."""
    q = inverse_covariance(data, weighted)
    if q is None:
        return None
    return 1.0 / q if q.ndim == 2 else np.linalg.inv(q)
