"""Options of the robust pipeline and the one order-range syntax.

:class:`AutoOptions` is what the ``auto:`` section of an ident YAML parses into
(:func:`fnsi_lab.ident.config.parse_ident_config`) and what
:func:`fnsi_lab.ident.robust.auto.identify_auto` takes; :func:`parse_orders` reads every order
sweep given on a command line or in a config (``2:60``, ``2:60:2``, ``4,6,8``, ``10``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from fnsi_lab import plain
from fnsi_lab.ident.robust import mdi as mdi_mod
from fnsi_lab.ident.robust import order_selection as osel
from fnsi_lab.ident.errors import IdentError

__all__ = ["AutoOptions", "OUT_OF_BAND", "parse_orders"]

OUT_OF_BAND: tuple[str, ...] = ("keep", "stabilised", "drop")



@dataclass(frozen=True)
class AutoOptions:
    """Options of the robust pipeline (all keyword, validated by :meth:`validate`).

    Attributes
    ----------
    ic_band : {'auto', 'processed', 'excited'} or (float, float)
        Lines of the model error V (docs/method.md §8.3); see :func:`ident.robust.order_selection.ic_line_mask`.
    criterion : {'mdl', 'seed', 'aic'}
        ``I(n)`` (:func:`ident.robust.order_selection.information_criterion`). ``mdl`` (default):
        Rissanen's minimum description length with the state-space parameter count,
        ``V exp(n_theta ln(N_r) / N_r)``. ``seed``: the paper's ``V (1 + n/F)`` (Eq. 8),
        whose penalty is 3 % at n = 60 and F = 2000 lines, so on a noise or model-error
        plateau its minimum falls anywhere (SmallSat at 40 dB: order 60 against 28 with
        ``mdl``, docs/robust.md); its values are reported either way. ``aic``: AIC-style.
    band_of_interest_hz : (float, float) or None
        Band of the MDI and of the stabilisation diagram; default the excited band.
    mdi_norm : {'h2', 'seed', 'h2_single', 'hinf', 'hinf_band'}
        Norm that classifies (all are reported).
    input_scaling : {'default', 'force', 'raw'}
        Column weights of the modal input rows (docs/method.md §5.2).
    output_scaling : {'rms', 'noise', 'none'}
        Row weights of the modal output shapes (:func:`ident.robust.mdi.output_weights`): ``rms``
        counts every channel by its relative response, so a mode that dominates a few
        low-amplitude channels (an instrument plate next to a wheel that moves 10x more)
        is not drowned by the large channels. Not in the seed; ``none`` is the seed's
        absolute sum.
    require_stabilised : bool
        Veto: a mode above the MDI threshold that is not stabilised in frequency against the
        previous order (class ``new``) is dropped and reported (docs/method.md §8.5). The gap search
        itself runs over every stable in-band mode.
    min_physical : int
        Search the largest gap below the ``min_physical`` largest candidates.
    top_n : int or None
        Keep exactly the ``top_n`` largest candidates (weak genuine modes; docs/method.md §7.5).
    manual_threshold : float or None
        Keep candidates with MDI above this value.
    group_split_modes : bool
        Group near-duplicate poles with cancelling residues (docs/method.md §7.5).
    freq_tol, damping_tol, mac_tol : float
        Stabilisation tolerances (docs/method.md §4).
    out_of_band : {'keep', 'stabilised', 'drop'}
        Poles outside the band of interest, which the MDI does not judge. ``keep``
        (default): every stable pole outside the band stays in the reduced model (real
        poles too): genuine modes above the excitation band carry the response the basis
        functions drive there, and a pole fitting residual content there does not disturb
        ``c_a`` in the band. ``stabilised``: only the pairs stabilised (at least in
        frequency) against the neighbouring orders and standing out of the residual in
        their bandwidth (``detection_sigma``). ``drop`` (one reading of the seed): only the
        physical in-band modes. Unstable and Nyquist poles are always removed. On the
        SmallSat (39 channels) ``drop`` raised the coefficient std 3-20x and ``stabilised``
        up to 8x against ``keep`` (docs/robust.md). JSON ``poles`` flag as physical the
        out-of-band pairs that pass the ``stabilised`` test, whatever the policy.
    sweep_bd : {'fast', 'weighted'}
        B, D of the sweep's models when the data carry a noise covariance: ``fast`` uses the
        unweighted modal-form least squares for every order (they only feed V(n); poles and
        mode shapes come from A, C of the weighted SVD) and re-estimates the selected and MDI
        models with the weighted routine (docs/method.md §1.4); ``weighted`` uses it for every order
        (about 1-3 s per order with 39 outputs).
    stab_lookback : int
        Previous orders each pole is compared with (best class kept); 2 because the sweep
        visits odd orders, which hold a real pole and are poor references for pairs.
    d_zero : bool
        ``D = 0`` in every least squares (displacement/velocity outputs).
    weighted : bool
        Use the noise covariance in the SVD and B, D least squares when available.
    block_rows : int or None
        ``i``; default from the core.
    ambiguous_ratio, clear_ratio : float
        Separation ratios below ``ambiguous_ratio`` are reported as ambiguous, above
        ``clear_ratio`` as clear (docs/method.md §7.4: "below about 2, call it ambiguous").
    fallback : {'stabilisation', 'none'}
        Combine the MDI split with stabilisation (docs/method.md §7.5, §8.5): an eligible mode below
        the gap is kept if it is fully stable (frequency, damping and MACX against the
        neighbouring orders); when the largest-gap ratio is below ``clear_ratio``, any mode
        stabilised in frequency with ``MDI >= fallback_rel_floor * max MDI`` is kept too. Reason: when no spurious
        pole lies in band the largest gap falls between genuine modes, and dropping a genuine
        mode degrades the reduced model (measured on the lumped model: +8.9 % coefficient
        error) whereas keeping a weak spurious one only forgoes an improvement.
    order_selection : {'consistent', 'ic'}
        ``ic``: the selected order is ``argmin I`` (seed Eq. 8). ``consistent`` (default,
        used when the coefficients can be computed: basis functions and a measured driving
        point): ``argmin I`` over the orders whose coefficient spread ``rho(n)``
        (:func:`ident.core.coefficients.coefficient_spread`) is within ``spread_factor`` of the
        smallest; see :func:`ident.robust.order_selection.select_order_consistent`.
    detection_sigma : float
        A mode is physical only if its energy in its bandwidth exceeds this many standard
        deviations of the residual's energy there (:func:`ident.robust.mdi.modal_detection`);
        0 disables the test. 5 rather than 3 because residuals are not white when they are
        model error rather than noise: a fully stable spurious pole of a noise-free 3-DOF
        chain reached 3.8, genuine weak modes 29-700 (docs/robust.md).
    spread_factor : float
        Gate of ``consistent`` selection. 3: on the SmallSat the orders whose coefficients
        were within 0.1-0.3 % had ``rho`` within 3x of the best (docs/robust.md).
    real_poles : {'keep', 'stabilised'}
        Real (non-oscillating) poles outside the modes, under ``out_of_band: keep``: ``keep``
        (default) leaves every stable one in the answer; ``stabilised`` only those that pass
        the out-of-band plausibility test (stabilised and detectable). Measured: on the lab
        Duffing ``stabilised`` answered order 2 in 10/10 realisations (value spread 0.23 %
        against 0.29 % at orders 2-3), on the Silverbox periods order 2 in 10/10 but spread
        1.10 % against 1.03 %, and on the 3-channel SmallSat at 40 dB it raised the positive
        stop's error from -0.05 % to -0.13 % (docs/robust.md).
    min_half_power_lines : float
        A kept mode whose half-power half-width ``zeta f_n`` is below this many line
        spacings ``fs / N`` falls between the lines (its damping is poorly determined): the
        confidence is not "clear", and within 3 lines of a 50/60 Hz harmonic the pole is
        taken for hum and dropped. 0.5 (the SmallSat's narrowest mode spans 4.7 lines, a
        genuine mode of the 3-DOF test chain 0.25); 0 disables both.
    fallback_rel_floor : float
        Relative MDI floor of the not-clear-gap fallback (docs/method.md §7.5 suggests 1e-3). Fully
        stable modes need no floor: weakly excited genuine modes carry MDI 1e-6 to 1e-3 of the
        largest (docs/method.md §8.5; SmallSat modes 9-11 with 39 channels).
    """

    ic_band: Any = "auto"
    criterion: str = "mdl"
    band_of_interest_hz: tuple | None = None
    mdi_norm: mdi_mod.MdiNorm = "h2"
    input_scaling: mdi_mod.InputScaling = "default"
    output_scaling: str = "rms"
    require_stabilised: bool = True
    min_physical: int = 1
    top_n: int | None = None
    manual_threshold: float | None = None
    group_split_modes: bool = True
    freq_tol: float = 0.01
    damping_tol: float = 0.05
    mac_tol: float = 0.98
    stab_lookback: int = 2
    sweep_bd: str = "fast"
    out_of_band: str = "keep"
    d_zero: bool = False
    weighted: bool = True
    block_rows: int | None = None
    ambiguous_ratio: float = 2.0
    clear_ratio: float = 10.0
    fallback: str = "stabilisation"
    fallback_rel_floor: float = 1e-3
    order_selection: str = "consistent"
    spread_factor: float = 3.0
    detection_sigma: float = 5.0
    min_half_power_lines: float = 0.5
    real_poles: str = "keep"

    def validate(self) -> "AutoOptions":
        """Raise :class:`IdentError` naming the bad option and the allowed values."""
        if self.criterion not in osel.CRITERIA:
            raise IdentError(f"criterion={self.criterion!r} is not one of {plain.names(osel.CRITERIA)}")
        if self.mdi_norm not in mdi_mod.MDI_NORMS:
            raise IdentError(f"mdi_norm={self.mdi_norm!r} is not one of {plain.names(mdi_mod.MDI_NORMS)}")
        if self.output_scaling not in ("rms", "noise", "none"):
            raise IdentError(f"output_scaling={self.output_scaling!r} is not one of "
                             "rms, noise, none")
        if self.input_scaling not in mdi_mod.INPUT_SCALINGS:
            raise IdentError(f"input_scaling={self.input_scaling!r} is not one of "
                             f"{plain.names(mdi_mod.INPUT_SCALINGS)}")
        if isinstance(self.ic_band, str) and self.ic_band not in osel.IC_BANDS:
            raise IdentError(f"ic_band={self.ic_band!r} is not one of {plain.names(osel.IC_BANDS)} or [f1, f2] in Hz")
        if self.top_n is not None and self.manual_threshold is not None:
            raise IdentError("give top_n or manual_threshold, not both")
        if self.sweep_bd not in ("fast", "weighted"):
            raise IdentError(f"sweep_bd={self.sweep_bd!r} is not one of fast, weighted")
        if self.out_of_band not in OUT_OF_BAND:
            raise IdentError(f"out_of_band={self.out_of_band!r} is not one of {plain.names(OUT_OF_BAND)}")
        if self.fallback not in ("stabilisation", "none"):
            raise IdentError(f"fallback={self.fallback!r} is not one of stabilisation, none")
        if self.order_selection not in ("consistent", "ic"):
            raise IdentError(f"order_selection={self.order_selection!r} is not one of "
                             "consistent, ic")
        if not self.detection_sigma >= 0:
            raise IdentError(f"detection_sigma must be >= 0, got {self.detection_sigma}")
        if self.real_poles not in ("keep", "stabilised"):
            raise IdentError(f"real_poles={self.real_poles!r} is not one of keep, stabilised")
        if not self.min_half_power_lines >= 0:
            raise IdentError(f"min_half_power_lines must be >= 0, got {self.min_half_power_lines}")
        if not self.spread_factor >= 1:
            raise IdentError(f"spread_factor must be >= 1, got {self.spread_factor}")
        if self.min_physical < 1:
            raise IdentError(f"min_physical must be >= 1, got {self.min_physical}")
        return self

    @classmethod
    def from_dict(cls, d: dict | None) -> "AutoOptions":
        """From a plain mapping (YAML ``auto:`` section); unknown keys are rejected."""
        d = dict(d or {})
        names = set(cls.__dataclass_fields__)
        bad = sorted(set(d) - names)
        if bad:
            raise IdentError(f"unknown auto option(s) {plain.names(bad)}; allowed: {plain.names(sorted(names))}")
        for k in ("band_of_interest_hz",):
            if d.get(k) is not None:
                d[k] = tuple(float(x) for x in d[k])
        if isinstance(d.get("ic_band"), (list, tuple)):
            d["ic_band"] = tuple(float(x) for x in d["ic_band"])
        return cls(**d).validate()


def parse_orders(text: str | int | range | list | tuple) -> list[int]:
    """Order sweep from ``'2:60'`` (inclusive), ``'2:60:2'`` (step), ``'4,6,8'`` or ``'10'``.

    Sequences and ranges are accepted as they are (validated). Returns sorted unique orders.

    Raises
    ------
    IdentError
        Not one of those forms, or an order below 1.
    """
    if isinstance(text, (range, list, tuple)):
        nums = [int(n) for n in text]
    else:
        s = str(text).replace(" ", "")
        try:
            if ":" in s:
                parts = [int(p) for p in s.split(":")]
                if len(parts) not in (2, 3) or parts[1] < parts[0] or (
                        len(parts) == 3 and parts[2] < 1):
                    raise ValueError
                nums = list(range(parts[0], parts[1] + 1, parts[2] if len(parts) == 3 else 1))
            else:
                nums = [int(p) for p in s.split(",") if p]
        except ValueError:
            raise IdentError(f"orders {text!r}: expected FIRST:LAST, FIRST:LAST:STEP or a "
                             "comma-separated list (e.g. 2:60, 2:60:2, 4,6,8)") from None
    if not nums or min(nums) < 1:
        raise IdentError(f"orders {text!r}: orders must be integers >= 1")
    return sorted(set(nums))
