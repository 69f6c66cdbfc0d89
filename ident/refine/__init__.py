"""The refinement floor: what is done to an answer after the robust pipeline.

Imports the core and the robust floor. ``parameter_search`` (basis parameters left to the
data: clearances, exponents, offsets), ``output_error`` (the answer refined on the model's
own periodic steady state), ``harmonic_balance`` (that steady state), ``modal`` (the model in
modal parameters) and ``validation`` (a model simulated on another record).
"""
