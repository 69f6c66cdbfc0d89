"""Entity paths and timeline names of everything fnsi-lab logs to Rerun.

One constants module (the pattern of mcap's ``well_known.py``): the ``log_*`` functions of
:mod:`viewer.log` write to these paths and :func:`viewer.blueprint.blueprint` takes its view
origins from them, so a rename happens in one place.

Two kinds of content (``docs/live.md`` says why):

- **time series** (signals, per-update estimates, status) on the ``acq_time`` timeline, the
  one the time panel selects; per-update estimates also on ``update``;
- **figures** indexed by order or frequency (FRF, stabilisation diagram, information
  criterion, MDI, coefficients): static 2D plots (:mod:`viewer.figure`) under a figure
  origin, one entity per series with its physical values attached (``rr.AnyValues``), so
  they show whatever the timeline and export losslessly.
"""

from __future__ import annotations

import re

# ---------------------------------------------------------------------------- timelines
#: Acquisition time of the samples, seconds from the start of the recording (duration).
TIME_ACQ = "acq_time"
#: Identification update counter (sequence, from 1).
TIME_UPDATE = "update"

# ---------------------------------------------------------------------------- roots
#: Time series of the measured channels, one child entity per channel group.
SIGNALS = "/signals"
#: Everything the identification produces.
IDENT = "/ident"
#: Driving-point FRF figure: magnitude (dB) and phase (deg) panels against frequency (Hz).
FRF = "/ident/frf"
FRF_MAGNITUDE = "/ident/frf/magnitude"
FRF_PHASE = "/ident/frf/phase"
FRF_MEASURED = "/ident/frf/magnitude/measured"
FRF_LINEAR = "/ident/frf/magnitude/linear"
FRF_MODEL = "/ident/frf/magnitude/model"
#: Stabilisation diagram: one child per pole class (pole frequency against model order).
STABILISATION = "/ident/stabilisation"
#: Information criterion against order, the chosen order as one marked point.
ORDER = "/ident/order"
ORDER_CRITERION = "/ident/order/criterion"
ORDER_SELECTED = "/ident/order/selected"
#: Modal dominancy index per pole against pole frequency, with the threshold.
MDI = "/ident/mdi"
MDI_KEPT = "/ident/mdi/kept"
MDI_REMOVED = "/ident/mdi/removed"
MDI_THRESHOLD = "/ident/mdi/threshold"
#: Nonlinear coefficients against frequency: per estimated coefficient a panel of Re c_a with
#: ``full`` (before reduction), ``reduced`` (after) and ``exact`` (when known), and one of
#: Im c_a (``<name>/im/{full,reduced,zero}``, dashed).
COEFFICIENTS = "/ident/coefficients"
#: The physical modes of the latest update: damping ratio (%) against natural frequency (Hz),
#: each marker labelled with its mode number (a figure: one update reads at once).
MODES = "/ident/modes"
MODES_POINTS = "/ident/modes/modes"
#: Basis parameters estimated from the data (clearances, exponents): the FNSI model error
#: against each parameter, the estimate marked; one panel per parameter.
PARAMETERS = "/ident/parameters"
#: ``kind: spline`` elements: the restoring-force curve against the relative displacement (or
#: velocity) with its confidence band, one panel per curve (docs/discovery.md).
RESTORING_FORCE = "/ident/restoring_force"
#: Estimates against the update number (pole frequencies, dampings, coefficient means).
CONVERGENCE = "/ident/convergence"
#: Markdown table of the latest result (the paper's Table 2).
SUMMARY = "/ident/summary"
#: Distortion analysis (``fnsi-lab analyse --rrd``): per record, the classic level plot
#: (output, noise, odd / even detection lines, realisations' spread against frequency) of
#: the chosen outputs; the BLAs of every record overlaid; distortion and resonances against
#: level; the verdicts as a markdown table.
ANALYSIS = "/analysis"
ANALYSIS_LEVELS = "/analysis/levels"
ANALYSIS_FRF = "/analysis/frf"
ANALYSIS_TREND = "/analysis/trend"
ANALYSIS_SUMMARY = "/analysis/summary"
#: Live status: scalars (rate, dropped blocks, file size...) and a text log.
STATUS = "/status"
STATUS_LOG = "/status/log"

#: Pole classes of the stabilisation diagram, in legend order (the names of
#: ``ident.robust.stabilisation.STAB_CLASSES`` plus ``unstable`` for poles with zeta < 0).
POLE_CLASSES: tuple[str, ...] = ("new", "frequency", "damping", "mode", "stable", "unstable")

_UNSAFE = re.compile(r"[^A-Za-z0-9_\-.]+")


def part(name: str) -> str:
    """A safe entity-path part for a free-text name (``F-NC2W Z`` -> ``F-NC2W_Z``)."""
    cleaned = _UNSAFE.sub("_", str(name)).strip("_")
    return cleaned or "unnamed"


def signal_group(group: str) -> str:
    """Entity path of one channel group's time series."""
    return f"{SIGNALS}/{part(group)}"


def stabilisation_class(pole_class: str) -> str:
    """Entity path of one pole class of the stabilisation diagram."""
    return f"{STABILISATION}/{part(pole_class)}"


def coefficient_panel(name: str) -> str:
    """Entity path of the panel of coefficient ``name``."""
    return f"{COEFFICIENTS}/{part(name)}"


def coefficient(name: str, which: str) -> str:
    """Entity path of coefficient ``name``; ``which`` in {'full', 'reduced', 'exact'}."""
    return f"{coefficient_panel(name)}/{which}"


def coefficient_im(name: str, which: str) -> str:
    """Entity path of the imaginary part of coefficient ``name`` (its Im panel);
    ``which`` in {'full', 'reduced', 'zero'}."""
    return f"{coefficient_panel(name)}/im/{which}"


def convergence(quantity: str) -> str:
    """Entity path of one convergence quantity (``natural_frequency_hz``...)."""
    return f"{CONVERGENCE}/{part(quantity)}"


def convergence_mode(quantity: str, mode: int) -> str:
    """Entity path of the per-update series of mode ``mode`` (1-based) of ``quantity``."""
    return f"{convergence(quantity)}/mode_{int(mode)}"


#: Per-update coefficient estimates (mean Re c_a over the excited lines), one child each.
CONVERGENCE_COEFFICIENTS = "/ident/convergence/coefficients"
CONVERGENCE_FREQUENCIES = "/ident/convergence/natural_frequency_hz"


def convergence_coefficient(name: str) -> str:
    """Entity path of one coefficient's per-update estimate."""
    return f"{CONVERGENCE_COEFFICIENTS}/{part(name)}"


def status(quantity: str) -> str:
    """Entity path of one status scalar (``rate``, ``dropped_blocks``...)."""
    return f"{STATUS}/{part(quantity)}"
