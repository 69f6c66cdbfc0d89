"""Frequency-domain nonlinear subspace identification (FNSI) and its robust pipeline.

Axis conventions (stated once, never transposed mid-pipeline)
-------------------------------------------------------------
- time signals: ``(n_samples, n_channels)``;
- periodic records: ``(n_realizations, n_periods, n_samples, n_channels)``
  (``(n_periods, n_samples, n_channels)`` and ``(n_samples, n_channels)`` are accepted and
  promoted);
- spectra: ``(n_lines, n_channels)``; noise covariances ``(n_lines, n_out, n_out)``;
- FRFs: ``(n_lines, n_out, n_in)``, so batched ``@`` and ``solve`` broadcast over frequency;
- state-space matrices: ``A (n, n)``, ``B (n, m_e)``, ``C (p, n)``, ``D (p, m_e)`` where
  ``m_e = m + s`` is the number of extended inputs (``m`` forces then ``s`` basis columns).

Units: Hz for frequencies (``frequency_hz``), rad/s for continuous-time eigenvalues,
damping as a ratio, SI units otherwise. DFT: numpy sign convention
``X(k) = sum_t x(t) exp(-j 2 pi k t / N)``, so the discrete-time frequency variable of line
``k`` is ``z_k = exp(j 2 pi k / N)``.

Extended input (docs/method.md §1.1): ``e = [p; h_1; ...; h_s]`` with ``+h_a`` (Noël/seed sign). A
basis function ``h_a`` acts on the signed combination ``delta_a = L_a^T q`` of measured
channels; the element force on the structure is ``c_a h_a(delta_a) L_a``.

Modules
-------
``periodic``      periodic records -> :class:`FrequencyData` (averaging, noise covariance)
``basis``         nonlinear basis functions and extended input
``fnsi``          one QR + one SVD, every order; B/D least squares; CT conversion; FRFs
``coefficients``  nonlinear coefficients by signed reciprocity (docs/method.md §2.3)
``pipeline``      the entry point; ``identification`` its frozen answer
                  :class:`Identification` and the JSON (``result``: the answer's :class:`Mode`
                  and :class:`Coefficient` records); ``fit`` FNSI at an order or the robust
                  pipeline; ``refinement`` the output-error refinement's decision and start;
                  ``linear_comparison`` the answer against the linear fit;
                  ``coefficient_summaries`` the coefficients with their verdicts
``output_error``  the answer refined on the model's own periodic steady state
                  (``harmonic_balance``: that steady state; ``modal``: the model's parameters)
``config``, ``io``, ``cli``  the ``fnsi-lab ident`` command

``ident`` depends on numpy, scipy and :mod:`fnsi_lab.errors`/:mod:`fnsi_lab.validate` only.
"""

from fnsi_lab.ident.errors import (ChannelError, IdentError, IdentWarning,  # noqa: F401
                          NotIdentifiableError)

__all__ = ["IdentError", "ChannelError", "NotIdentifiableError", "IdentWarning"]
