"""A model of a given order from the subspace decomposition (docs/method.md §1.3-1.7):
``A``, ``C`` from the observability, ``B``, ``D`` by least squares, continuous time.
"""

from __future__ import annotations

from fnsi_lab.ident.core.bd import estimate_bd, estimate_bd_given_modes, project_outputs
from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.core.fast_bd import fast_estimate_bd
from fnsi_lab.ident.core.frequency_data import FrequencyData
from fnsi_lab.ident.core.state_space import StateSpaceModel, eigen_decomposition, make_model
from fnsi_lab.ident.core.subspace import (SubspaceDecomposition, state_matrices,
                                     state_matrices_block)

__all__ = ["model_at_order", "models_for_orders", "model_at_order_fast", "compressed_outputs"]


def model_at_order(decomp: SubspaceDecomposition, data: FrequencyData, order: int, *,
                   d_zero: bool = False) -> StateSpaceModel:
    """The model of order ``n`` from the first ``n`` singular directions.

    Parameters
    ----------
    decomp : SubspaceDecomposition
    data : FrequencyData
        The same data as given to :func:`subspace_decomposition`.
    order : int
        ``1 <= n <= decomp.max_order``.
    d_zero : bool
        Constrain ``D = 0`` (displacement/velocity outputs, docs/method.md §1.4).

    Returns
    -------
    StateSpaceModel

    Notes
    -----
    docs/method.md §1.3 shift invariance: ``C = Gamma[0:p]``, ``A = Gamma[0:(i-1)p]^+ Gamma[p:ip]``
    (least squares; each block row whitened by ``decomp.shift_weight`` when weighted);
    ``B``, ``D`` by :func:`estimate_bd` (§1.4); CT by the exact ZOH inverse (§1.5) or the
    bilinear inverse (§1.6) per ``data.time_base``. The models are nested in the state basis, not in their poles (§1.7).
    """
    n = int(order)
    if not 1 <= n <= decomp.max_order:
        raise IdentError(f"order: {n} is outside 1..{decomp.max_order}, the largest order "
                         "of this decomposition (fix: a lower order, or a larger max_order / "
                         "--max-order or more block rows)")
    a_d, c_d = state_matrices(decomp, n)
    modal = eigen_decomposition(a_d)
    b_d, d_d = estimate_bd_given_modes(a_d, c_d, data, d_zero=d_zero, weighted=decomp.weighted, modal=modal)
    return make_model(a_d, b_d, c_d, d_d, sample_rate_hz=data.sample_rate_hz,
                      n_inputs=data.n_inputs, input_names=data.extended_input_names,
                      output_names=data.output_names, time_base=data.time_base,
                      bilinear_period_s=data.bilinear_period_s, _modal_dt=modal)


def models_for_orders(decomp: SubspaceDecomposition, data: FrequencyData, orders, *,
                      d_zero: bool = False) -> list[StateSpaceModel]:
    """:func:`model_at_order` for each order (docs/method.md §1.7)."""
    return [model_at_order(decomp, data, int(n), d_zero=d_zero) for n in orders]


def compressed_outputs(decomp, data, d_zero):
    """``project_outputs(data, W)`` of a compressed decomposition, cached on ``data``."""
    cache = data.__dict__.setdefault("_ident_cache", {})
    key = ("compressed", id(decomp.output_basis), bool(d_zero))
    hit = cache.get(key)
    if hit is None or hit[0] is not decomp.output_basis:
        hit = cache[key] = (decomp.output_basis,) + project_outputs(
            data, decomp.output_basis, d_zero=d_zero)
    return hit[1:]


def model_at_order_fast(decomp, data, order, *, d_zero=False, weighted_bd=True):
    """:func:`ident.model_at_order` with :func:`fast_estimate_bd` for B, D.

    ``A`` and ``C`` always come from ``decomp`` (weighted SVD if it was). ``B``, ``D`` use the
    fast unweighted routine unless the decomposition is weighted and ``weighted_bd``. When
    the decomposition is compressed (``decomp.output_basis`` ``W``) the least squares runs
    on the ``r`` channels ``Y W`` and ``D = W D_r + D_perp`` (exact,
    :func:`ident.project_outputs`); the model keeps its ``r``-channel form for
    :func:`model_error`.
    """
    if decomp.weighted and weighted_bd:
        return model_at_order(decomp, data, order, d_zero=d_zero)
    n = int(order)
    if not 1 <= n <= decomp.max_order:
        raise IdentError(f"order: {n} is outside 1..{decomp.max_order}, the largest order "
                         "of this decomposition (fix: a lower order, or a larger max_order / "
                         "--max-order or more block rows)")
    W = decomp.output_basis
    a_d, c_r = state_matrices_block(decomp, n)
    fit_data = data if W is None else compressed_outputs(decomp, data, d_zero)[0]
    bd = fast_estimate_bd(a_d, c_r, fit_data, d_zero=d_zero)
    if bd is None:
        b_d, d_r = estimate_bd(a_d, c_r, fit_data, d_zero=d_zero, weighted=False)
    else:
        b_d, d_r = bd
    if W is None:
        c_d, d_d = c_r, d_r
    else:
        c_d, d_d = W @ c_r, W @ d_r + compressed_outputs(decomp, data, d_zero)[1]
    model = make_model(a_d, b_d, c_d, d_d, sample_rate_hz=data.sample_rate_hz,
                            n_inputs=data.n_inputs, input_names=data.extended_input_names,
                            output_names=data.output_names, time_base=data.time_base,
                            bilinear_period_s=data.bilinear_period_s)
    if W is not None:  # the r-channel twin: model error in O(F n r)
        model.__dict__["_compressed"] = (c_r, d_r) + compressed_outputs(decomp, data, d_zero)
    return model
