"""What the live service runs on each snapshot: the nonparametric FRF, or the one
identification entry point with the request resolved as ``fnsi-lab ident`` resolves it
(:func:`config_identifier`), so live, replayed and offline answers agree.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
from fnsi_lab.daq.channels import ChannelInfo
from fnsi_lab.replay.service import Identifier


# ---------------------------------------------------------------------------- identifiers
@dataclass(frozen=True)
class FrfResult:
    """Nonparametric estimate: FRFs at the excited lines from the averaged periods.

    Attributes
    ----------
    frequencies_hz : ndarray, shape (n_lines,)
    frf : complex ndarray, shape (n_lines, n_out, n_in)
        ``Y / U`` of the period-averaged spectra (single input) or least squares over
        realizations (several inputs).
    noise_std : ndarray, shape (n_lines, n_out)
        Standard deviation of the averaged output spectrum (NaN with one period).
    n_periods : int
        Steady-state periods averaged per realization.
    output_names, input_names : tuple of str
    """

    frequencies_hz: np.ndarray
    frf: np.ndarray
    noise_std: np.ndarray
    n_periods: int
    output_names: tuple[str, ...]
    input_names: tuple[str, ...]


def frf_identifier(record: Any) -> FrfResult:
    """A fast nonparametric identification of a periodic record (baseline and tests).

    Parameters
    ----------
    record : PeriodicRecord
        ``u`` (R, P, N, m), ``y`` (R, P, N, p); the first ``transient_periods`` are dropped.

    Returns
    -------
    FrfResult
    """
    t = int(record.transient_periods)
    u = np.asarray(record.u)[:, t:]
    y = np.asarray(record.y)[:, t:]
    n = record.samples_per_period
    lines = np.asarray(record.excited_lines, dtype=np.int64)
    if lines.size == 0:
        lines = np.arange(1, (n - 1) // 2 + 1)
    U = np.fft.rfft(u, axis=2)[:, :, lines] / n          # (R, P, F, m)
    Y = np.fft.rfft(y, axis=2)[:, :, lines] / n          # (R, P, F, p)
    Um, Ym = U.mean(axis=1), Y.mean(axis=1)              # (R, F, m), (R, F, p)
    p_count = U.shape[1]
    if p_count > 1:
        noise = np.sqrt(np.mean(np.var(Y, axis=1, ddof=1), axis=0) / p_count)
    else:
        noise = np.full(Ym.shape[1:], np.nan)
    # (F, p, m) = Y^T U^+ over realizations (R >= m); for R = m = 1 a plain division.
    Yf = np.transpose(Ym, (1, 2, 0))                     # (F, p, R)
    Uf = np.transpose(Um, (1, 2, 0))                     # (F, m, R)
    frf = Yf @ np.linalg.pinv(Uf)
    return FrfResult(frequencies_hz=lines * record.sample_rate_hz / n, frf=frf,
                     noise_std=noise, n_periods=p_count,
                     output_names=tuple(c.name for c in record.output_channels),
                     input_names=tuple(c.name for c in record.input_channels))


def driving_point(output_channels: Sequence[ChannelInfo], input_channels: Sequence[ChannelInfo],
                  input_index: int = 0) -> int:
    """Index of the output measured where (node, direction) the force ``input_index`` acts.

    Falls back to a name match (``F-NC2W-Z`` -> ``NC2W-Z``), then to output 0.
    """
    force = input_channels[input_index]
    for i, c in enumerate(output_channels):
        if force.node and c.node == force.node and c.direction == force.direction:
            return i
    for i, c in enumerate(output_channels):
        if force.name.endswith(c.name):
            return i
    return 0


# ---------------------------------------------------------------------------- robust pipeline
@dataclass(frozen=True)
class AutoIdentification:
    """What :func:`config_identifier` returns for one snapshot.

    Attributes
    ----------
    identification : fnsi_lab.ident.pipeline.Identification
        The answer of the one entry point (:func:`fnsi_lab.ident.pipeline.identify_input`).
    coefficient_curves : dict
        ``{'full': {name: c(f)}, 'reduced': {name: c(f)}, 'frequency_hz': f}`` when the
        configuration has basis functions, else empty.
    exact_coefficients : dict
        Known coefficient values (simulations), name -> value.
    """

    identification: Any
    coefficient_curves: dict
    exact_coefficients: dict

    @property
    def result(self) -> Any:
        """The robust pipeline's :class:`~fnsi_lab.ident.robust.auto_result.AutoResult`."""
        return self.identification.auto

    @property
    def data(self) -> Any:
        """The :class:`~fnsi_lab.ident.core.periodic.FrequencyData` identified."""
        return self.identification.data


