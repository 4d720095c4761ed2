"""Overlapping Allan deviation of a gyro rate series, its confidence intervals, the IEEE Std 952
noise terms read off the curve, and the four-term model fit (NPSAT1 thesis section IV.G.3; IEEE Std
952-1997 Annex C).

Definitions (rate Ω in deg/s, ``n`` samples at f_s Hz, τ₀ = 1/f_s, τ = m·τ₀):

* phase (integrated rate, deg): x₀ = 0, x_k = τ₀·Σ_{i<k} (Ω_i − Ω̄), k = 1 … n (the mean is
  removed first, which leaves the Allan deviation unchanged and keeps the phase small);
* overlapping Allan variance (NIST SP 1065 Eq. 11, NPSAT1 Eq. 18-20 with every start point):

      σ²(τ) = Σ_{k=0}^{M−1} (x_{k+2m} − 2x_{k+m} + x_k)² / (2 τ² M),   M = n + 1 − 2m

  ``M`` is the number of overlapping terms (``n_terms``). Each τ costs O(n): the second differences
  are formed block by block for all τ at once (cache-sized buffers, no temporaries of length n) and
  summed with a dot product. The result equals ``allantools.oadev(rate, rate=f_s, data_type="freq", taus=...)``.
* confidence intervals: chi-squared with equivalent degrees of freedom (NIST SP 1065 Eq. 45:
  edf·σ̂²/χ²_{p}(edf)), the edf from the simple noise-type formulas of NIST SP 1065 Table 5
  (Howe, Allan and Barnes 1981; Riley's handbook) for white PM (α = +2), flicker PM (+1), white FM
  (0), flicker FM (−1) and random-walk FM (−2); flicker FM at m = 1 with the square of SP 1065
  (2(N−2)²/(2.3N−4.9); allantools 2024.6 drops it). White FM (angle random walk) is the default;
  the read-out passes the type the local slope shows at each τ.

The read-out (:func:`read_noise_terms`, used by ``bench calibrate noise``) reads quantization (slope
−1), angle random walk (−½), bias instability (0), rate random walk (+½) and rate ramp (+1) off the
measured curve the way IEEE Std 952 Annex C and NPSAT1 IV.G.3 do: each from the τ range where the
curve has that term's slope, with the range, the interval and the clusters; a term whose slope is
absent, or whose line would lie above the curve, is not reported (with the reason). Method in
``docs/noise.md``.

The noise-term model fitted by :func:`fit_noise_terms` (IEEE Std 952 Eq. C.6 ff.; no longer used for
the read-outs: on real data it puts all weight on one or two terms and reports the others as 0):

    σ²(τ) = 3Q²/τ² + N²/τ + (2 ln 2/π)·B² + K²·τ/3

Q quantization (deg, slope −1), N angle random walk (deg/√s, slope −½, equals σ at τ = 1 s),
B bias instability (deg/s, flat at 0.664·B), K rate random walk (deg/s/√s, slope +½, equals σ at
τ = 3 s). Fitted by non-negative least squares, weighted by the chi-squared variance of each Allan
variance point (var σ̂² ≈ 2σ⁴/edf), re-weighted with the model (iteratively re-weighted LS).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import optimize
from scipy.special import chdtri

from bench.errors import InputError

ONE_SIGMA = math.erf(1 / math.sqrt(2))
"""Confidence level of a ±1σ interval (0.6827)."""

STOP_RATIO = 4
"""Default largest averaging factor is n/STOP_RATIO (Stable32's stop ratio for overlapping ADEV)."""

BLOCK = 1 << 13
"""Start indices per block of the second-difference kernel: the block's windows of x for every τ
(one per distinct offset m, 2m) and the two buffers fit a 1 MiB L2 cache."""

FLICKER_FLOOR = math.sqrt(2 * math.log(2) / math.pi)
"""σ(τ)/B on the flicker (bias instability) plateau: 0.6643 (IEEE Std 952 Eq. C.14)."""

ALPHA = {"quantization": 2, "arw": 0, "bias_instability": -1, "rrw": -2, "rate_ramp": -2}
"""Power-law exponent α (S_y ∝ f^α) of each noise term, for the edf formulas (a rate ramp is not a
power-law noise; its points get the random-walk FM edf, the smallest)."""

TERMS = ("quantization", "arw", "bias_instability", "rrw")


@dataclass(frozen=True)
class AllanResult:
    """Overlapping Allan deviation at each averaging time.

    ``taus_s`` averaging times (s); ``m`` averaging factors (samples, τ = m/f_s); ``adev`` Allan
    deviation (units of the input, deg/s for gyro rates); ``n_terms`` overlapping terms in each sum
    (n + 1 − 2m); ``edf`` equivalent degrees of freedom; ``adev_lo``/``adev_hi`` the two-sided
    chi-squared confidence interval at level ``confidence``; ``alpha`` the noise type assumed for
    the edf at each τ; ``n_samples`` and ``sample_rate_hz`` describe the input.
    """

    taus_s: np.ndarray
    m: np.ndarray
    adev: np.ndarray
    n_terms: np.ndarray
    edf: np.ndarray
    adev_lo: np.ndarray
    adev_hi: np.ndarray
    alpha: np.ndarray
    confidence: float
    n_samples: int
    sample_rate_hz: float

    @property
    def avar(self) -> np.ndarray:
        """Allan variance (units² of the input)."""
        return self.adev * self.adev

    def with_alpha(self, alpha: int | Sequence[int] | np.ndarray) -> "AllanResult":
        """The same deviations with confidence intervals recomputed for noise type(s) ``alpha``."""
        alpha_arr = np.broadcast_to(np.asarray(alpha, dtype=int), self.m.shape).copy()
        edf = edf_simple(self.n_samples + 1, self.m, alpha_arr)
        lo, hi = chi2_interval(self.adev, edf, self.confidence)
        return AllanResult(self.taus_s, self.m, self.adev, self.n_terms, edf, lo, hi, alpha_arr,
                           self.confidence, self.n_samples, self.sample_rate_hz)

    def subset(self, index: np.ndarray | Sequence[int]) -> "AllanResult":
        """The points at ``index`` (integer positions or a boolean mask)."""
        k = np.asarray(index)
        return AllanResult(self.taus_s[k], self.m[k], self.adev[k], self.n_terms[k], self.edf[k], self.adev_lo[k],
                           self.adev_hi[k], self.alpha[k], self.confidence, self.n_samples, self.sample_rate_hz)


def octave_m(n_samples: int, stop_ratio: int = STOP_RATIO) -> np.ndarray:
    """Averaging factors 1, 2, 4, … up to ``n_samples // stop_ratio`` (at least m = 1)."""
    top = max(1, n_samples // stop_ratio)
    return 2 ** np.arange(int(math.floor(math.log2(top))) + 1, dtype=np.int64)


def overlapping_adev(
    rate: np.ndarray | Sequence[float],
    fs: float,
    taus: np.ndarray | Sequence[float] | None = None,
    *,
    m: np.ndarray | Sequence[int] | None = None,
    confidence: float = ONE_SIGMA,
    alpha: int | Sequence[int] | np.ndarray = 0,
) -> AllanResult:
    """Overlapping Allan deviation of ``rate`` (a rate series, e.g. deg/s) sampled at ``fs`` (Hz).

    ``taus`` (s): averaging times, each rounded to m = round(τ·f_s) samples; duplicates are merged
    and τ with m < 1 or fewer than two overlapping terms (m ≥ n/2) are dropped, as allantools does.
    ``m`` (samples): the averaging factors (cluster sizes) themselves instead of ``taus``, e.g.
    :func:`octave_m` with another stop ratio; the same rules apply. Default (neither given):
    octave-spaced m = 1, 2, 4, … ≤ n/4. ``confidence``: level of the chi-squared interval (default
    ±1σ, 0.683); ``alpha``: noise type(s) for the edf (default 0, white FM).

    Raises :class:`InputError` for fewer than 3 samples, non-finite values, a bad ``fs``, both
    ``taus`` and ``m``, or when no requested τ can be computed.
    """
    y = np.asarray(rate, dtype=np.float64)
    if y.ndim != 1:
        raise InputError(f"Allan deviation needs a 1-D rate series, got shape {y.shape}")
    n = int(y.shape[0])
    if n < 3:
        raise InputError(f"Allan deviation needs at least 3 samples, got {n}")
    if not (isinstance(fs, (int, float, np.floating, np.integer)) and math.isfinite(fs) and fs > 0):
        raise InputError(f"sample rate must be a positive number of Hz, got {fs!r}")
    if not 0 < confidence < 1:
        raise InputError(f"confidence must lie between 0 and 1, got {confidence!r}")
    total = float(y.sum())  # NaN/inf propagate: one pass checks every sample and gives the mean
    if not math.isfinite(total):
        bad = np.flatnonzero(~np.isfinite(y))
        if bad.size:
            i = int(bad[0])
            raise InputError(f"rate sample {i} is {y[i]!r}: Allan deviation needs finite values")
        total = float(np.sum(y / n)) * n  # finite values whose sum overflows

    m = select_m(n, fs, taus, m=m)
    x = _phase_samples(y, total / n)  # Σ(Ω − Ω̄) in units of rate·τ₀ (the 1/f_s factor is applied at the end)
    sums = _second_difference_sums(x, m)
    n_terms = (n + 1 - 2 * m).astype(np.int64)
    adev = np.sqrt(sums / (2.0 * n_terms)) / m  # rate units: (Σv²/2M)^½ / (m τ₀) with v in rate·τ₀
    alpha_arr = np.broadcast_to(np.asarray(alpha, dtype=int), m.shape).copy()
    edf = edf_simple(n + 1, m, alpha_arr)
    lo, hi = chi2_interval(adev, edf, confidence)
    return AllanResult(m / float(fs), m, adev, n_terms, edf, lo, hi, alpha_arr, float(confidence), n, float(fs))


def select_m(n: int, fs: float, taus: np.ndarray | Sequence[float] | None = None, *,
             m: np.ndarray | Sequence[int] | None = None) -> np.ndarray:
    """Averaging factors (samples) as :func:`overlapping_adev` uses them: ``taus`` (s) each rounded
    to m = round(τ·f_s), or the factors ``m`` given directly (whole numbers); duplicates merged,
    m < 1 and m ≥ n/2 dropped; octaves (:func:`octave_m`) when neither is given. Raises
    :class:`InputError` when none is usable, or when both are given."""
    if m is not None:
        if taus is not None:
            raise InputError("give averaging times or averaging factors, not both")
        cand = np.atleast_1d(np.asarray(m, dtype=np.float64))
        if not np.all(np.isfinite(cand)) or np.any(cand != np.round(cand)):
            raise InputError("averaging factors must be whole numbers of samples")
        usable = _usable_m(cand, n)
        if usable.size == 0:
            raise InputError(f"no usable averaging factor in {[int(v) for v in cand]} for {n} samples "
                             f"(m must lie between 1 and {(n - 1) // 2})")
        return usable
    if taus is None:
        return octave_m(n)
    t = np.atleast_1d(np.asarray(taus, dtype=np.float64))
    if not np.all(np.isfinite(t)):
        raise InputError("averaging times must be finite numbers of seconds")
    usable = _usable_m(np.round(t * float(fs)), n)
    if usable.size == 0:
        raise InputError(f"no usable averaging time in {list(t)} s for {n} samples at {fs:g} Hz "
                         f"(τ must lie between {1 / fs:g} s and {(n - 1) / 2 / fs:g} s)")
    return usable


def _usable_m(m: np.ndarray, n: int) -> np.ndarray:
    """The distinct whole averaging factors of ``m`` with 1 ≤ m < n/2 (at least two overlapping terms,
    n + 1 − 2m ≥ 2), ascending."""
    return np.unique(m[(m >= 1) & (m < n / 2)]).astype(np.int64)


def _phase_samples(y: np.ndarray, mean: float | None = None) -> np.ndarray:
    """x₀ = 0, x_k = Σ_{i<k}(y_i − ȳ): phase in units of (rate × sample interval), length n + 1."""
    x = np.empty(y.shape[0] + 1)
    x[0] = 0.0
    np.subtract(y, y.mean() if mean is None else mean, out=x[1:])
    np.cumsum(x[1:], out=x[1:])
    return x


def _second_difference_sums(x: np.ndarray, ms: np.ndarray, block: int = BLOCK) -> np.ndarray:
    """Σ_k (x_{k+2m} − 2x_{k+m} + x_k)² for each m (ascending), k = 0 … len(x) − 2m − 1.

    The start indices k are walked in blocks; within a block every m is accumulated while the
    block's data are in cache (blocks outer, τ inner), so x streams from memory about once per
    distinct offset instead of once per τ. For m ≤ block the second difference is D_{k+m} − D_k with
    D_k = x_{k+m} − x_k (two subtractions), otherwise three; buffers are preallocated and reused,
    the sum of squares is a BLAS dot product per block.
    """
    m_list = [int(v) for v in ms]
    size = x.shape[0]
    totals = [size - 2 * m for m in m_list]
    acc = [0.0] * len(m_list)
    buf_d = np.empty(2 * block)
    buf_v = np.empty(block)
    sub, dot = np.subtract, np.dot
    for a in range(0, max(totals), block):
        for i, m in enumerate(m_list):
            ln = totals[i] - a
            if ln <= 0:
                continue
            if ln > block:
                ln = block
            v = buf_v[:ln]
            if m <= block:
                d = buf_d[:ln + m]  # D_a … D_{a+ln+m-1}
                sub(x[a + m:a + 2 * m + ln], x[a:a + m + ln], out=d)
                sub(d[m:], d[:ln], out=v)
            else:
                d = buf_d[:ln]
                sub(x[a + 2 * m:a + 2 * m + ln], x[a + m:a + m + ln], out=v)
                sub(x[a + m:a + m + ln], x[a:a + ln], out=d)
                sub(v, d, out=v)
            acc[i] += float(dot(v, v))
    return np.array(acc)


def edf_simple(n_phase: int, m: np.ndarray | int, alpha: np.ndarray | int) -> np.ndarray:
    """Equivalent degrees of freedom of the overlapping Allan variance (NIST SP 1065 Table 5).

    ``n_phase``: number of phase points (samples + 1); ``m``: averaging factor(s); ``alpha``: noise
    type(s), +2 white PM, +1 flicker PM, 0 white FM, −1 flicker FM, −2 random-walk FM. Clipped to ≥ 1.
    """
    m_arr = np.atleast_1d(np.asarray(m, dtype=np.float64))
    a_arr = np.broadcast_to(np.asarray(alpha, dtype=int), m_arr.shape)
    big_n = float(n_phase)
    edf = np.empty_like(m_arr)
    for i, (mm, a) in enumerate(zip(m_arr, a_arr)):
        if a == 2:
            e = (big_n + 1) * (big_n - 2 * mm) / (2 * (big_n - mm))
        elif a == 1:
            e = math.exp(math.sqrt(math.log(max((big_n - 1) / (2 * mm), 1.0)) *
                                   math.log(max((2 * mm + 1) * (big_n - 1) / 4, 1.0))))
        elif a == 0:
            e = (3 * (big_n - 1) / (2 * mm) - 2 * (big_n - 2) / big_n) * 4 * mm * mm / (4 * mm * mm + 5)
        elif a == -1:
            e = 2 * (big_n - 2) ** 2 / (2.3 * big_n - 4.9) if mm == 1 else 5 * big_n ** 2 / (4 * mm * (big_n + 3 * mm))
        elif a == -2:
            e = (big_n - 2) / (mm * (big_n - 3) ** 2) * ((big_n - 1) ** 2 - 3 * mm * (big_n - 1) + 4 * mm * mm)
        else:
            raise ValueError(f"unknown noise type alpha={a} (use 2, 1, 0, -1 or -2)")
        edf[i] = max(e, 1.0)
    return edf


def chi2_interval(dev: np.ndarray, edf: np.ndarray, confidence: float = ONE_SIGMA) -> tuple[np.ndarray, np.ndarray]:
    """Two-sided chi-squared interval of a deviation: σ·√(edf/χ²_{1−p}) … σ·√(edf/χ²_{p}),
    p = (1 − confidence)/2 (NIST SP 1065 Eq. 45)."""
    p = (1.0 - confidence) / 2.0
    edf = np.asarray(edf, dtype=np.float64)
    lo = dev * np.sqrt(edf / chi2_ppf(1.0 - p, edf))
    hi = dev * np.sqrt(edf / chi2_ppf(p, edf))
    return lo, hi


def chi2_ppf(q: float, df: np.ndarray | float) -> np.ndarray:
    """Quantile ``q`` of the chi-squared distribution with ``df`` degrees of freedom (what
    ``scipy.stats.chi2.ppf`` computes, through the same ``scipy.special.chdtri``, without importing
    scipy.stats: 0.4 s of every command's start-up)."""
    return chdtri(np.asarray(df, dtype=np.float64), 1.0 - q)


# ---- noise-term fit (IEEE Std 952 Annex C) ------------------------------------------------------
@dataclass(frozen=True)
class NoiseTerms:
    """Fitted IEEE Std 952 coefficients, in SI-like bench units.

    ``q_deg`` quantization Q (deg); ``n_deg_rts`` angle random walk N (deg/√s); ``b_dps`` bias
    instability B (deg/s); ``k_dps_rts`` rate random walk K (deg/s/√s). ``dominant``: for each
    term, whether it is the largest contribution to the fitted σ²(τ) at one or more measured τ
    (a term that dominates nowhere is not resolved by the data; its value is an upper bound at best).
    """

    q_deg: float
    n_deg_rts: float
    b_dps: float
    k_dps_rts: float
    dominant: dict[str, bool]

    def avar(self, taus_s: np.ndarray) -> np.ndarray:
        """Model Allan variance (deg/s)² at ``taus_s``."""
        return _design(np.asarray(taus_s, dtype=np.float64)) @ self.coefficients_squared

    def contributions(self, taus_s: np.ndarray) -> np.ndarray:
        """Each term's share of the model Allan variance, shape (len(taus), 4), order :data:`TERMS`."""
        return _design(np.asarray(taus_s, dtype=np.float64)) * self.coefficients_squared

    @property
    def coefficients_squared(self) -> np.ndarray:
        return np.array([self.q_deg ** 2, self.n_deg_rts ** 2, self.b_dps ** 2, self.k_dps_rts ** 2])

    # read-outs in the customary units
    @property
    def arw_deg_per_sqrt_h(self) -> float:
        """N read off the −½ line at τ = 1 s, in deg/√h (1 deg/√s = 60 deg/√h)."""
        return self.n_deg_rts * 60.0

    @property
    def rrw_deg_per_h_per_sqrt_h(self) -> float:
        """K read off the +½ line at τ = 3 s, in deg/h/√h (1 deg/s^1.5 = 3600^1.5 deg/h^1.5)."""
        return self.k_dps_rts * 3600.0 ** 1.5


def _design(taus: np.ndarray) -> np.ndarray:
    return np.column_stack([3.0 / taus ** 2, 1.0 / taus, np.full_like(taus, FLICKER_FLOOR ** 2), taus / 3.0])


def dominant_alpha(terms: NoiseTerms, taus_s: np.ndarray) -> np.ndarray:
    """Noise type α (for the edf) of the term that dominates the fitted model at each τ."""
    share = terms.contributions(taus_s)
    alphas = np.array([ALPHA[t] for t in TERMS])
    out = alphas[np.argmax(share, axis=1)]
    out[share.sum(axis=1) <= 0] = 0
    return out


def fit_noise_terms(result: AllanResult, iterations: int = 4) -> NoiseTerms:
    """Weighted non-negative least squares of σ²(τ) = 3Q²/τ² + N²/τ + (2ln2/π)B² + K²τ/3.

    Residuals are relative, (σ̂² − model)/model·√(edf/2), i.e. weighted by the chi-squared standard
    deviation of each Allan-variance point; the first pass scales by the measured σ̂², later passes by
    the model and with the edf of the noise type dominating the model at each τ.
    """
    taus = result.taus_s
    avar = result.avar
    a = _design(taus)
    if not np.any(avar > 0):
        return NoiseTerms(0.0, 0.0, 0.0, 0.0, {t: False for t in TERMS})
    scale = np.where(avar > 0, avar, np.max(avar))
    edf = result.edf
    coef = np.zeros(4)
    for _ in range(max(1, iterations)):
        w = np.sqrt(edf / 2.0) / scale
        aw = a * w[:, None]
        norm = np.linalg.norm(aw, axis=0)
        norm[norm == 0] = 1.0
        sol, _ = optimize.nnls(aw / norm, avar * w)
        coef = sol / norm
        model = a @ coef
        if not np.all(model > 0):
            break
        scale = model
        terms = _terms(coef, taus)
        edf = edf_simple(result.n_samples + 1, result.m, dominant_alpha(terms, taus))
    return _terms(coef, taus)


def _terms(coef: np.ndarray, taus: np.ndarray) -> NoiseTerms:
    q2, n2, b2, k2 = (max(float(c), 0.0) for c in coef)
    share = _design(taus) * np.array([q2, n2, b2, k2])
    winners = set(np.argmax(share, axis=1)[share.sum(axis=1) > 0].tolist())
    dominant = {t: bool(i in winners and share[:, i].max() > 0) for i, t in enumerate(TERMS)}
    return NoiseTerms(math.sqrt(q2), math.sqrt(n2), math.sqrt(b2), math.sqrt(k2), dominant)


# ---- read-out by the book (IEEE Std 952 Annex C, NPSAT1 IV.G.3) ---------------------------------
READ_TERMS = ("quantization", "arw", "bias_instability", "rrw", "rate_ramp")
"""The terms read off the measured curve, by slope (−1, −½, 0, +½, +1)."""

SLOPE = {"quantization": -1.0, "arw": -0.5, "bias_instability": 0.0, "rrw": 0.5, "rate_ramp": 1.0}
"""Slope of each term's line σ = C·g(τ) on the log-log Allan deviation plot (IEEE Std 952 Fig. C.2)."""

UNITS = {"quantization": ("deg", 1.0), "arw": ("deg/√h", 60.0), "bias_instability": ("deg/h", 3600.0),
         "rrw": ("deg/h/√h", 3600.0 ** 1.5), "rate_ramp": ("deg/h/h", 3600.0 ** 2)}
"""Customary unit of each coefficient and the factor from the bench unit (Q deg, N deg/√s, B deg/s,
K deg/s/√s, R deg/s²)."""

NAMES = {"quantization": "quantization", "arw": "angle random walk", "bias_instability": "bias instability",
         "rrw": "rate random walk", "rate_ramp": "rate ramp"}

SLOPE_TEXT = {-1.0: "−1", -0.5: "−½", 0.0: "0", 0.5: "+½", 1.0: "+1"}

PER_OCTAVE = 4
"""Averaging times per octave of the analysis grid the read-outs use (whatever τ are displayed)."""

SLOPE_TOL = 0.15
"""A local slope within this of a sloped term's slope counts as that slope even when its statistical
uncertainty is smaller (the term holds ≥ 70 % of the Allan variance there when one neighbouring
term adds to it). Where two terms a slope unit apart meet (−1 and 0, −½ and +1, …) the slope passes
the middle term's within ±0.15 over less than an octave, so no middle term is invented."""

FLAT_TOL = 0.125
"""The same for the flat (bias instability) slope: tighter, because the V where −½ meets +½ passes
through 0 within ±0.125 over 1.7 × in τ (±0.15: 1.9 ×), just under the octave a region needs."""

SLOPE_Z = 2.0
"""Coverage factor of the slope tests: consistent within SLOPE_Z standard uncertainties (≈ 95 %)."""

MIN_SHARE = 0.5
"""A term is read only where its line holds at least this share of the measured Allan variance."""

ARW_TAU_S = 1.0
"""The −½ line is read at τ = 1 s (NPSAT1 Table 13, IEEE Std 952: N = σ(1 s))."""

WHITE_SLOPE_TOL = 0.05
"""The −½ line is read at 1 s itself where the local slope there is −½ within this (or its own
standard uncertainty): with AVAR = N²/τ + (a term of slope 0 or −1) the slope is −½ ∓ ½·(the other
term's share), so 0.05 means white noise holds ≥ 90 % of the variance (σ within 5 % of the line).
Flatter or steeper at 1 s but −½ within this elsewhere on the −½ stretch: the line is read there."""

MIN_RUN_RATIO = 2.0 * (1 - 1e-9)
"""A term is resolved only where its slope holds (and is told apart from the neighbouring terms')
over at least an octave of τ: IEEE 952 reads straight-line segments, and shorter excursions of the
local slope are mostly scatter."""

CHECK_Z = 3.0
"""A term's line contradicts the curve where it lies above the curve's upper bound at this many
standard deviations (99.7 %): with tens of τ points a 1σ or 2σ band is crossed somewhere by chance."""


def term_factor(term: str, taus_s: np.ndarray | float) -> np.ndarray:
    """g(τ) with σ(τ) = C·g(τ) for a term's coefficient C in bench units: √3/τ (Q), 1/√τ (N), 0.664
    (B), √(τ/3) (K), τ/√2 (R, NPSAT1 Eq. 23)."""
    t = np.asarray(taus_s, dtype=np.float64)
    if term == "quantization":
        return math.sqrt(3.0) / t
    if term == "arw":
        return 1.0 / np.sqrt(t)
    if term == "bias_instability":
        return np.full_like(t, FLICKER_FLOOR)
    if term == "rrw":
        return np.sqrt(t / 3.0)
    if term == "rate_ramp":
        return t / math.sqrt(2.0)
    raise ValueError(f"unknown noise term {term!r}")


def analysis_m(n_samples: int, fs: float, extra_m: np.ndarray | Sequence[int] = (), per_octave: int = PER_OCTAVE,
               stop_ratio: int = STOP_RATIO) -> np.ndarray:
    """Averaging factors of the analysis grid: ``per_octave`` per octave from 1 to n/``stop_ratio``,
    the m of τ = 1 s, and ``extra_m`` (e.g. the displayed τ), each usable (1 ≤ m < n/2)."""
    top = max(1, n_samples // stop_ratio)
    k = np.arange(int(math.floor(per_octave * math.log2(top) + 1e-9)) + 1)
    m = np.round(2.0 ** (k / per_octave))
    one = round(ARW_TAU_S * fs)
    parts = [m, np.asarray(list(extra_m), dtype=np.float64)]
    if 1 <= one <= top:
        parts.append(np.array([float(one)]))
    allm = np.unique(np.concatenate(parts))
    return allm[(allm >= 1) & (allm < n_samples / 2)].astype(np.int64)


SLOPE_RHO = 0.5
"""Correlation assumed between ln σ̂ at the two ends of an octave (overlapping estimates share data).
Monte Carlo (white, flicker and random-walk FM, 10⁵ samples, 150 runs) puts the true scatter of the
local slope 1.3-4 times below the independent-ends value; ρ = 0.5 divides it by ≈ 1.4, which stays
at or above the true scatter at every τ."""


def local_slopes(result: AllanResult) -> tuple[np.ndarray, np.ndarray]:
    """Local slope d ln σ / d ln τ at each τ over one octave (τ/√2 … τ·√2, one-sided at the ends)
    and its standard uncertainty, from the relative scatter 1/√(2·edf) of the two end points
    (correlation :data:`SLOPE_RHO`). NaN where the grid has fewer than two points or σ is 0."""
    lt = np.log(result.taus_s)
    size = lt.size
    mu = np.full(size, np.nan)
    u = np.full(size, np.nan)
    if size < 2 or not np.all(result.adev > 0):
        return mu, u
    ls = np.log(result.adev)
    var = 1.0 / (2.0 * result.edf)
    half, eps = math.log(2.0) / 2.0, 1e-9
    for i in range(size):
        a = int(np.searchsorted(lt, lt[i] - half - eps))
        b = int(np.searchsorted(lt, lt[i] + half + eps, side="right")) - 1
        if lt[b] - lt[a] < 2 * half * 0.99:
            if a == 0:
                b = max(b, int(np.searchsorted(lt, lt[0] + 2 * half + eps, side="right")) - 1)
            if b == size - 1:
                a = min(a, int(np.searchsorted(lt, lt[-1] - 2 * half - eps)))
        if b <= a:
            a, b = max(i - 1, 0), min(i + 1, size - 1)
        d = lt[b] - lt[a]
        mu[i] = (ls[b] - ls[a]) / d
        u[i] = math.sqrt(max(var[a] + var[b] - 2 * SLOPE_RHO * math.sqrt(var[a] * var[b]), 0.0)) / d
    return mu, u


@dataclass
class TermReading:
    """One term read off the Allan deviation curve (coefficient in bench units: Q deg, N deg/√s,
    B deg/s, K deg/s/√s, R deg/s²).

    ``value``: ``None`` when the term is not reported; ``reason`` then says why and ``upper_bound`` is
    the largest coefficient the curve allows (under its upper confidence band; for B the minimum / 0.664).
    ``tau_s``: the read point; ``tau_range_s``: where the term's line lies within the curve's 2σ band
    and holds at least half of its variance (the line *is* the curve there); ``ci``: the interval of
    the reading from the curve's interval at the read point; ``n_terms`` overlapping and
    ``clusters`` independent (⌊n/m⌋) clusters at the read point; ``slope``/``slope_u``: the local
    slope there and its standard uncertainty; ``slope_range_s``: where the curve has the term's slope
    (resolved runs; for B read at the minimum, where the slope is consistent with 0);
    ``estimate_only``: B read at a minimum that is no resolved floor (NPSAT1's "estimate only": an
    upper bound). ``how``: for B ``"flat region"``, ``"minimum"``, ``"minimum, no flat region"`` (a V)
    or ``"minimum, floor not resolved"``; for ARW ``"1 s"`` (IEEE 952: σ(1 s) itself where the curve
    falls as −½ at 1 s, else the lowest −½ line touching the curve at τ ≥ 1 s, NPSAT1) or
    ``"slope region"`` (read on a −½ stretch away from 1 s; ``not_at_1s`` says why, the reason the
    read-out took).
    ``alternative`` (ARW read at 1 s where the slope is not −½): the reading on the −½ stretch
    (value, ci, tau_s, tau_range_s, slope, slope_u, slope_range_s). ``at_slope``: the local slope at
    the read point is consistent with the term's; ``evidenced``: the read point lies in a stretch
    where the term's slope is resolved; ``seen``: such a stretch exists."""

    term: str
    value: float | None = None
    reason: str | None = None
    tau_s: float | None = None
    tau_range_s: tuple[float, float] | None = None
    ci: tuple[float, float] | None = None
    n_terms: int | None = None
    clusters: int | None = None
    slope: float | None = None
    slope_u: float | None = None
    slope_range_s: tuple[float, float] | None = None
    estimate_only: bool = False
    upper_bound: float | None = None
    alternative: dict[str, Any] | None = None
    at_slope: bool = True
    not_at_1s: str | None = None
    evidenced: bool = False
    seen: bool = False
    how: str = ""

    @property
    def resolved(self) -> bool:
        """Reported, not an estimate only, and the curve shows the term's slope somewhere (``seen``:
        a run of τ at least an octave long where that slope is told apart from the neighbours')."""
        return self.value is not None and not self.estimate_only and self.seen

    @property
    def subtracted(self) -> bool:
        """Reported and read inside the term's own resolved slope region (``evidenced``): its variance
        is taken off when the other terms are read."""
        return self.value is not None and not self.estimate_only and self.evidenced

    def customary(self, v: float | None) -> float | None:
        return None if v is None else v * UNITS[self.term][1]


@dataclass
class NoiseReadout:
    """The analysis-grid Allan deviation (with confidence intervals for the noise type the local
    slope shows), its local slopes and uncertainties, and the readings of :data:`READ_TERMS`."""

    allan: AllanResult
    slope: np.ndarray
    slope_u: np.ndarray
    readings: dict[str, TermReading]
    z: float = SLOPE_Z


def _fmt(v: float) -> str:
    return f"{v:.3g}"


def _range_text(lo: float, hi: float) -> str:
    return f"τ = {_fmt(lo)} s" if math.isclose(lo, hi) else f"τ = {_fmt(lo)}-{_fmt(hi)} s"


class _Reader:
    """The graphical read-out of one curve (see :func:`read_noise_terms`)."""

    def __init__(self, allan: AllanResult, z: float, arw_tau_s: float):
        self.z, self.arw_tau_s = z, arw_tau_s
        self.why = ""
        self.no_flat = False
        self.allan = allan.with_alpha(0)
        self.taus = self.allan.taus_s
        self.size = self.taus.size
        for _ in range(3):  # slopes -> noise type per τ -> edf -> slope uncertainties -> ...
            self.mu, self.u = local_slopes(self.allan)
            self._classify()
            alpha = self._alpha()
            if np.array_equal(alpha, self.allan.alpha):
                break
            self.allan = self.allan.with_alpha(alpha)
        self.mu, self.u = local_slopes(self.allan)
        self._classify()
        p = math.erf(CHECK_Z / math.sqrt(2.0))
        self.check_hi = chi2_interval(self.allan.adev, self.allan.edf, p)[1]

    def _classify(self) -> None:
        """Per term and τ: ``consistent`` (the local slope is within SLOPE_TOL (FLAT_TOL for the bias
        instability) or z uncertainties of the term's slope) and ``resolved`` (the term's slope is the
        nearest to the local slope, and the neighbouring terms' slopes are more than z uncertainties
        away, over at least an octave). A resolved stretch can be a transition where two terms meet
        (the V of −½ and +½ looks flat); the read-out takes the neighbours' variance off and checks
        the terms together against the curve, which tells the two apart."""
        slopes = np.array([SLOPE[t] for t in READ_TERMS])
        nearest = np.argmin(np.abs(np.nan_to_num(self.mu, nan=9.0)[:, None] - slopes[None, :]), axis=1)
        self.consistent: dict[str, np.ndarray] = {}
        self.resolved: dict[str, np.ndarray] = {}
        for j, t in enumerate(READ_TERMS):
            s = SLOPE[t]
            fixed = FLAT_TOL if t == "bias_instability" else SLOPE_TOL
            self.consistent[t] = np.abs(self.mu - s) <= np.maximum(fixed, self.z * self.u)
            res = (nearest == j) & np.isfinite(self.mu)
            for t2 in READ_TERMS:
                if abs(SLOPE[t2] - s) == 0.5:
                    res &= np.abs(self.mu - SLOPE[t2]) > self.z * self.u
            for lo, hi in _true_runs(res):  # a slope seen over less than an octave is a wiggle, not a term
                if self.taus[hi] / self.taus[lo] < MIN_RUN_RATIO:
                    res[lo:hi + 1] = False
            self.resolved[t] = res

    def _alpha(self) -> np.ndarray:
        """Noise type for the edf at each τ: that of the term resolved there; elsewhere that of the
        term whose slope is nearest the local slope, white PM excepted (its edf, ≈ n/2 at every τ, is
        taken only where quantization is resolved)."""
        out = np.zeros(self.size, dtype=int)
        names = [t for t in READ_TERMS if t != "quantization"]
        slopes = np.array([SLOPE[t] for t in names])
        for i in range(self.size):
            res = [t for t in READ_TERMS if self.resolved[t][i]]
            if res:
                out[i] = ALPHA[res[0]]
            elif math.isfinite(self.mu[i]):
                out[i] = ALPHA[names[int(np.argmin(np.abs(self.mu[i] - slopes)))]]
        return out

    # -- helpers --
    def runs(self, term: str) -> list[tuple[int, int]]:
        """The term's slope regions: the runs of τ where it is resolved."""
        return _true_runs(self.resolved[term])

    def slope_text(self, i: int) -> str:
        return f"{self.mu[i]:+.2f} ± {self.u[i]:.2f}" if self.u[i] >= 0.01 else f"{self.mu[i]:+.3f} ± {self.u[i]:.1g}"

    def upper_bound(self, term: str, idx: np.ndarray | None = None) -> float:
        k = np.arange(self.size) if idx is None else idx
        return float(np.min(self.allan.adev_hi[k] / term_factor(term, self.taus[k])))

    def fill(self, r: TermReading, i: int) -> None:
        r.tau_s = float(self.taus[i])
        r.n_terms = int(self.allan.n_terms[i])
        r.clusters = int(self.allan.n_samples // self.allan.m[i])
        r.slope = float(self.mu[i])
        r.slope_u = float(self.u[i])
        r.at_slope = bool(self.consistent[r.term][i])
        r.evidenced = bool(self.resolved[r.term][i])
        r.seen = bool(self.resolved[r.term].any())

    def tangent(self, term: str, idx: np.ndarray, others: np.ndarray, need_slope: bool = True) -> dict[str, Any] | None:
        """The term's line read over candidate points ``idx`` with the other terms' Allan variance
        ``others`` subtracted. At each point the coefficient c = √(σ² − others)/g(τ); a point can be
        the read point when the term holds ≥ MIN_SHARE of the variance there and its line c·g(τ) stays
        under the curve (its upper band at CHECK_Z) at every candidate point, i.e. the line touches the
        curve from below there (IEEE 952 graphical reading), and (``need_slope``) the local slope
        there is consistent with the term's. Of those, the one whose c has the smallest relative
        uncertainty is read. The range is where that line lies within the curve's
        band at z standard deviations (contiguous around the read point)."""
        al = self.allan
        g = term_factor(term, self.taus[idx])
        s2 = al.adev[idx] ** 2 - others[idx]
        c = np.sqrt(np.clip(s2, 0.0, None)) / g
        chi = np.sqrt(np.clip(al.adev_hi[idx] ** 2 - others[idx], 0.0, None)) / g
        clo = np.sqrt(np.clip(al.adev_lo[idx] ** 2 - others[idx], 0.0, None)) / g
        top = float(np.min(self.check_hi[idx] / g))
        share = np.clip(s2, 0.0, None) / al.adev[idx] ** 2
        big = (share >= MIN_SHARE) & (c > 0)
        span = _range_text(self.taus[idx[0]], self.taus[idx[-1]])
        s = SLOPE_TEXT[SLOPE[term]]
        if not big.any():
            self.why = f"at {span} the {s} line would hold less than half of the variance once the other terms are taken off"
            return None
        ok = big & (c <= top * (1 + 1e-12))
        if need_slope:
            ok &= self.consistent[term][idx]
        if not ok.any():
            self.why = (f"no {s} line touches the curve from below at {span} where the curve's slope is {s} "
                        "(it bends away first)")
            return None
        with np.errstate(divide="ignore"):
            rel = np.where(s2 > 0, al.adev[idx] ** 2 * np.sqrt(2.0 / al.edf[idx]) / (2.0 * s2), np.inf)
        pos = np.flatnonzero(ok)
        k = int(pos[np.argmin(rel[pos])])
        lo_z, hi_z = chi2_interval(al.adev[idx], al.edf[idx], math.erf(self.z / math.sqrt(2.0)))
        zlo = np.sqrt(np.clip(lo_z ** 2 - others[idx], 0.0, None)) / g
        zhi = np.sqrt(np.clip(hi_z ** 2 - others[idx], 0.0, None)) / g
        inside = (zlo <= c[k] * (1 + 1e-12)) & (c[k] <= zhi * (1 + 1e-12)) & (share >= MIN_SHARE)
        a = b = k
        while a - 1 >= 0 and inside[a - 1]:
            a -= 1
        while b + 1 < idx.size and inside[b + 1]:
            b += 1
        return {"i": int(idx[k]), "value": float(c[k]), "ci": (float(clo[k]), float(chi[k])),
                "range": (float(self.taus[idx[a]]), float(self.taus[idx[b]])), "rel": float(rel[k])}

    def contradiction(self, term: str, value: float, tau_from: float | None) -> float | None:
        """The first τ (≥ ``tau_from``; anywhere when ``None``) where the term's own line exceeds the
        curve's upper confidence bound (at CHECK_Z standard deviations: the curve has many τ, and a
        1σ band is crossed somewhere by chance), or ``None``."""
        line = value * term_factor(term, self.taus)
        bad = line > self.check_hi * (1 + 1e-9)
        if tau_from is not None:
            bad &= self.taus >= tau_from * (1 - 1e-12)
        return float(self.taus[np.flatnonzero(bad)[0]]) if bad.any() else None

    def others(self, term: str, values: dict[str, TermReading]) -> np.ndarray:
        total = np.zeros(self.size)
        for t, r in values.items():
            if t != term and r.subtracted:
                total += (r.value * term_factor(t, self.taus)) ** 2
        return total

    # -- terms --
    def bias_instability(self, values: dict[str, TermReading]) -> TermReading:
        """Where the curve has a resolved flat stretch (slope 0, told apart from ±½, over an octave or
        more), the flat line 0.664·B read there like the other terms (touching the curve from below,
        at its best-determined point, the other terms taken off); otherwise :meth:`minimum`."""
        if self.runs("bias_instability") and not self.no_flat:
            reasons: list[str] = []
            best = self.read_runs("bias_instability", self.others("bias_instability", values), reasons, anywhere=True)
            if best is not None:
                got, srange = best
                r = TermReading("bias_instability", how="flat region")
                self.fill(r, got["i"])
                r.value, r.ci, r.tau_range_s, r.slope_range_s = got["value"], got["ci"], got["range"], srange
                return r
        return self.minimum(values)

    def minimum(self, values: dict[str, TermReading] | None = None) -> TermReading:
        """NPSAT1 / IEEE 952: B = minimum of the measured curve / 0.664. Omitted when the minimum is
        at an end of the curve without a floor there (still falling at the longest τ, or rising from
        the shortest). An estimate only when the slope around the minimum is consistent with 0 over
        less than an octave, or the other terms' lines (read in their own slope regions) hold more
        than half of the minimum (a V where two other terms meet: no flat region). A floor is
        ``seen`` when the slope there is told apart from ±½ over an octave; an estimate only too when it
        is not (flat within the uncertainty, but too few clusters to tell a floor from a bend)."""
        al, r = self.allan, TermReading("bias_instability", how="minimum")
        i = int(np.argmin(al.adev))
        last = self.size - 1
        sig = float(al.adev[i])
        # points indistinguishable from the minimum: lower band at or below it, contiguous around it
        a = b = i
        while a - 1 >= 0 and al.adev_lo[a - 1] <= sig:
            a -= 1
        while b + 1 <= last and al.adev_lo[b + 1] <= sig:
            b += 1
        cons = self.consistent["bias_instability"]
        run = next(((lo, hi) for lo, hi in _true_runs(cons) if lo <= i <= hi), None)
        floor = run is not None and bool(self.resolved["bias_instability"][run[0]:run[1] + 1].any())
        self.fill(r, i)
        r.seen, r.evidenced = floor, False
        value = sig / FLICKER_FLOOR
        if i == last and not floor:
            what = "is still falling" if self.mu[last] < 0 else "has its minimum"
            r.reason = (f"the Allan deviation {what} at the longest τ ({_fmt(self.taus[last])} s, slope "
                        f"{self.slope_text(last)}): no floor is seen, the bias instability is below the minimum / 0.664 "
                        "(record longer)")
            r.upper_bound = value
            return r
        if i == 0 and not floor:
            r.reason = (f"the Allan deviation rises from the shortest τ ({_fmt(self.taus[0])} s, slope "
                        f"{self.slope_text(0)}): no floor")
            r.upper_bound = value
            return r
        r.value = value
        r.ci = (float(al.adev_lo[i]) / FLICKER_FLOOR, float(al.adev_hi[i]) / FLICKER_FLOOR)
        r.tau_range_s = (float(self.taus[a]), float(self.taus[b]))
        others = self.others("bias_instability", values or {})[i]
        if others > (1 - MIN_SHARE) * sig * sig:  # the other terms' lines already fill the minimum: a V
            r.estimate_only, r.how = True, "minimum, no flat region"
        elif run is not None and self.taus[run[1]] / self.taus[run[0]] >= MIN_RUN_RATIO:
            r.slope_range_s = (float(self.taus[run[0]]), float(self.taus[run[1]]))
            if not floor:  # flat within the uncertainty, but not told apart from ±½: too few clusters
                r.estimate_only, r.how = True, "minimum, floor not resolved"
        else:  # the slope passes 0 within less than an octave: a V where two other terms meet
            r.estimate_only, r.how = True, "minimum, no flat region"
        return r

    def read_runs(self, term: str, others: np.ndarray, reasons: list[str],
                  anywhere: bool = False) -> tuple[dict[str, Any], tuple] | None:
        """The best non-contradicting reading over the term's slope runs (smallest relative
        uncertainty); the line is checked against the curve from the start of its range on, or at
        every τ (``anywhere``)."""
        best = None
        for lo, hi in self.runs(term):
            idx = np.arange(lo, hi + 1)
            span = _range_text(self.taus[lo], self.taus[hi])
            cons = idx[self.consistent[term][idx]]
            if not cons.size:
                reasons.append(f"at {span} the slope ({self.mu[lo]:+.2f} to {self.mu[hi]:+.2f}) is nearer "
                               f"{SLOPE_TEXT[SLOPE[term]]} than any other term's but never within its tolerance")
                continue
            got = self.tangent(term, cons, others)
            if got is None:
                reasons.append(self.why)
                continue
            bad = self.contradiction(term, got["value"], None if anywhere else got["range"][0])
            if bad is not None:
                reasons.append(f"a {SLOPE_TEXT[SLOPE[term]]} line read at τ = {_fmt(self.taus[got['i']])} s (slope region "
                               f"{span}) would lie above the curve's upper {CHECK_Z:g}σ bound at τ = {_fmt(bad)} s: that "
                               f"slope is correlated noise or a transition, not {NAMES[term]}")
                continue
            if best is None or got["rel"] < best[0]["rel"]:
                best = (got, (float(self.taus[lo]), float(self.taus[hi])))
        return best

    def absent_reason(self, term: str, near: int) -> str:
        """Why a term has no slope region: the slope near where it would show (index ``near``)."""
        s = SLOPE_TEXT[SLOPE[term]]
        cons = self.consistent[term] & ~self.resolved[term]
        where = f"slope {self.slope_text(near)} at τ = {_fmt(self.taus[near])} s"
        if cons[near]:
            nb = " or ".join(NAMES[t] for t in READ_TERMS if abs(SLOPE[t] - SLOPE[term]) == 0.5
                            and abs(self.mu[near] - SLOPE[t]) <= self.z * self.u[near])
            return f"too few clusters to tell {NAMES[term]} from {nb} ({where})"
        return f"no {s} slope in the curve ({where})"

    def generic(self, term: str, values: dict[str, TermReading], near: int) -> TermReading:
        r = TermReading(term)
        reasons: list[str] = []
        others = self.others(term, values)
        best = self.read_runs(term, others, reasons)
        if best is None:
            if not any(lo <= near <= hi for lo, hi in self.runs(term)):
                reasons.append(self.absent_reason(term, near))
            r.reason = "; ".join(reasons)
            r.upper_bound = self.upper_bound(term)
            return r
        got, srange = best
        self.fill(r, got["i"])
        r.value, r.ci, r.tau_range_s, r.slope_range_s = got["value"], got["ci"], got["range"], srange
        return r

    def at(self, term: str, i: int, others: np.ndarray) -> dict[str, Any] | None:
        """The term's line through the curve at index ``i`` itself (IEEE 952 reads the −½ line at
        τ = 1 s), with the other terms' variance ``others`` taken off; ``None`` with ``self.why`` when
        the line would hold less than half of the variance there. The range is where that line lies
        within the curve's band at z standard deviations, contiguous around ``i``."""
        al = self.allan
        g = term_factor(term, self.taus)
        s2 = al.adev ** 2 - others
        share = np.clip(s2, 0.0, None) / al.adev ** 2
        if share[i] < MIN_SHARE or s2[i] <= 0:
            self.why = (f"at τ = {_fmt(self.taus[i])} s the {SLOPE_TEXT[SLOPE[term]]} line would hold only "
                        f"{100 * max(float(share[i]), 0.0):.0f} % of the variance once the other terms are taken off")
            return None
        c = math.sqrt(s2[i]) / g[i]
        ci = tuple(math.sqrt(max(b ** 2 - others[i], 0.0)) / g[i] for b in (al.adev_lo[i], al.adev_hi[i]))
        lo_z, hi_z = chi2_interval(al.adev, al.edf, math.erf(self.z / math.sqrt(2.0)))
        zlo = np.sqrt(np.clip(lo_z ** 2 - others, 0.0, None)) / g
        zhi = np.sqrt(np.clip(hi_z ** 2 - others, 0.0, None)) / g
        inside = (zlo <= c * (1 + 1e-12)) & (c <= zhi * (1 + 1e-12)) & (share >= MIN_SHARE)
        a = b = i
        while a - 1 >= 0 and inside[a - 1]:
            a -= 1
        while b + 1 < self.size and inside[b + 1]:
            b += 1
        rel = al.adev[i] ** 2 * math.sqrt(2.0 / al.edf[i]) / (2.0 * s2[i])
        return {"i": int(i), "value": float(c), "ci": (float(ci[0]), float(ci[1])),
                "range": (float(self.taus[a]), float(self.taus[b])), "rel": float(rel)}

    def white_at(self, one: int, runs: list[tuple[int, int]], others: np.ndarray) -> tuple[dict[str, Any] | None, str | None]:
        """The −½ line where the curve falls as −½ at 1 s (index ``one``): read at 1 s itself when
        1 s lies in a stretch where the slope is −½ within :data:`WHITE_SLOPE_TOL` (white noise
        holds ≥ 90 % of the variance there); else, when such a stretch exists elsewhere on a −½ run,
        read there (the line's value at 1 s is N) with the reason; else at 1 s. Returns the reading
        (or ``None``, ``self.why`` saying why) and the reason it is not read at 1 s."""
        in_run = np.zeros(self.size, dtype=bool)
        for lo, hi in runs:
            in_run[lo:hi + 1] = True
        pure = self.consistent["arw"] & in_run & (np.abs(self.mu + 0.5) <= np.maximum(WHITE_SLOPE_TOL, self.u))
        stretches = _true_runs(pure)
        if pure[one] or not stretches:
            return self.at("arw", one, others), None
        lo, hi = min(stretches, key=lambda r: min(abs(math.log(self.taus[i] / self.taus[one])) for i in (r[0], r[1])))
        got = self.tangent("arw", np.arange(lo, hi + 1), others, need_slope=False)
        if got is None:
            return self.at("arw", one, others), None
        why = (f"the slope at τ = {_fmt(self.taus[one])} s is {self.slope_text(one)}: white noise holds less than "
               f"90 % of the variance there (another term adds to it); the −½ line is read where the slope is "
               f"−½ within {WHITE_SLOPE_TOL:g} ({_range_text(self.taus[lo], self.taus[hi])}) and N is its value at 1 s")
        return got, why

    def arw(self, values: dict[str, TermReading]) -> TermReading:
        """IEEE Std 952 (Annex C) and NPSAT1 Table 13: the −½ line read at τ = 1 s.

        * the curve falls as −½ at 1 s (local slope consistent with −½): N = σ(1 s) itself, the other
          terms' variance taken off (``how`` ``"1 s"``); below 1 s the curve may lie under the line
          (an output filter or correlated noise flattens it there), which does not move the reading;
        * the curve has another slope at 1 s: the lowest −½ line touching the curve at τ ≥ 1 s
          (NPSAT1's reading, ``how`` ``"1 s"``, ``at_slope`` false, with the reading where the curve
          itself falls as −½ in ``alternative``);
        * 1 s not reached, or the line at 1 s not readable (it would hold less than half of the
          variance, or lie above the curve's upper band at longer τ): the −½ line read in a −½
          stretch (``how`` ``"slope region"``), and ``not_at_1s`` says why (the reason taken)."""
        r = TermReading("arw")
        others = self.others("arw", values)
        reasons: list[str] = []
        runs = self.runs("arw")
        reach = self.taus[0] <= self.arw_tau_s * (1 + 1e-9) and self.taus[-1] >= self.arw_tau_s * (1 - 1e-9)
        alt = self.read_runs("arw", others, reasons) if runs else None
        if not runs:
            r.reason = self.absent_reason("arw", int(np.argmin(np.abs(np.log(self.taus / self.arw_tau_s)))))
            idx = np.flatnonzero(self.taus >= self.arw_tau_s * (1 - 1e-9)) if reach else None
            r.upper_bound = self.upper_bound("arw", idx)
            return r
        got, how, not_at_1s = None, "slope region", None
        if not reach:
            not_at_1s = (f"the data do not reach τ = {_fmt(self.arw_tau_s)} s (τ = {_fmt(self.taus[0])}-"
                         f"{_fmt(self.taus[-1])} s)")
        else:
            idx = np.flatnonzero(self.taus >= self.arw_tau_s * (1 - 1e-9))
            one = int(idx[0])
            if self.consistent["arw"][one] or any(lo <= one <= hi for lo, hi in runs):
                # 1 s on the −½ stretch: the line read at 1 s, or where the slope is −½ on that stretch
                got, not_at_1s = self.white_at(one, runs, others)
                if got is None and not_at_1s is None:
                    not_at_1s = self.why
                how = "1 s" if got is not None and got["i"] == one else "slope region"
            else:  # another slope at 1 s: the lowest −½ line under the curve from 1 s on (NPSAT1)
                got = self.tangent("arw", idx, others, need_slope=False)
                if got is None:
                    not_at_1s = self.why
                how = "1 s"
            if got is not None:
                bad = self.contradiction("arw", got["value"], self.taus[got["i"]])
                if bad is not None:
                    not_at_1s = (f"the −½ line read at τ = {_fmt(self.taus[got['i']])} s would lie above the curve's "
                                 f"upper {CHECK_Z:g}σ bound at τ = {_fmt(bad)} s")
                    got = None
        if got is None:
            if alt is None:
                r.reason = "; ".join(([not_at_1s] if not_at_1s else []) + reasons) or "no −½ line fits under the curve"
                r.upper_bound = self.upper_bound("arw")
                return r
            got, how = alt[0], "slope region"
        self.fill(r, got["i"])
        r.how = how
        r.not_at_1s = not_at_1s if how == "slope region" else None
        r.value, r.ci, r.tau_range_s = got["value"], got["ci"], got["range"]
        k = np.concatenate([np.arange(lo, hi + 1) for lo, hi in runs])
        r.slope_range_s = (float(self.taus[k.min()]), float(self.taus[k.max()]))
        if alt is not None and alt[0]["i"] != got["i"] and not r.at_slope:
            a = alt[0]
            r.alternative = {"value": a["value"], "ci": a["ci"], "tau_s": float(self.taus[a["i"]]),
                             "tau_range_s": a["range"], "slope": float(self.mu[a["i"]]), "slope_u": float(self.u[a["i"]]),
                             "slope_range_s": alt[1]}
        return r

    def iterate(self, values: dict[str, TermReading]) -> None:
        """Read every term with the others' current variance taken off until the values settle."""
        for _ in range(6):
            before = {t: r.value for t, r in values.items()}
            values["bias_instability"] = self.bias_instability(values)
            values["quantization"] = self.generic("quantization", values, 0)
            values["arw"] = self.arw(values)
            values["rrw"] = self.generic("rrw", values, self.size - 1)
            values["rate_ramp"] = self.generic("rate_ramp", values, self.size - 1)
            if all(_same(before[t], values[t].value) for t in READ_TERMS):
                break

    def overshoot(self, values: dict[str, TermReading]) -> float | None:
        """The first τ where the terms taken off together exceed the curve's upper CHECK_Z band."""
        total = self.others("", values)
        bad = total > self.check_hi ** 2 * (1 + 1e-9)
        return float(self.taus[np.flatnonzero(bad)[0]]) if bad.any() else None

    def read(self) -> dict[str, TermReading]:
        values: dict[str, TermReading] = {t: TermReading(t) for t in READ_TERMS}
        if self.size == 0 or not np.all(self.allan.adev > 0) or not np.all(np.isfinite(self.mu)):
            why = ("the Allan deviation is 0 (the output does not change over the static stretch)"
                   if not np.all(self.allan.adev > 0) else "too few averaging times for a slope")
            for r in values.values():
                r.reason = why
            return values
        self.iterate(values)
        if values["bias_instability"].how == "flat region" and self.overshoot(values) is not None:
            # the terms read together lie above the curve: the "flat" stretch is the V where the
            # neighbouring slopes meet (their lines already fill it); read B as NPSAT1 does instead
            self.no_flat = True
            self.iterate(values)
        # the bias instability floor must not lie above the band anywhere (it cannot: it is the minimum)
        b = values["bias_instability"]
        if b.value is not None:
            bad = self.contradiction("bias_instability", b.value, None)
            if bad is not None:
                b.reason = f"0.664·B lies above the curve's upper confidence bound at τ = {_fmt(bad)} s"
                b.upper_bound, b.value = b.value, None
        return values


def _same(a: float | None, b: float | None) -> bool:
    if a is None or b is None:
        return a is b
    return math.isclose(a, b, rel_tol=1e-9)


def _true_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    out, i, n = [], 0, mask.size
    while i < n:
        if mask[i]:
            j = i
            while j + 1 < n and mask[j + 1]:
                j += 1
            out.append((i, j))
            i = j + 1
        else:
            i += 1
    return out


def read_noise_terms(allan: AllanResult, *, z: float = SLOPE_Z, arw_tau_s: float = ARW_TAU_S) -> NoiseReadout:
    """Read quantization, ARW, bias instability, rate random walk and rate ramp off a measured Allan
    deviation the way IEEE Std 952 Annex C and NPSAT1 IV.G.3 do (method in ``docs/noise.md``).

    ``allan`` should be dense in τ (:func:`analysis_m`, four per octave). Its confidence intervals
    are recomputed for the noise type the local slope shows. Each term is read from the τ range
    where the curve has that term's slope (local slope over an octave within SLOPE_TOL or ``z``
    standard uncertainties of it, and apart from the neighbouring terms' slopes by more than ``z``
    uncertainties): the line C·g(τ) that touches the curve there, with the other resolved terms'
    variance taken off (iterated). ARW is the −½ line read at ``arw_tau_s`` (the lowest that touches
    the curve at τ ≥ 1 s), the bias instability the curve's minimum / 0.664. A term whose slope is
    absent, or whose line would lie above the curve's upper confidence bound at longer τ, is not
    reported (``value`` ``None`` with a ``reason``)."""
    rd = _Reader(allan, z, arw_tau_s)
    return NoiseReadout(rd.allan, rd.mu, rd.u, rd.read(), z)
