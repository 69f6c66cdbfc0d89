"""The refinement floor: what is done to an answer after the robust pipeline.

Imports the core and the robust floor. ``parameter_search`` (basis parameters left to the
data: clearances, exponents, offsets; the search and its retry from a second start), with its
jobs in ``search_space`` (the search spaces and the basis at given values),
``search_fit`` (the fixed-state fit behind the objective, the search's block rows and order),
``search_objective`` (the objective at the candidate points: memo, threads, coarse scans),
``motion_noise`` (what the noise in the measured motion adds, and whether to correct it),
``search_newton`` (Newton on the continuous parameters, the curvature at the estimate),
``search_start`` (the second start from the stops open), ``search_refusal`` (refusals and
notes) and ``search_result`` (the records), and ``slip_search`` (a Jenkins element's slip, with
any stop's clearances, by the information criterion); ``output_error`` (the answer refined on the
model's own periodic steady state: whether to refine and how the lines under the band
enter), with its jobs in ``output_error_problem`` (the modal problem, its Jacobian and
normal equations), ``output_error_fit`` (the Levenberg-Marquardt loop),
``output_error_result`` (the record and its JSON summary) and ``mode_evidence`` (the
evidence for a mode the fit left out); ``harmonic_balance`` (that steady state), ``modal``
(the model in modal parameters) and ``validation`` (a model simulated on another record).
"""
