"""Overlapping Allan deviation of a gyro rate series, its confidence intervals and the IEEE Std 952
noise-term fit (NPSAT1 thesis section IV.G.3; IEEE Std 952-1997 Annex C).

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
  (0), flicker FM (−1) and random-walk FM (−2). White FM (angle random walk) is the default; the
  noise calibration passes the type that dominates the fitted model at each τ.

The noise-term model fitted by :func:`fit_noise_terms` (IEEE Std 952 Eq. C.6 ff.):

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

import numpy as np
from scipy import optimize, stats

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

ALPHA = {"quantization": 2, "arw": 0, "bias_instability": -1, "rrw": -2}
"""Power-law exponent α (S_y ∝ f^α) of each noise term, for the edf formulas."""

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


def octave_m(n_samples: int, stop_ratio: int = STOP_RATIO) -> np.ndarray:
    """Averaging factors 1, 2, 4, … up to ``n_samples // stop_ratio`` (at least m = 1)."""
    top = max(1, n_samples // stop_ratio)
    return 2 ** np.arange(int(math.floor(math.log2(top))) + 1, dtype=np.int64)


def overlapping_adev(
    rate: np.ndarray | Sequence[float],
    fs: float,
    taus: np.ndarray | Sequence[float] | None = None,
    *,
    confidence: float = ONE_SIGMA,
    alpha: int | Sequence[int] | np.ndarray = 0,
) -> AllanResult:
    """Overlapping Allan deviation of ``rate`` (a rate series, e.g. deg/s) sampled at ``fs`` (Hz).

    ``taus`` (s): averaging times, each rounded to m = round(τ·f_s) samples; duplicates are merged
    and τ with m < 1 or fewer than two overlapping terms (m ≥ n/2) are dropped, as allantools does.
    Default: octave-spaced m = 1, 2, 4, … ≤ n/4. ``confidence``: level of the chi-squared
    interval (default ±1σ, 0.683); ``alpha``: noise type(s) for the edf (default 0, white FM).

    Raises :class:`InputError` for fewer than 3 samples, non-finite values, a bad ``fs``, or when
    no requested τ can be computed.
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

    if taus is None:
        m = octave_m(n)
    else:
        t = np.atleast_1d(np.asarray(taus, dtype=np.float64))
        if not np.all(np.isfinite(t)):
            raise InputError("averaging times must be finite numbers of seconds")
        m = np.round(t * float(fs))
        m = np.unique(m[(m >= 1) & (m < n / 2)]).astype(np.int64)  # n + 1 - 2m >= 2
        if m.size == 0:
            raise InputError(f"no usable averaging time in {list(t)} s for {n} samples at {fs:g} Hz "
                             f"(τ must lie between {1 / fs:g} s and {(n - 1) / 2 / fs:g} s)")

    x = _phase_samples(y, total / n)  # Σ(Ω − Ω̄) in units of rate·τ₀ (the 1/f_s factor is applied at the end)
    sums = _second_difference_sums(x, m)
    n_terms = (n + 1 - 2 * m).astype(np.int64)
    adev = np.sqrt(sums / (2.0 * n_terms)) / m  # rate units: (Σv²/2M)^½ / (m τ₀) with v in rate·τ₀
    alpha_arr = np.broadcast_to(np.asarray(alpha, dtype=int), m.shape).copy()
    edf = edf_simple(n + 1, m, alpha_arr)
    lo, hi = chi2_interval(adev, edf, confidence)
    return AllanResult(m / float(fs), m, adev, n_terms, edf, lo, hi, alpha_arr, float(confidence), n, float(fs))


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
            e = 2 * (big_n - 2) / (2.3 * big_n - 4.9) if mm == 1 else 5 * big_n ** 2 / (4 * mm * (big_n + 3 * mm))
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
    lo = dev * np.sqrt(edf / stats.chi2.ppf(1.0 - p, edf))
    hi = dev * np.sqrt(edf / stats.chi2.ppf(p, edf))
    return lo, hi


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
