"""The core floor: periodic records to a linear-in-the-parameters FNSI model.

Imports nothing from the floors above (``robust``, ``refine``) nor from the entry point; only
numpy, scipy and :mod:`fnsi_lab.ident.errors`. ``periodic`` (records -> ``FrequencyData``,
``prepare_frequency_data`` running the steps, each in its module: ``frequency_data`` the
containers ``FrequencyData``, ``BasisMotion`` and ``data_report``; ``averaging`` periods,
steady state, the averaged output's noise, steady periods chosen by ``steady``;
``processed_lines`` band, excited lines with ``excitation``, mains lines with ``noise``, ``z``;
``motion`` integration of velocities/accelerations, DC offsets, the motion the basis reads;
``extended_input`` the basis evaluated on it, ``with_basis``), ``basis``, ``spline`` and
``hysteresis`` (the nonlinear basis functions, the extended input; ``hysteresis`` the play
operator of a Jenkins element), the FNSI decomposition split by job:
``subspace`` (one QR + one SVD, ``A`` and ``C``; ``folding`` folds stacked realisations
per line for it), ``bd`` and ``fast_bd`` (``B``, ``D`` by
least squares), ``weights`` (noise weights), ``models`` (a model of a given order),
``state_space`` (the model, its poles, continuous time, FRFs), with ``fnsi`` as their public
face; ``coefficients`` (nonlinear coefficients by signed reciprocity), ``regressors`` (their
conditioning), ``units``, ``time_base`` (the line map of a fixed-order model), ``distortion``
(noise and distortion levels of a record, verdicts; with ``bla`` the best linear
approximation, ``distortion_windows`` the F tests, ``resonances``, ``distortion_records``
and ``level_comparison`` the records compared by level), ``io`` (arrays in),
``model_json`` (a model rebuilt from a result) and ``result`` (the answer's typed records:
``Mode``, ``Coefficient``).
"""
