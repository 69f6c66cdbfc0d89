"""The public Python API of fnsi-lab (docs/api.md).

Three calls cover the lab's jobs::

    import fnsi_lab
    report = fnsi_lab.acquire(out="run.mcap")             # record the simulated SmallSat
    with fnsi_lab.open_recording("run.mcap") as rec:      # what is in a recording
        print(rec.channels[0].name, rec.sample_rate_hz)
    result = fnsi_lab.identify("run.mcap", config="smallsat39")   # robust pipeline
    print(result.order, result.modes[0]["frequency_hz"], result.coefficients[0]["value"])

:func:`identify` is the one entry point of an identification: the ``fnsi-lab ident`` and
``fnsi-lab report`` commands, batch campaigns and the benchmarks of the whole
identification (``bench/reproduce_paper.py``, ``bench/bench_pipeline.py``,
``bench/scaling.py``...) call it. The live service (``fnsi-lab live/replay/run``), whose
periods are already in memory, calls :func:`fnsi_lab.ident.pipeline.identify_input`, which
:func:`identify` wraps: the same configuration and the same pipeline either way.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

if TYPE_CHECKING:   # imported on first use (module __getattr__ below): a light `import fnsi_lab`
    from fnsi_lab.ident.pipeline import Identification

__all__ = ["identify", "analyse", "locate", "open_recording", "acquire", "load_config", "Identification"]


def load_config(config: Any) -> Any:
    """An :class:`~fnsi_lab.ident.config.IdentConfig` from what a user may give.

    Parameters
    ----------
    config : str, path, mapping or IdentConfig
        A YAML file, the name of a packaged example (``'smallsat39'``, ``'smallsat3'``,
        ``'lumped-stop'``, ``'lumped-cubic'``), the YAML content as a mapping, or a parsed
        config (returned as is).

    Raises
    ------
    IdentConfigError
        Missing file, unknown name or invalid content (one line naming file and field).
    """
    from fnsi_lab.ident.config import (IdentConfig, load_ident_config, packaged_config,
                                       parse_ident_config)
    from fnsi_lab.ident.errors import IdentError

    if isinstance(config, IdentConfig):
        return config
    if isinstance(config, Mapping):
        return parse_ident_config(dict(config), file="<dict>")
    path = Path(os.fspath(config))
    if not path.exists() and path.parent == Path("."):
        try:
            path = packaged_config(str(config))
        except IdentError:
            pass  # the loader reports the missing file with its name
    return load_ident_config(path)


def _as_input(source: Any, samples_per_period: int | None) -> Any:
    from fnsi_lab.ident.core.io import IdentInput, input_from_arrays
    from fnsi_lab.inputs import load_input

    if isinstance(source, IdentInput):
        return source
    if isinstance(source, Mapping):
        return input_from_arrays(dict(source), "<arrays>", samples_per_period)
    if isinstance(source, (list, tuple)):   # several records: one identification over all
        from fnsi_lab.ident.core.io import stack_records

        return stack_records([_as_input(s, samples_per_period) for s in source])
    return load_input(source, samples_per_period=samples_per_period)


def _recorded_driving_point(source: Any) -> str | None:
    """The output a recording's channel table places at its first force's node and
    direction (or whose name ends the force's: ``F-NC2W-Z`` -> ``NC2W-Z``); None when the
    source is not a recording or its table does not say."""
    if not isinstance(source, (str, os.PathLike)) or Path(source).suffix.lower() != ".mcap":
        return None
    from fnsi_lab.daq.recording.reader import open_recording as _open

    with _open(source) as rec:
        outs, ins = rec.output_channels, rec.input_channels
    if not ins:
        return None
    force = ins[0]
    for c in outs:
        if force.node and c.node == force.node and c.direction == force.direction:
            return c.name
    return next((c.name for c in outs if force.name.endswith(c.name)), None)


def identify(source: Any, config: Any = None, *, order: int | None = None,
             orders: Any = None, reduce_at: int | None = None, max_order: int | None = None,
             block_rows: int | None = None, progress: Any = False,
             samples_per_period: int | None = None,
             blas_threads: int | None = 1, validation: Any = None) -> "Identification":
    """Identify the underlying linear modes and nonlinear coefficients of a structure.

    Parameters
    ----------
    source : str, path, mapping or IdentInput, or a list of them
        An fnsi-lab recording (``.mcap``), an array file (``.npz``/``.mat``: ``u``, ``y``,
        ``fs``, optional ``N``, ``channels``, ...; docs/ident.md), the same arrays as a
        mapping, or an :class:`~fnsi_lab.ident.core.io.IdentInput`. A list: several records
        of one structure (force levels, realisations), identified together as the
        realisations of one input (:func:`ident.core.io.stack_records`: one model for all;
        docs/ident.md, "Several records at once").
    config : str, path, mapping or IdentConfig, optional
        See :func:`load_config`. None: the excited band, the driving point where a
        recording's channel table puts an output at the force's node and direction, and for
        simulated recordings the basis functions of the recording's truth (measured data: a
        linear model).
    order : int, optional
        Fixed model order, a whole number >= 1 (``6.0`` is 6; ``6.7`` or ``'x'`` are refused
        as on the command line). None (default): the robust automatic pipeline (information
        criterion, stabilisation, modal dominancy index, reduction).
    orders : str or sequence of int, optional
        Order sweep of the robust pipeline (``'2:60'``, ``'2:60:2'``, ``'4,6,8'``);
        default the config's ``auto.orders``, else 2..60.
    reduce_at : int, optional
        Order at which the MDI and the reduction are applied (default: the selected order).
    max_order : int, optional
        Largest order of a fixed-order decomposition (default: the order).
    block_rows : int, optional
        Block rows ``i`` of the subspace step (default from the data sizes).
    progress : bool, optional
        Progress bar over the order sweep on stderr.
    samples_per_period : int, optional
        ``N`` when the file does not say (else the config's).
    blas_threads : int or None, optional
        OpenBLAS threads during the identification (default 1; the process's own count is
        restored afterwards; None: leave it as it is). The many small solves of the order
        sweep gain nothing from threads, and threads oversubscribe a small machine: the
        README example took 23 s with the default OpenBLAS threads and 1.3 s with one, on
        a loaded 2-core machine. The answer does not depend on it (docs/method.md §1.3).
    validation : str, path, mapping or IdentInput, or a list of them, optional
        Other records of the same structure and channels (other force levels, another
        realisation). The nested test's simulation check (docs/ident.md, "... on another
        record") then predicts these records instead of the identified one: the nonlinear
        terms are kept only if the nonlinear model predicts no output of any of them worse
        than the linear fit of the identified record, and has a steady state under each
        one's force. A level below and a level above: a friction model checked only on the
        level above can be worse than the linear fit on the levels below.

    Returns
    -------
    Identification
        ``.order``, ``.modes``, ``.coefficients``, ``.model``, ``.to_json()`` (the dict that
        ``fnsi-lab ident --json`` writes).

    Raises
    ------
    FnsiLabError
        Any problem with the input, the configuration or the identification, as one line;
        a bad ``order``, ``max_order``, ``block_rows``, ``reduce_at`` or ``orders`` is a
        :class:`~fnsi_lab.errors.ConfigError` naming it, before anything is read.

    Examples
    --------
    >>> import numpy as np, fnsi_lab
    >>> fs, n = 256.0, 256                       # a 1-DOF oscillator, 5 periods
    >>> t = np.arange(5 * n) / fs
    >>> u = sum(np.cos(2 * np.pi * k * t + k ** 2) for k in range(2, 40))
    >>> from scipy import signal
    >>> sys = signal.cont2discrete(([1.0], [1.0, 2 * 0.02 * 2 * np.pi * 20, (2 * np.pi * 20) ** 2]),
    ...                            1 / fs, method="zoh")
    >>> y = signal.lfilter(sys[0][0], sys[1], np.tile(u[:n], 30))[-5 * n:]
    >>> r = fnsi_lab.identify({"u": u, "y": y, "fs": fs, "N": n},
    ...                       {"band_hz": [2, 40]}, order=2)
    >>> round(r.modes[0]["frequency_hz"], 2)
    20.0
    """
    import time

    from fnsi_lab.arguments import check_order_options
    from fnsi_lab.blas import limit_blas_threads, restored_blas_threads
    from fnsi_lab.ident.pipeline import identify_request
    from fnsi_lab.ident.request import check_order, resolve_request

    # the order rules of the command line, before anything is read
    check_order_options(order=order, max_order=max_order, block_rows=block_rows,
                        reduce_at=reduce_at, orders=orders)
    t0 = time.perf_counter()
    cfg = load_config(config) if config is not None else None
    inp = _as_input(source, samples_per_period or (cfg.samples_per_period if cfg else None))
    request = resolve_request(inp, cfg, order=order, orders=orders, reduce_at=reduce_at,
                              max_order=max_order, block_rows=block_rows,
                              driving_point=(_recorded_driving_point(
                                  source[0] if isinstance(source, (list, tuple)) else source)
                                  if cfg is None
                                             else None))
    others = []
    wanted = (list(validation) if isinstance(validation, (list, tuple)) else
              [] if validation is None else [validation])
    identified = {Path(p).resolve() for p in (source if isinstance(source, (list, tuple))
                                              else [source]) if isinstance(p, (str, os.PathLike))}
    if all(isinstance(r, (str, os.PathLike)) and Path(r).resolve() in identified
           for r in wanted):
        wanted = []      # only identified records: the check's default reads each of them
    seen = set()
    for record in wanted:
        if isinstance(record, (str, os.PathLike)):
            if Path(record).resolve() in seen:
                continue     # named twice: checked once
            seen.add(Path(record).resolve())
        # an identified record named beside others is checked with them (simulation.own),
        # not dropped: the model must predict each record named no worse than the linear fit
        from fnsi_lab.ident.linear_comparison import validation_input

        rc = request.config   # each record's channels and rate checked before any work
        other = _as_input(record, samples_per_period or (cfg.samples_per_period if cfg
                                                         else None))
        validation_input(other, rc.outputs or inp.output_channels,
                         [i.name for i in rc.inputs] or inp.input_channels, inp.sample_rate_hz,
                         rc.output_quantity or inp.output_quantity, units=inp.channel_units,
                         transient_periods=rc.transient_periods)
        others.append(other)
    load_s = time.perf_counter() - t0
    with restored_blas_threads():
        if blas_threads is not None:
            limit_blas_threads(check_order(blas_threads, "blas_threads"))
        return identify_request(inp, request, progress=progress, spent_s={"load": load_s},
                                validation=others or None)


def analyse(sources: Any, config: Any = None, *, band_hz: Any = None, alpha: float = 0.01,
            samples_per_period: int | None = None) -> Any:
    """Nonlinear distortion analysis of multisine records, before any model.

    Parameters
    ----------
    sources : str, path, mapping or IdentInput, or a sequence of them
        One record, or several records of one structure (e.g. force levels).
    config : str, path, mapping or IdentConfig, optional
        Its ``inputs[0].name`` (the drive), ``outputs`` and ``transient_periods`` are used
        (:func:`load_config`).
    band_hz : (float, float), optional
        Analysed band (default: lowest excited line to three times the highest, at most
        0.45 fs).
    alpha : float
        Family-wise false-alarm probability of a record's "nonlinear" verdicts.
    samples_per_period : int, optional
        ``N`` when the file does not say (else the config's).

    Returns
    -------
    fnsi_lab.ident.analysis.DistortionReport
        ``.records[i].outputs[j].verdict``, ``.records[i].resonances``, ``.levels``,
        ``.to_json()`` (what ``fnsi-lab analyse --json`` writes; docs/discovery.md).

    Examples
    --------
    >>> import numpy as np, fnsi_lab
    >>> from fnsi_lab.daq.multisine import multisine
    >>> ms = multisine(1024, 256.0, (2, 60), 1.0, n_periods=4, grid="random-odd")
    >>> u = ms.signal[0]
    >>> y = np.fft.irfft(np.fft.rfft(u) / (1 + 1j * np.fft.rfftfreq(u.size, 1 / 256) / 20), u.size)
    >>> rng = np.random.default_rng(0)
    >>> data = {"u": u, "y": y + 1e-3 * rng.standard_normal(u.size), "fs": 256.0, "N": 1024}
    >>> fnsi_lab.analyse(data).records[0].outputs[0].verdict
    'linear within the noise'
    """
    from fnsi_lab.ident.analysis import analyse_inputs

    cfg = load_config(config) if config is not None else None
    many = (isinstance(sources, (list, tuple)) and not isinstance(sources, Mapping))
    items = list(sources) if many else [sources]
    n = samples_per_period or (cfg.samples_per_period if cfg else None)
    inputs = [_as_input(s, n) for s in items]
    return analyse_inputs(inputs, cfg, band_hz=None if band_hz is None else
                          (float(band_hz[0]), float(band_hz[1])), alpha=alpha)


def locate(source: Any, config: Any = None, *, candidates: Any = "all",
           order: int | None = None, refine: int | None = None, knots: int | None = None,
           form: str = "auto", progress: Any = None,
           samples_per_period: int | None = None) -> Any:
    """Where is the structure nonlinear: candidate locations ranked (docs/discovery.md).

    Parameters
    ----------
    source : str, path, mapping or IdentInput, or a list of them
        As for :func:`identify` (a list: several levels judged together).
    config : str, path, mapping or IdentConfig, optional
        Band, inputs, outputs and order (its nonlinearities are not used). None: the
        excited band.
    candidates : {'all', 'channels', 'pairs'}, str path or sequence of mapping
        Each channel to ground, each pair in the same direction, both (default), a YAML/JSON
        file of location vectors, or the list itself (``[{'A': 1, 'B': -1}, ...]``).
    order : int, optional
        Linear model order (default: the config's, else the minimum-description-length
        order).
    refine, knots : int, optional
        Candidates of the screen re-ranked by FNSI with a spline of ``knots`` knots
        (defaults :data:`ident.locate.REFINE_TOP`, :data:`ident.locate.REFINE_KNOTS`).
    form : {'auto', 'generic', 'jenkins'}
        The force offered at each candidate: the generic columns, or a Jenkins element
        (stick-slip friction) ranked by the information criterion
        (:mod:`ident.locate_stick_slip`; docs/discovery.md, "Bolted joints"); ``auto``
        (default): the Jenkins element first when there are at most
        :data:`ident.locate.AUTO_STICK_SLIP_CANDIDATES` candidates, kept when it locates
        one, else the generic columns.
    progress : callable(str), optional

    Returns
    -------
    Localisation
        ``.candidates`` (best first: ``channels``, ``score``, ``significance``, ``verdict``),
        ``.located``, ``.to_json()`` (what ``fnsi-lab locate --json`` writes).
    """
    from fnsi_lab.ident import locate as loc
    from fnsi_lab.ident.pipeline import default_config

    cfg = load_config(config) if config is not None else None
    inp = _as_input(source, samples_per_period or (cfg.samples_per_period if cfg else None))
    if cfg is None:
        from dataclasses import replace
        cfg = replace(default_config(inp), nonlinearities=())
    from fnsi_lab.ident.errors import IdentError

    if isinstance(candidates, (str, os.PathLike)) and str(candidates) not in (
            "all", "channels", "pairs"):
        if not Path(os.fspath(candidates)).exists():
            raise IdentError(f"candidates {os.fspath(candidates)!r}: neither all, channels, "
                             "pairs nor an existing file (fix: one of those words, or the path "
                             "of a YAML/JSON list of location vectors)")
        source = os.fspath(candidates)
        candidates = loc.read_candidates_file(source)
        # a misspelt channel: named with the file (locate_input checks again, without it)
        loc.check_candidate_channels(candidates, list(cfg.outputs or inp.output_channels),
                                     source)
    for name, value in (("refine", refine), ("knots", knots)):
        if value is not None and int(value) < 0:
            raise IdentError(f"{name} {value} is negative (fix: 0 or more)")
    return loc.locate_input(inp, cfg, candidates=candidates, order=order,
                            refine=loc.REFINE_TOP if refine is None else int(refine),
                            knots=loc.REFINE_KNOTS if knots is None else int(knots),
                            form=form, progress=progress)


def open_recording(path: str | os.PathLike[str], **kwargs: Any) -> Any:
    """Open an fnsi-lab MCAP recording for reading (a context manager).

    See :func:`fnsi_lab.daq.recording.reader.open_recording` for the options
    (``salvage``, ``validate_crcs``...). The result has ``channels``, ``sample_rate_hz``,
    ``metadata``, ``excitation``, ``truth``, ``iter_blocks()``, ``read_samples()`` and
    ``read_periodic()``.
    """
    from fnsi_lab.daq.recording.reader import open_recording as _open

    return _open(path, **kwargs)


def acquire(config: Any = None, out: str | os.PathLike[str] | None = None, *,
            realtime: bool = False, force: bool = False) -> Any:
    """Run an experiment and record everything it acquires to MCAP.

    Parameters
    ----------
    config : str, path or ExperimentConfig, optional
        Experiment YAML (or a packaged name); default the simulated SmallSat test.
    out : path, optional
        The recording (default: the experiment's ``output``). An existing file is refused
        unless ``force``.
    realtime : bool
        Pace a simulated source at wall-clock speed, as hardware would deliver.
    force : bool
        Replace an existing output file.

    Returns
    -------
    AcquisitionReport
        Blocks, samples, drops and the output path (``report.output``).
    """
    from fnsi_lab.daq.acquisition import record_experiment
    from fnsi_lab.daq.config import ExperimentConfig, load_experiment
    from fnsi_lab.outputs import check_output_path

    cfg = config if isinstance(config, ExperimentConfig) else load_experiment(config)
    path = check_output_path(out if out is not None else cfg.output, force=force,
                             inputs=[config if not isinstance(config, ExperimentConfig) else None,
                                     cfg.file])
    return record_experiment(cfg, path, realtime=realtime)


def __getattr__(name: str) -> Any:
    if name == "Identification":
        from fnsi_lab.ident.pipeline import Identification

        return Identification
    raise AttributeError(f"module 'fnsi_lab.api' has no attribute {name!r}")