# ---------------------------------------------------------------------------- ident config
def config_identifier(config: Any = None, *, truth: Mapping[str, Any] | None = None,
                      orders: Sequence[int] | str | None = None,
                      channels: Sequence[ChannelInfo] = (), harmonics: float = 1.0,
                      use_truth: bool = True) -> tuple[Identifier, str]:
    """``identify(record)`` running the one identification entry point on each snapshot.

    Every snapshot goes through :func:`fnsi_lab.ident.pipeline.identify_input` with the
    same configuration as ``fnsi-lab ident --auto`` would use (its ``auto:`` section
    included), so live, replayed and offline results agree.

    Parameters
    ----------
    config : IdentConfig or None
        Band, basis functions, driving points, options. None: the excited band and, for
        simulated recordings, the basis of ``truth``
        (:func:`fnsi_lab.ident.pipeline.default_config`).
    truth : mapping, optional
        Recording truth (nonlinear elements, exact coefficients).
    orders : str or sequence of int, optional
        Order sweep; default the config's ``auto.orders``, else
        :data:`fnsi_lab.ident.request.DEFAULT_ORDERS` (2..60, as ``fnsi-lab ident --auto``).
    channels : sequence of ChannelInfo
        The recording's channels (driving point when the config names none).
    harmonics : float
        Without a config and with basis functions: process the lines up to ``harmonics``
        times the highest excited frequency (see ``default_config``). 1: the excited band.
    use_truth : bool
        False: no basis from the truth (a linear identification without a config).

    Returns
    -------
    (callable, str)
        The identifier and a one-line description.
    """
    from dataclasses import replace

    from fnsi_lab.ident.robust.options import parse_orders
    from fnsi_lab.ident.pipeline import identify_request
    from fnsi_lab.ident.request import DEFAULT_ORDERS, resolve_request

    from fnsi_lab.inputs import input_from_record

    # for the description only: each snapshot's request is resolved as `ident` resolves it
    sweep = (parse_orders(orders) if orders is not None
             else list(config.orders) if config is not None and config.orders
             else list(DEFAULT_ORDERS))
    outputs = [c for c in channels if not c.is_force]
    inputs = [c for c in channels if c.is_force]
    dp_name = outputs[driving_point(outputs, inputs)].name if outputs and inputs else None

    def identify(record: Any) -> AutoIdentification:
        import warnings

        inp = input_from_record(record, path="<live>")
        if not use_truth:
            inp = replace(inp, truth=None)
        elif inp.truth is None and truth is not None:
            inp = replace(inp, truth=dict(truth))
        request = resolve_request(inp, config, orders=orders, harmonics=harmonics,
                                  driving_point=dp_name)
        with warnings.catch_warnings():  # steady-state warnings go to the status, not stderr
            warnings.simplefilter("ignore")
            ident = identify_request(inp, request)
        curves: dict = {}
        if ident.config.nonlinearities:
            res = ident.auto
            curves["frequency_hz"] = ident.data.frequencies_hz
            for which, model in (("full", res.full_model), ("reduced", res.reduced)):
                if model is not None:
                    sp = ident.coefficient_spectra_of(model)
                    curves[which] = {n: sp.values[:, i] for i, n in enumerate(sp.names)}
        exact = {n: float(v) for nl in ident.config.nonlinearities if nl.truth is not None
                 for n, v in zip(nl.coefficient_names, nl.truth) if v is not None}
        return AutoIdentification(identification=ident, coefficient_curves=curves,
                                  exact_coefficients=exact)

    what = (f"robust pipeline, orders {sweep[0]}-{sweep[-1]}"
            + (f", config {config.file}" if config is not None and config.file else
               ", excited band" + (", basis from the recording truth" if use_truth else "")))
    return identify, what


def auto_identifier(*, orders: Sequence[int] | str | None = None) -> Identifier:
    """A linear ``identify(record)`` over the excited band (no config, no basis functions)."""
    return config_identifier(None, orders=orders, use_truth=False)[0]
