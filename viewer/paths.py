"""Entity paths and timeline names of everything fnsi-lab logs to Rerun.

One constants module (the pattern of mcap's ``well_known.py``): the ``log_*`` functions of
:mod:`viewer.log` write to these paths and :func:`viewer.blueprint.blueprint` takes its view
origins from them, so a rename happens in one place.

Rerun time-series views plot against the timeline selected in the time panel, so every
entity is indexed on exactly one "x" timeline and appears in the views of that timeline:

========================  ==================  =============================================
timeline                  kind                entities
========================  ==================  =============================================
``acq_time``              duration (s)        signals, convergence, status
``update``                sequence            convergence (also on ``acq_time``)
``model_order``           sequence            stabilisation diagram, information criterion
``frequency_mHz``         sequence (mHz)      FRFs, MDI per pole, nonlinear coefficients
========================  ==================  =============================================
"""

from __future__ import annotations

import re

# ---------------------------------------------------------------------------- timelines
#: Acquisition time of the samples, seconds from the start of the recording (duration).
TIME_ACQ = "acq_time"
#: Identification update counter (sequence, from 1).
TIME_UPDATE = "update"
#: Model order n of the one-SVD sweep (sequence): x axis of the stabilisation diagram.
TIME_ORDER = "model_order"
#: Frequency in integer millihertz (sequence): x axis of FRFs, MDI and coefficients.
#: Rerun has no float-valued x axis other than time, so 12.5 Hz is logged at 12500.
TIME_FREQUENCY = "frequency_mHz"

# ---------------------------------------------------------------------------- roots
#: Time series of the measured channels, one child entity per channel group.
SIGNALS = "/signals"
#: Everything the identification produces.
IDENT = "/ident"
#: Driving-point FRF magnitudes (dB): measured, underlying linear, model.
FRF = "/ident/frf"
FRF_MEASURED = "/ident/frf/measured"
FRF_LINEAR = "/ident/frf/linear"
FRF_MODEL = "/ident/frf/model"
#: Stabilisation diagram: one child per pole class (frequency against model order).
STABILISATION = "/ident/stabilisation"
#: Information criterion against order, and the chosen order as one marked point.
ORDER = "/ident/order"
ORDER_CRITERION = "/ident/order/criterion"
ORDER_SELECTED = "/ident/order/selected"
#: Modal distribution index per pole (log10) against pole frequency, with the threshold.
MDI = "/ident/mdi"
MDI_KEPT = "/ident/mdi/kept"
MDI_REMOVED = "/ident/mdi/removed"
MDI_THRESHOLD = "/ident/mdi/threshold"
#: Nonlinear coefficients against frequency: one child per coefficient, then
#: ``full`` (before reduction), ``reduced`` (after) and ``exact`` (when known).
COEFFICIENTS = "/ident/coefficients"
#: Estimates against the update number (pole frequencies, dampings, coefficient means).
CONVERGENCE = "/ident/convergence"
#: Markdown table of the latest result (the paper's Table 2).
SUMMARY = "/ident/summary"
#: Live status: scalars (rate, dropped blocks, file size...) and a text log.
STATUS = "/status"
STATUS_LOG = "/status/log"

#: Pole classes of the stabilisation diagram, in legend order (spec §4; the names of
#: ``ident.stabilisation.STAB_CLASSES`` plus ``unstable`` for poles with zeta < 0).
POLE_CLASSES: tuple[str, ...] = ("new", "frequency", "damping", "mode", "stable", "unstable")

_UNSAFE = re.compile(r"[^A-Za-z0-9_\-.]+")


def part(name: str) -> str:
    """A safe entity-path part for a free-text name (``F-NC2W Z`` -> ``F-NC2W_Z``)."""
    cleaned = _UNSAFE.sub("_", str(name)).strip("_")
    return cleaned or "unnamed"


def versioned(base: str, update: int | None) -> str:
    """Entity of one identification update under ``base`` (``base/update_3``); ``base`` if None.

    Data indexed by order or frequency get one child entity per update: Rerun averages
    values that share an x position within one series, so successive updates must not
    share an entity. :mod:`viewer.log` hides the previous update's child when it logs a
    new one (static ``visible_series``), so each plot shows the newest estimate while the
    older ones stay in the recording (tick them in the legend to compare).
    """
    return base if update is None else f"{base}/update_{int(update)}"


def signal_group(group: str) -> str:
    """Entity path of one channel group's time series."""
    return f"{SIGNALS}/{part(group)}"


def stabilisation_class(pole_class: str) -> str:
    """Entity path of one pole class of the stabilisation diagram."""
    return f"{STABILISATION}/{part(pole_class)}"


def coefficient(name: str, which: str) -> str:
    """Entity path of coefficient ``name``; ``which`` in {'full', 'reduced', 'exact'}."""
    return f"{COEFFICIENTS}/{part(name)}/{which}"


def convergence(quantity: str) -> str:
    """Entity path of one convergence series (``natural_frequency_hz``...)."""
    return f"{CONVERGENCE}/{part(quantity)}"


#: Per-update coefficient estimates (mean Re c_a over the excited lines), one child each.
CONVERGENCE_COEFFICIENTS = "/ident/convergence/coefficients"
CONVERGENCE_FREQUENCIES = "/ident/convergence/natural_frequency_hz"


def convergence_coefficient(name: str) -> str:
    """Entity path of one coefficient's per-update estimate."""
    return f"{CONVERGENCE_COEFFICIENTS}/{part(name)}"


def status(quantity: str) -> str:
    """Entity path of one status scalar (``rate``, ``dropped_blocks``...)."""
    return f"{STATUS}/{part(quantity)}"
