"""The robust floor: from the core's models of every order to the automatic answer.

Imports the core only. ``order_selection`` (information criterion), ``stabilisation``
(the diagram), ``mdi`` (modal dominancy index), ``reduction`` (model reduction), ``auto``
(``identify_auto``: the automatic pipeline) and its result ``auto_result``, ``options``
(``AutoOptions``, order sweeps), ``verdict`` (a verdict for every coefficient) and
``pole_fate`` (one vocabulary for what happened to each pole) and ``nested`` (the answer
tested against the linear fit of the same data).
"""
