"""Modal dominancy index (MDI), automatic threshold and separation ratio.

Pure functions over arrays (docs/method.md §5 and §7; seed paper §4, Eq. 13-20). Conventions:
continuous-time poles ``lam`` in rad/s, bands in rad/s unless the name says ``_hz``, modal
output shapes ``c_hat`` of shape ``(n_out, n_poles)``, modal input rows ``b_hat`` of shape
``(n_poles, n_in)``.

The index of a pole measures how much the model's FRF changes, in a frequency band, when the
pole is removed with the other modal parameters kept. Removing pole i leaves the modal error
``R_i / (j w - lam_i)`` with the rank-one residue ``R_i = c_hat[:, i] b_hat[i, :]`` (Eq. 14).

Norms offered (all squared, Eq. 17 is a squared norm):

``h2`` (default)
    Exact frequency-restricted H2 norm (Eq. 16) of the modal error of the **conjugate pair**,
    cross term included (docs/method.md §5.2). A real pole uses the single-pole value.
``seed``
    Our reading of the seed's Eq. 18 (near-side arctan only, doubled).
``h2_single``
    Eq. 16-17 applied to one complex pole alone.
``hinf``
    ``sigma_max(R_i) / |Re lam_i|`` (Eq. 19-20), not restricted to the band.
``hinf_band``
    The H-infinity norm over the band and its mirror only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Sequence

import numpy as np

from fnsi_lab import plain
from fnsi_lab.ident.errors import IdentError

MdiNorm = Literal["h2", "seed", "h2_single", "hinf", "hinf_band"]
MDI_NORMS: tuple[str, ...] = ("h2", "seed", "h2_single", "hinf", "hinf_band")
InputScaling = Literal["default", "force", "raw"]
INPUT_SCALINGS: tuple[str, ...] = ("default", "force", "raw")

__all__ = [
    "ModalDominancy", "Threshold", "modal_decomposition", "modal_dominancy",
    "frh2_single", "frh2_pair", "frh2_seed", "hinf_single", "hinf_band", "frh2_sum",
    "largest_gap_threshold", "group_split_modes", "input_weights", "output_weights", "MDI_NORMS",
    "INPUT_SCALINGS", "modal_detection",
]


def _check_choice(name: str, value: str, allowed: Sequence[str]) -> None:
    if value not in allowed:
        raise IdentError(f"{name}={value!r} is not one of {plain.names(allowed)}")


def _band(band: Sequence[float]) -> tuple[float, float]:
    w1, w2 = (float(band[0]), float(band[1]))
    if not (0.0 <= w1 < w2) or not np.isfinite(w2):
        raise IdentError(f"band must satisfy 0 <= w1 < w2 < inf, got {plain.value(band)}")
    return w1, w2


# --------------------------------------------------------------------------------------
# Closed forms for one residue
# --------------------------------------------------------------------------------------
def _p(beta, sigma, w1, w2):
    """``P(beta) = atan((w2 - beta)/sigma) - atan((w1 - beta)/sigma)`` (docs/method.md §5.2)."""
    return np.arctan((w2 - beta) / sigma) - np.arctan((w1 - beta) / sigma)


def frh2_single(r2, lam, band):
    """Squared frequency-restricted H2 norm of ``R / (j w - lam)`` (one pole).

    Parameters
    ----------
    r2 : float or ndarray
        ``||R||_F^2``.
    lam : complex or complex ndarray
        Pole(s), rad/s, ``Re lam != 0``.
    band : (float, float)
        ``[w1, w2]`` in rad/s; the mirror band ``[-w2, -w1]`` is included (Eq. 16).

    Returns
    -------
    float or ndarray
        ``||R||^2 [P(beta) + P(-beta)] / (2 pi sigma)`` with ``lam = -sigma + j beta``.

    Notes
    -----
    Seed Eq. 16-17 taken literally for one pole; docs/method.md §5.2. ``|sigma|`` is used, so the
    value is the (finite) band integral for an unstable pole too.
    """
    w1, w2 = _band(band)
    lam = np.asarray(lam, dtype=complex)
    sigma = np.abs(lam.real)
    beta = lam.imag
    return np.asarray(r2) * (_p(beta, sigma, w1, w2) + _p(-beta, sigma, w1, w2)) / (2 * np.pi * sigma)


def frh2_pair(r2, cross, lam, band):
    """Squared FRH2 norm of the conjugate pair ``R/(jw - lam) + conj(R)/(jw - conj(lam))``.

    Parameters
    ----------
    r2 : float or ndarray
        ``||R||_F^2``.
    cross : complex or complex ndarray
        ``trace(R^H conj(R))``; for ``R = c b`` it is ``conj((c^T c)(b b^T))``.
    lam : complex or complex ndarray
        Pole(s) with ``Im lam > 0``, rad/s.
    band : (float, float)
        ``[w1, w2]`` rad/s (mirror band included).

    Returns
    -------
    float or ndarray
        ``(1/pi) {||R||^2 [P(b) + P(-b)] / sigma + 2 Re[cross (atan(w2/c) - atan(w1/c)) / c]}``
        with ``c = -conj(lam)`` (docs/method.md §5.2).

    Notes
    -----
    ``trace(g^H g) = ||R||^2 (1/|jw-lam|^2 + 1/|jw-conj lam|^2) + 2 Re[cross/(w^2 + c^2)]``
    and ``int dw/(w^2 + c^2) = atan(w/c)/c``; ``w/c`` never meets the arctan branch cuts for
    real ``w`` and ``Re c != 0`` (the expression is even in ``c``, so unstable poles work).
    """
    w1, w2 = _band(band)
    lam = np.asarray(lam, dtype=complex)
    sigma = np.abs(lam.real)
    beta = lam.imag
    c = -np.conj(lam)
    direct = np.asarray(r2) * (_p(beta, sigma, w1, w2) + _p(-beta, sigma, w1, w2)) / sigma
    crossint = (np.arctan(w2 / c) - np.arctan(w1 / c)) / c
    return (direct + 2.0 * np.real(np.asarray(cross) * crossint)) / np.pi


def frh2_seed(r2, lam, band):
    """Seed Eq. 18 as we read it (near-side arctan, doubled): option ``'seed'``.

    ``(1/pi) ||R||^2 / |Re lam| [atan((w2 - |Im lam|)/|Re lam|) - atan((w1 - |Im lam|)/|Re lam|)]``.
    Equals :func:`frh2_single` for a real pole and is within about 1 % of :func:`frh2_pair`
    for lightly damped in-band modes (docs/method.md §5.2).
    """
    w1, w2 = _band(band)
    lam = np.asarray(lam, dtype=complex)
    sigma = np.abs(lam.real)
    return np.asarray(r2) * _p(np.abs(lam.imag), sigma, w1, w2) / (np.pi * sigma)


def hinf_single(rnorm, lam):
    """H-infinity MDI ``sigma_max(R)/|Re lam|`` (seed Eq. 20), attained at ``w = Im lam``.

    ``rnorm`` is ``sigma_max(R) = ||c|| ||b||`` for a rank-one residue. Not band-limited.
    """
    lam = np.asarray(lam, dtype=complex)
    return np.asarray(rnorm) / np.abs(lam.real)


def hinf_band(rnorm, lam, band):
    """Band-restricted H-infinity MDI of one pole (docs/method.md §5.3).

    ``||R||/|Re lam|`` if ``|Im lam|`` lies in ``[w1, w2]``, else
    ``||R|| / sqrt(sigma^2 + (|beta| - w_edge)^2)`` with ``w_edge`` the nearest band edge.
    The sup over the band and its mirror of ``||R||/|jw - lam|``.
    """
    w1, w2 = _band(band)
    lam = np.asarray(lam, dtype=complex)
    sigma = np.abs(lam.real)
    b = np.abs(lam.imag)
    dist = np.where(b < w1, w1 - b, np.where(b > w2, b - w2, 0.0))
    return np.asarray(rnorm) / np.sqrt(sigma ** 2 + dist ** 2)


def _int_cross(a, b, w1, w2):
    """``int_{w1}^{w2} dw / (conj(jw - a) (jw - b))`` in closed form (a, b broadcast).

    Partial fractions: ``1/((-jw - conj a)(jw - b)) = -[1/(jw - b) - 1/(jw + conj a)]/(b + conj a)``;
    ``int dw/(jw - b) = -j log(w + j b)`` and ``int dw/(jw + conj a) = -j log(w - j conj a)``.
    The imaginary parts of ``w + j b`` (``Re b``) and ``w - j conj a`` (``-Re a``) are constant
    and nonzero, so the principal log is continuous over real ``w``.
    """
    ac = np.conj(a)
    lb = np.log(w2 + 1j * b) - np.log(w1 + 1j * b)
    la = np.log(w2 - 1j * ac) - np.log(w1 - 1j * ac)
    return -(-1j * lb + 1j * la) / (b + ac)


def frh2_sum(lam, c_hat, b_hat, band):
    """Squared FRH2 norm of a sum of modal terms ``sum_i c_i b_i / (jw - lam_i)``.

    Parameters
    ----------
    lam : complex ndarray, shape (q,)
        Poles (rad/s), every member listed (pass both members of a pair for a real system).
    c_hat : complex ndarray, shape (n_out, q)
    b_hat : complex ndarray, shape (q, n_in)
    band : (float, float)
        rad/s, mirror band included.

    Returns
    -------
    float

    Notes
    -----
    ``(1/2pi) sum_{i,l} (c_i^H c_l)(b_l b_i^H) [I(lam_i, lam_l; w1, w2) + I(...; -w2, -w1)]``
    with :func:`_int_cross`. Used for split-mode groups (docs/method.md §7) and as an oracle for
    :func:`frh2_pair` (the two agree to rounding).
    """
    w1, w2 = _band(band)
    lam = np.asarray(lam, dtype=complex).ravel()
    cc = np.asarray(c_hat, dtype=complex)
    bb = np.asarray(b_hat, dtype=complex)
    gc = cc.conj().T @ cc                      # (q, q): c_i^H c_l
    gb = bb @ bb.conj().T                      # (q, q): b_i b_l^H -> need b_l b_i^H = gb[l, i]
    a = lam[:, None]
    b = lam[None, :]
    integ = _int_cross(a, b, w1, w2) + _int_cross(a, b, -w2, -w1)
    total = np.sum(gc * gb.T * integ)
    return float(np.real(total) / (2 * np.pi))


# --------------------------------------------------------------------------------------
# Modal form of a CT model and the index for every pole
# --------------------------------------------------------------------------------------
def modal_decomposition(a, b, c):
    """Eigen-decomposition ``A = Phi diag(lam) Phi^-1``; ``C_hat = C Phi``, ``B_hat = Phi^-1 B``.

    Parameters
    ----------
    a : ndarray, shape (n, n)
    b : ndarray, shape (n, m)
    c : ndarray, shape (p, n)

    Returns
    -------
    lam : complex ndarray, shape (n,)
    c_hat : complex ndarray, shape (p, n)
    b_hat : complex ndarray, shape (n, m)

    Notes
    -----
    Seed Eq. 9-10 (``Phi^dagger = Phi^-1`` for a diagonalisable A). Residues ``c_i b_i`` do
    not depend on the eigenvector scaling. A near-defective A gives large, cancelling
    residues; the split-mode guard rail (:func:`group_split_modes`) treats them.
    """
    a = np.asarray(a)
    lam, phi = np.linalg.eig(a)
    c_hat = np.asarray(c) @ phi
    b_hat = np.linalg.solve(phi, np.asarray(b, dtype=complex))
    return lam, c_hat, b_hat


def _pair_up(lam: np.ndarray, rel_tol: float = 1e-8) -> list[tuple[int, ...]]:
    """Group eigenvalues into conjugate pairs and real poles.

    Returns a list of tuples ``(i,)`` (real or unpaired) or ``(i, j)`` with ``Im lam[i] > 0``
    and ``lam[j]`` its conjugate partner.
    """
    lam = np.asarray(lam, dtype=complex)
    n = lam.size
    scale = np.maximum(np.abs(lam), 1e-300)
    is_real = np.abs(lam.imag) <= rel_tol * scale
    used = np.zeros(n, bool)
    units: list[tuple[int, ...]] = []
    order = np.argsort(-lam.imag)              # positive imaginary parts first
    for i in order:
        if used[i]:
            continue
        used[i] = True
        if is_real[i]:
            units.append((int(i),))
            continue
        if lam[i].imag < 0:                    # partner not found earlier: unpaired
            units.append((int(i),))
            continue
        cand = np.flatnonzero(~used & ~is_real & (lam.imag < 0))
        if cand.size:
            d = np.abs(lam[cand] - np.conj(lam[i]))
            k = int(cand[np.argmin(d)])
            if d.min() <= 1e-6 * scale[i]:
                used[k] = True
                units.append((int(i), k))
                continue
        units.append((int(i),))
    return units


def input_weights(E, n_inputs, scaling: InputScaling = "default"):
    """Column weights for ``b_hat`` (docs/method.md §5.2, "input scaling matters").

    Parameters
    ----------
    E : complex ndarray, shape (n_lines, n_ext_inputs)
        Extended-input spectrum **in physical units** over the processed lines.
    n_inputs : int
        Number of force columns (the first ``n_inputs`` of ``E``).
    scaling : {'default', 'force', 'raw'}
        ``default``: each column weighted by the RMS of its spectrum over the lines, so every
        column contributes in output units (what the pole adds to the measured output).
        ``force``: force columns only (dominancy in the underlying linear FRF), same weights.
        ``raw``: all columns, weight 1 (seed-literal; units mixed).

    Returns
    -------
    ndarray, shape (n_ext_inputs,)
    """
    _check_choice("input_scaling", scaling, INPUT_SCALINGS)
    E = np.asarray(E)
    m_e = E.shape[1]
    if scaling == "raw":
        return np.ones(m_e)
    w = np.sqrt(np.mean(np.abs(E) ** 2, axis=0))
    if scaling == "force":
        w = w.copy()
        w[n_inputs:] = 0.0
    return w


@dataclass(frozen=True)
class ModalDominancy:
    """MDI of every mode (one entry per conjugate pair or real/unpaired pole).

    Attributes
    ----------
    eigenvalues : complex ndarray, shape (q,)
        Representative pole of each mode (``Im >= 0`` for pairs), rad/s.
    members : tuple of tuple of int
        Indices of the mode's poles in the eigenvalue list given to :func:`modal_dominancy`.
    frequency_hz, damping_ratio : ndarray, shape (q,)
        ``|lam|/2pi`` and ``-Re lam/|lam|``.
    is_pair : bool ndarray, shape (q,)
    stable : bool ndarray, shape (q,)
        ``Re lam < 0``.
    in_band : bool ndarray, shape (q,)
        Natural frequency inside the MDI band.
    values : dict str -> ndarray, shape (q,)
        Every norm of :data:`MDI_NORMS`.
    norm : str
        The norm used as the headline (``values[norm]``).
    band_hz : (float, float)
    """

    eigenvalues: np.ndarray
    members: tuple
    frequency_hz: np.ndarray
    damping_ratio: np.ndarray
    is_pair: np.ndarray
    stable: np.ndarray
    in_band: np.ndarray
    values: dict
    norm: str
    band_hz: tuple

    @property
    def mdi(self) -> np.ndarray:
        """Headline index, shape (q,)."""
        return self.values[self.norm]


def output_weights(Y, scaling: str = "rms", noise_cov=None):
    """Row weights for ``c_hat`` (outputs), shape (p,).

    ``rms``: ``1 / rms_k |Y_i(k)|`` over the lines, so every channel counts by its *relative*
    response (channels of different size or unit - a wheel that moves 10x more than an
    instrument plate, accelerometers next to displacement sensors - weigh alike).
    ``noise``: ``1 / sqrt(mean_k Sigma_Y,ii(k))`` (MDI in units of the noise level; falls back
    to ``rms`` without a covariance). ``none``: ones (the absolute output sum).
    """
    Y = np.asarray(Y)
    if scaling not in ("rms", "noise", "none"):
        raise IdentError(f"output_scaling={scaling!r} is not one of rms, noise, none")
    if scaling == "none":
        return np.ones(Y.shape[1])
    if scaling == "noise" and noise_cov is not None:
        cov = np.asarray(noise_cov)  # (F, p, p), or (F, p) variances (many channels)
        v = np.real(cov if cov.ndim == 2 else np.einsum("kii->ki", cov)).mean(axis=0)
        return 1.0 / np.sqrt(np.where(v > 0, v, np.inf))
    r = np.sqrt(np.mean(np.abs(Y) ** 2, axis=0))
    return 1.0 / np.where(r > 0, r, np.inf)


def _weighted_residues(c_hat, b_hat, weights, out_weights) -> tuple[np.ndarray, np.ndarray]:
    """``C Phi`` scaled by the output weights per row, ``Phi^-1 B`` by the input weights per
    column (None: unweighted)."""
    c_hat = np.asarray(c_hat, dtype=complex)
    b_hat = np.asarray(b_hat, dtype=complex)
    if weights is not None:
        b_hat = b_hat * np.asarray(weights, dtype=float)[None, :]
    if out_weights is not None:
        c_hat = c_hat * np.asarray(out_weights, dtype=float)[:, None]
    return c_hat, b_hat


def modal_dominancy(lam, c_hat, b_hat, band_hz, *, norm: MdiNorm = "h2", weights=None,
                    nyquist_hz: float | None = None, out_weights=None) -> ModalDominancy:
    """Modal dominancy index of every mode of a CT model in modal form.

    Parameters
    ----------
    lam : complex ndarray, shape (n,)
        CT poles, rad/s.
    c_hat : complex ndarray, shape (n_out, n)
    b_hat : complex ndarray, shape (n, n_in)
    band_hz : (float, float)
        Band of interest in Hz (the MDI integrates over it and its mirror).
    norm : {'h2', 'seed', 'h2_single', 'hinf', 'hinf_band'}
        Headline index (all are computed).
    weights : ndarray, shape (n_in,), optional
        Column weights of ``b_hat`` (see :func:`input_weights`); default ones.
    out_weights : ndarray, shape (n_out,), optional
        Row weights of ``c_hat`` (see :func:`output_weights`); default ones.
    nyquist_hz : float, optional
        Unused in the values; modes with ``|Im lam| >= 0.999 * 2 pi nyquist_hz`` are
        reported out of band.

    Returns
    -------
    ModalDominancy

    Notes
    -----
    docs/method.md §5: ``||R||_F^2 = ||c||^2 ||b||^2``, ``trace(R^H conj R) = conj((c^T c)(b b^T))``,
    ``sigma_max(R) = ||c|| ||b||`` for the rank-one residue ``R = c b``.
    """
    _check_choice("norm", norm, MDI_NORMS)
    f1, f2 = float(band_hz[0]), float(band_hz[1])
    band = _band((2 * np.pi * f1, 2 * np.pi * f2))
    lam = np.asarray(lam, dtype=complex).ravel()
    c_hat, b_hat = _weighted_residues(c_hat, b_hat, weights, out_weights)
    units = _pair_up(lam)
    rep = np.array([lam[u[0]] for u in units], dtype=complex)
    is_pair = np.array([len(u) == 2 for u in units], bool)
    ci = c_hat[:, [u[0] for u in units]]
    bi = b_hat[[u[0] for u in units], :]
    cn2 = np.sum(np.abs(ci) ** 2, axis=0)
    bn2 = np.sum(np.abs(bi) ** 2, axis=1)
    r2 = cn2 * bn2
    cross = np.conj(np.sum(ci * ci, axis=0) * np.sum(bi * bi, axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        single = frh2_single(r2, rep, band)
        pair = frh2_pair(r2, cross, rep, band)
        values = {
            "h2": np.where(is_pair, pair, single),
            "seed": frh2_seed(r2, rep, band),
            "h2_single": single,
            "hinf": hinf_single(np.sqrt(r2), rep),
            "hinf_band": hinf_band(np.sqrt(r2), rep, band),
        }
    values = {k: np.real(v).astype(float) for k, v in values.items()}
    absl = np.abs(rep)
    freq = absl / (2 * np.pi)
    with np.errstate(divide="ignore", invalid="ignore"):
        damp = np.where(absl > 0, -rep.real / absl, np.nan)
    in_band = (freq >= f1) & (freq <= f2) & (is_pair | (np.abs(rep.imag) > 0))
    if nyquist_hz is not None:
        in_band &= np.abs(rep.imag) < 0.999 * 2 * np.pi * nyquist_hz
    return ModalDominancy(eigenvalues=rep, members=tuple(units), frequency_hz=freq,
                          damping_ratio=damp, is_pair=is_pair, stable=rep.real < 0,
                          in_band=in_band, values=values, norm=norm, band_hz=(f1, f2))


# --------------------------------------------------------------------------------------
# Split modes (docs/method.md §7 guard rail)
# --------------------------------------------------------------------------------------
def group_split_modes(md: ModalDominancy, lam, c_hat, b_hat, *, weights=None, out_weights=None,
                      freq_tol: float = 0.002, damping_tol: float = 0.5,
                      cancel_ratio: float = 0.5):
    """Find split modes: near-duplicate poles whose residues largely cancel.

    Parameters
    ----------
    md : ModalDominancy
        Result of :func:`modal_dominancy` on the same ``lam, c_hat, b_hat``.
    lam, c_hat, b_hat, weights
        As given to :func:`modal_dominancy`.
    freq_tol : float
        ``|f_a - f_b| / f_a`` below which two modes are near-duplicates (docs/method.md §7: 0.2 %).
    damping_tol : float
        Relative damping difference ``|z_a - z_b| / max(z_a, z_b)`` allowed ("similar zeta").
    cancel_ratio : float
        The group is a split mode when its joint FRH2 MDI is below ``cancel_ratio`` times the
        sum of the members' MDIs (large, opposing residues).

    Returns
    -------
    groups : list of list of int
        Mode indices (into ``md``), singletons included, ordered by first member.
    group_mdi : ndarray, shape (n_groups,)
        FRH2 MDI of each group's summed modal error (:func:`frh2_sum`); the member's own
        value for singletons (headline norm).
    """
    q = md.frequency_hz.size
    parent = list(range(q))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    lam = np.asarray(lam, dtype=complex)
    c_hat, b_hat = _weighted_residues(c_hat, b_hat, weights, out_weights)
    band = (2 * np.pi * md.band_hz[0], 2 * np.pi * md.band_hz[1])
    h2 = md.values["h2"]

    def joint(mode_ids):
        idx = [k for m in mode_ids for k in md.members[m]]
        return frh2_sum(lam[idx], c_hat[:, idx], b_hat[idx, :], band)

    order = np.argsort(md.frequency_hz)
    for a_pos in range(len(order) - 1):
        a, b = int(order[a_pos]), int(order[a_pos + 1])
        fa, fb = md.frequency_hz[a], md.frequency_hz[b]
        if not (md.is_pair[a] and md.is_pair[b]) or fa <= 0:
            continue
        if abs(fa - fb) / fa > freq_tol:
            continue
        za, zb = md.damping_ratio[a], md.damping_ratio[b]
        if abs(za - zb) > damping_tol * max(abs(za), abs(zb)):
            continue
        if not (md.stable[a] and md.stable[b]):
            continue
        j = joint([a, b])
        if j < cancel_ratio * (h2[a] + h2[b]):
            parent[find(b)] = find(a)
    groups: dict[int, list[int]] = {}
    for i in range(q):
        groups.setdefault(find(i), []).append(i)
    glist = sorted(groups.values(), key=lambda g: g[0])
    gm = np.array([md.mdi[g[0]] if len(g) == 1 else joint(g) for g in glist], dtype=float)
    return glist, gm


# --------------------------------------------------------------------------------------
# Threshold
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Threshold:
    """Physical/spurious split of a set of MDI values.

    Attributes
    ----------
    threshold : float
        Values ``>= threshold`` are physical (``nan`` if nothing could be split).
    physical : bool ndarray, shape (q,)
    separation_ratio : float
        Lowest physical MDI / highest spurious candidate MDI (``10**gap``; docs/method.md §7.4).
        ``inf`` when no candidate is spurious, ``nan`` when none is physical.
    method : str
        ``'largest_gap'``, ``'top_n'`` or ``'manual'``.
    n_candidates : int
        Number of values the split was searched over.
    """

    threshold: float
    physical: np.ndarray
    separation_ratio: float
    method: str
    n_candidates: int = 0
    gap_log10: float = field(default=float("nan"))


def largest_gap_threshold(mdi, *, candidates=None, min_physical: int = 1,
                          top_n: int | None = None, manual_threshold: float | None = None,
                          floor: float = 1e-300) -> Threshold:
    """Split MDI values at the largest gap of ``log10 MDI`` (docs/method.md §7).

    Parameters
    ----------
    mdi : ndarray, shape (q,)
        Index values (>= 0).
    candidates : bool ndarray, shape (q,), optional
        Values eligible to be physical (e.g. stable and in band); the others are spurious
        beforehand and take no part in the search (docs/method.md §7.1). Default all.
    min_physical : int
        Search the gap only below the ``min_physical`` largest values (``j >= j_min``).
    top_n : int, optional
        Keep exactly the ``top_n`` largest candidates (guard rail for weak genuine modes).
    manual_threshold : float, optional
        Keep candidates with ``mdi >= manual_threshold``.
    floor : float
        Values are clipped to ``floor`` before the log.

    Returns
    -------
    Threshold

    Notes
    -----
    Sort ``v = log10 MDI`` descending, ``j* = argmax_{j >= j_min} (v_j - v_{j+1})``;
    threshold ``10**((v_j* + v_j*+1)/2)`` (geometric mean of the neighbours); separation ratio
    ``10**(v_j* - v_j*+1)``.
    """
    mdi = np.asarray(mdi, dtype=float).ravel()
    q = mdi.size
    cand = np.ones(q, bool) if candidates is None else np.asarray(candidates, bool).ravel()
    if cand.size != q:
        raise IdentError(f"candidates has {cand.size} entries, mdi has {q}")
    if top_n is not None and manual_threshold is not None:
        raise IdentError("give top_n or manual_threshold, not both")
    idx = np.flatnonzero(cand & np.isfinite(mdi))
    vals = np.clip(mdi[idx], floor, None)
    order = idx[np.argsort(-vals)]
    v = np.log10(np.clip(mdi[order], floor, None))
    physical = np.zeros(q, bool)
    nc = int(order.size)
    if nc == 0:
        return Threshold(float("nan"), physical, float("nan"), "largest_gap", 0)

    def ratio(n_phys):
        if n_phys <= 0:
            return float("nan")
        if n_phys >= nc:
            return float("inf")
        return float(10 ** (v[n_phys - 1] - v[n_phys]))

    if manual_threshold is not None:
        thr = float(manual_threshold)
        n_phys = int(np.sum(mdi[order] >= thr))
        physical[order[:n_phys]] = True
        return Threshold(thr, physical, ratio(n_phys), "manual", nc,
                         float(np.log10(ratio(n_phys))) if 0 < n_phys < nc else float("nan"))
    if top_n is not None:
        n_phys = int(min(max(top_n, 0), nc))
        physical[order[:n_phys]] = True
        if 0 < n_phys < nc:
            thr = float(10 ** ((v[n_phys - 1] + v[n_phys]) / 2))
        elif n_phys == nc:
            thr = float(10 ** v[-1])
        else:
            thr = float("inf")
        return Threshold(thr, physical, ratio(n_phys), "top_n", nc,
                         float(v[n_phys - 1] - v[n_phys]) if 0 < n_phys < nc else float("nan"))
    if nc == 1:
        physical[order] = True
        return Threshold(float(10 ** v[0]), physical, float("inf"), "largest_gap", 1)
    gaps = v[:-1] - v[1:]                       # gaps[j-1] = v_j - v_{j+1}, j = 1..nc-1
    j_min = int(min(max(min_physical, 1), nc - 1))
    j_star = j_min + int(np.argmax(gaps[j_min - 1:]))   # number of physical values
    physical[order[:j_star]] = True
    thr = float(10 ** ((v[j_star - 1] + v[j_star]) / 2))
    return Threshold(thr, physical, float(10 ** gaps[j_star - 1]), "largest_gap", nc,
                     float(gaps[j_star - 1]))



def modal_detection(mu, c_hat, b_hat_d, E, z, Y, Y_model, frequencies_hz, members,
                    natural_frequency_hz, damping_ratio, *, half_widths: float = 3.0,
                    min_lines: int = 2, noise_var=None) -> np.ndarray:
    """How far each mode of a DT model stands above the model's residual, in sigmas.

    Parameters
    ----------
    mu : complex ndarray, shape (n,)
        Eigenvalues of ``A_d``.
    c_hat : complex ndarray, shape (p, n)
        ``C_d Phi``.
    b_hat_d : complex ndarray, shape (n, m_e)
        ``Phi^-1 B_d`` (physical basis units, like ``E``).
    E : complex ndarray, shape (F, m_e)
        Extended input (physical units).
    z : complex ndarray, shape (F,)
    Y, Y_model : complex ndarray, shape (F, p)
        Measured output and the model's steady-state output on the same lines.
    frequencies_hz : ndarray, shape (F,)
    members : sequence of sequence of int
        Eigenvalue indices of each mode (both members of a pair).
    natural_frequency_hz, damping_ratio : ndarray, shape (n_modes,)
    half_widths : float
        Window ``|f - f_n| <= half_widths * zeta f_n`` (the half-power half-width is
        ``zeta f_n``), at least ``min_lines`` lines each side.
    noise_var : ndarray, shape (F, p), optional
        Independent noise variance of ``Y`` per line (periods or non-excited lines). The
        residual energy in the window is taken as at least the expected noise energy there:
        a model whose extra poles fit the noise has a residual below it, which would make
        those poles look detectable.

    Returns
    -------
    ndarray, shape (n_modes,)
        ``d = (E_mode / E_res) sqrt(M)`` over the window: ``E_mode`` the energy of the mode's
        part of the model output, ``E_res`` that of the residual ``Y - Y_model``, ``M`` the
        number of complex residual samples (lines x outputs). NaN when the window holds no
        line.

    Notes
    -----
    For a white residual, its energy over ``M`` complex samples fluctuates by
    ``E_res / sqrt(M)``; a mode whose energy in its own bandwidth is a few of those
    fluctuations above zero is detectable, a smaller one cannot be told from noise or model
    error. Needed because the nested models of one SVD keep noise-fitting poles "stable"
    across orders: measured (docs/robust.md) d < 1 for such poles and d > 10 for genuine but
    weakly excited modes (SmallSat modes 9-11 with 39 channels).
    """
    E = np.asarray(E)
    f = np.asarray(frequencies_hz, float)
    x = (E @ np.asarray(b_hat_d).T) / (np.asarray(z)[:, None] - np.asarray(mu)[None, :])
    res = np.sum(np.abs(np.asarray(Y) - np.asarray(Y_model)) ** 2, axis=1)   # (F,)
    df = float(np.min(np.diff(np.unique(f)))) if f.size > 1 else 1.0
    p = np.asarray(Y).shape[1]
    out = np.full(len(members), np.nan)
    for k, idx in enumerate(members):
        f0, zeta = float(natural_frequency_hz[k]), abs(float(damping_ratio[k]))
        w = np.abs(f - f0) <= max(half_widths * zeta * f0, min_lines * df)
        if not w.any():
            continue
        idx = list(idx)
        y_mode = x[w][:, idx] @ np.asarray(c_hat)[:, idx].T
        e_mode = float(np.sum(np.abs(y_mode) ** 2))
        e_res = float(np.sum(res[w]))
        if noise_var is not None:
            e_res = max(e_res, float(np.sum(np.asarray(noise_var)[w])))
        m = int(w.sum()) * p
        out[k] = np.inf if e_res <= 0 else e_mode / e_res * np.sqrt(m)
    return out
