"""The refinement floor: what is done to an answer after the robust pipeline.

Imports the core and the robust floor. ``parameter_search`` (basis parameters left to the
data: clearances, exponents, offsets), ``output_error`` (the answer refined on the model's
own periodic steady state: whether to refine and how the lines under the band enter; its
jobs in ``output_error_problem``, the modal problem with its Jacobian and normal equations,
``output_error_fit``, the Levenberg-Marquardt loop, ``output_error_result``, the record and
its JSON summary, and ``mode_evidence``, the evidence for a mode the fit left out),
``harmonic_balance`` (that steady state), ``modal`` (the model in modal parameters) and
``validation`` (a model simulated on another record).
"""
