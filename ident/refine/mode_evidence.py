"""The evidence for a mode an output-error fit left out (a split mode the robust pipeline
kept, tested against the refined residual): the score test of :func:`omitted_mode_evidence`.
"""

from __future__ import annotations

import numpy as np

from fnsi_lab.ident.errors import IdentError
from fnsi_lab.ident.refine.modal import ModalModel
from fnsi_lab.ident.refine.output_error_result import OutputErrorFit

__all__ = ["omitted_mode_evidence"]


def omitted_mode_evidence(fit: OutputErrorFit, pole: complex, input_vector: np.ndarray,
                          z: np.ndarray) -> float:
    """How much of a refined fit's residual a mode the fit left out would explain.

    The score test of the omitted mode: its pole and input vector held where they were
    (``pole``, discrete time; ``input_vector``, shape (n_inputs + n_basis,), any scale), its
    output vector fitted to ``fit.weighted_residual`` by least squares, row by row.

    Parameters
    ----------
    fit : OutputErrorFit
        A fit without the mode.
    pole : complex
        The mode's discrete-time pole ``mu`` (``Im > 0``).
    input_vector : complex ndarray, shape (n_inputs + n_basis,)
        ``beta`` of the mode in a model that held it.
    z : complex ndarray, shape (n_lines,)
        The data's lines, ``exp(j 2 pi k / N)`` (``FrequencyData.z``).

    Returns
    -------
    float
        The decrease of ``V`` (noise variances) the mode's output vector alone would bring.
        Pure noise gives about the number of outputs; the mode's own parameters number
        ``2 + 2 (n_inputs + n_basis) + 2 n_outputs``, which is what a mode must beat to
        be worth keeping (the Akaike criterion of a complex Gaussian residual).
    """
    if fit.weighted_residual is None or fit.excitation is None \
            or fit.residual_weights is None:
        raise IdentError("the fit holds no residual to test a mode against")
    n_outputs, m_e = fit.weighted_residual.shape[1], fit.excitation.shape[1]
    mode = ModalModel(poles=np.array([pole], complex), real_poles=np.zeros(0),
                      b_pair=np.asarray(input_vector, complex).reshape(1, m_e),
                      b_real=np.zeros((0, m_e)), c_pair=np.zeros((n_outputs, 1), complex),
                      c_real=np.zeros((n_outputs, 0)), d=np.zeros((n_outputs, m_e)))
    phi = mode.regressor(z, fit.excitation, d_free=False)          # (F, 2): Re, Im gamma
    explained = 0.0
    for o in range(n_outputs):
        a = phi * fit.residual_weights[:, o:o + 1]
        a_real = np.concatenate([a.real, a.imag])
        r = fit.weighted_residual[:, o]
        r_real = np.concatenate([r.real, r.imag])
        coef, *_ = np.linalg.lstsq(a_real, r_real, rcond=None)
        explained += float(r_real @ r_real - np.sum((r_real - a_real @ coef) ** 2))
    return explained
