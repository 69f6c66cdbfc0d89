"""FNSI core: one QR and one SVD, then every model order (docs/method.md §1.3-1.7, §2.1-2.2, §3).

The public face of the decomposition, re-exported from the modules that do each job:
:mod:`ident.core.subspace` (the subspace step: QR, SVD, ``A``, ``C``), :mod:`ident.core.bd` (``B``,
``D`` by least squares), :mod:`ident.core.models` (a model of a given order),
:mod:`ident.core.state_space` (the model, its poles, continuous time, FRFs) and
:mod:`ident.core.weights` (noise weights).

Pipeline (each a plain function over arrays, returning frozen dataclasses)::

    data = prepare_frequency_data(...)                      # ident.core.periodic
    dec = subspace_decomposition(data, max_order=60)        # §1.3: one QR, one SVD
    model = model_at_order(dec, data, 10)                   # §1.3 A, C; §1.4 B, D; §1.5 CT
    y_ss = steady_state_output(model, data)                 # §3 exact shortcut
    H = frf(model, f)                                       # §2.2 extended FRF

Discrete-time identification at ``z_k = exp(j 2 pi k / N)``; continuous time by the exact
inverse of zero-order hold, pole by pole.
"""

from __future__ import annotations

from fnsi_lab.ident.core.bd import estimate_bd, project_outputs
from fnsi_lab.ident.core.models import model_at_order, model_at_order_fast, models_for_orders
from fnsi_lab.ident.core.periodic import FrequencyData, prepare_frequency_data
from fnsi_lab.ident.core.state_space import (TIME_BASES, Poles, StateSpaceModel,
                                        band_limited_to_continuous, bilinear_to_continuous,
                                        compute_poles, discrete_to_continuous, frf, make_model,
                                        steady_state_output, transfer_discrete,
                                        underlying_linear_frf)
from fnsi_lab.ident.core.folding import (FOLD_GRAM_ENERGY, FoldedLines, fold_repeated_lines,
                                         merge_repeated_lines)
from fnsi_lab.ident.core.subspace import (SubspaceDecomposition, block_rows_for,
                                          default_block_rows, default_output_rank,
                                          noise_row_limit, output_directions,
                                          significant_input_basis, state_matrices,
                                          subspace_decomposition)

__all__ = ["FrequencyData", "prepare_frequency_data", "SubspaceDecomposition", "Poles",
           "StateSpaceModel", "subspace_decomposition", "default_block_rows", "block_rows_for",
           "noise_row_limit", "default_output_rank", "merge_repeated_lines",
           "fold_repeated_lines", "FoldedLines", "FOLD_GRAM_ENERGY", "significant_input_basis",
           "output_directions", "state_matrices", "model_at_order", "model_at_order_fast",
           "models_for_orders", "estimate_bd", "project_outputs", "make_model",
           "discrete_to_continuous", "compute_poles", "bilinear_to_continuous",
           "steady_state_output", "transfer_discrete", "frf", "underlying_linear_frf",
           "band_limited_to_continuous", "TIME_BASES"]
