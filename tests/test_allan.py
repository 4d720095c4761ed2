"""Overlapping Allan deviation, IEEE Std 952 read-outs and the noise / moving-average calibrations."""

from __future__ import annotations

import json
import math

import allantools
import numpy as np
import pytest
from allantools import ci as at_ci
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.analysis.allan import (
    FLICKER_FLOOR,
    ONE_SIGMA,
    chi2_interval,
    edf_simple,
    fit_noise_terms,
    octave_m,
    overlapping_adev,
)
from bench.analysis.dataset import Dataset, dataset_from_csv
from bench.analysis.noise_cal import (
    DEFAULT_BUFFER_LENGTHS,
    calibrate,
    calibrate_moving_average,
    detect_lsb,
)
from bench.errors import InputError

REL = 1e-9


def make_ds(rate: np.ndarray, fs: float, source: str = "synthetic.csv", **extra: np.ndarray) -> Dataset:
    n = rate.shape[0]
    cols = {"time_s": np.arange(n) / fs, "gyro_x_dps": np.asarray(rate, dtype=float), **extra}
    return Dataset(cols, {"sample_rate_hz": float(fs)}, source)


def white(rng: np.random.Generator, n: int, fs: float, arw_deg_rts: float) -> np.ndarray:
    """White rate noise with angle random walk N (deg/√s): per-sample σ = N·√f_s."""
    return rng.standard_normal(n) * arw_deg_rts * math.sqrt(fs)


def assert_matches_allantools(rate: np.ndarray, fs: float, taus=None) -> None:
    ours = overlapping_adev(rate, fs, taus)
    t, d, _, ns = allantools.oadev(rate, rate=fs, data_type="freq", taus=ours.taus_s if taus is None else taus)
    np.testing.assert_allclose(ours.taus_s, t, rtol=1e-12)
    np.testing.assert_array_equal(ours.n_terms, ns.astype(np.int64))
    np.testing.assert_allclose(ours.adev, d, rtol=REL, atol=0)


# ---- equality with allantools ----------------------------------------------------------------
def test_equals_allantools_default_octave_taus():
    rng = np.random.default_rng(1)
    n, fs = 50_000, 100.0
    rate = 0.4 + white(rng, n, fs, 0.005) + np.cumsum(rng.standard_normal(n)) * 1e-5
    ours = overlapping_adev(rate, fs)
    np.testing.assert_array_equal(ours.m, 2 ** np.arange(14))  # 1 … 8192 ≤ n/4
    assert_matches_allantools(rate, fs)


def test_equals_allantools_on_messy_tau_list():
    rng = np.random.default_rng(2)
    rate = rng.normal(-3.0, 0.2, 3001)
    taus = [0.1, 0.1, 0.004, 0.05, 0.0149, 7.5, 15.0, 15.005, 100.0, 2.7]  # duplicates, < τ0, > n/2, rounding
    ours = overlapping_adev(rate, 100.0, taus)
    np.testing.assert_array_equal(ours.m, [1, 5, 10, 270, 750, 1500])
    assert_matches_allantools(rate, 100.0, taus)


def test_cluster_sizes_given_directly_equal_the_taus_path_and_allantools():
    """``m=`` (what ``bench diagnose``'s structure plot passes: octaves up to n/8) gives the same
    deviations as the averaging times m/f_s and as allantools, also where τ·f_s is inexact."""
    from bench.analysis.diagnose.structure import allan as structure_allan

    rng = np.random.default_rng(3)
    fs = 1 / 3
    rate = rng.normal(0.1, 0.02, 5000) + np.cumsum(rng.standard_normal(5000)) * 1e-4
    m = octave_m(rate.shape[0], 8)
    ours = overlapping_adev(rate, fs, m=m)
    np.testing.assert_array_equal(ours.m, m)
    np.testing.assert_array_equal(ours.adev, overlapping_adev(rate, fs, m / fs).adev)
    _, d, _, _ = allantools.oadev(rate, rate=fs, data_type="freq", taus=m / fs)
    np.testing.assert_allclose(ours.adev, d, rtol=REL, atol=0)
    taus, adev = structure_allan(rate, fs)
    np.testing.assert_array_equal(taus, ours.taus_s)
    np.testing.assert_array_equal(adev, ours.adev)
    assert [a.size for a in structure_allan(rate[:7], fs)] == [0, 0]
    np.testing.assert_array_equal(overlapping_adev(rate, fs, m=[0, 4, 1, 1, 2, 2500]).m, [1, 2, 4])
    with pytest.raises(InputError, match="not both"):
        overlapping_adev(rate, fs, [3.0], m=[1])
    with pytest.raises(InputError, match="whole numbers"):
        overlapping_adev(rate, fs, m=[1.5])
    with pytest.raises(InputError, match="no usable averaging factor"):
        overlapping_adev(rate, fs, m=[2500])


@settings(max_examples=60, deadline=None)
@given(n=st.integers(3, 4000), fs=st.floats(0.05, 5000.0), scale=st.floats(1e-4, 1e3),
       offset=st.floats(-10.0, 10.0), seed=st.integers(0, 2**32 - 1), walk=st.booleans())
def test_equals_allantools_hypothesis(n, fs, scale, offset, seed, walk):
    rng = np.random.default_rng(seed)
    rate = rng.standard_normal(n)
    if walk:
        rate = np.cumsum(rate) / math.sqrt(n)
    rate = scale * (rate + offset)
    assert_matches_allantools(rate, fs)
    every = np.arange(1, n + 1) / fs  # every m, including the ones both drop (m >= n/2)
    assert_matches_allantools(rate, fs, every)


def test_edf_equals_allantools_simple_formulas():
    for alpha in (2, 1, 0, -1, -2):
        for m in (1, 2, 7, 64, 250):
            if alpha == -1 and m == 1:
                continue  # allantools drops the square of SP 1065 Table 5 here (below)
            assert edf_simple(1001, m, alpha)[0] == pytest.approx(max(at_ci.edf_simple(1001, m, alpha), 1.0), rel=1e-12)


def test_edf_flicker_fm_at_m1_has_the_square():
    """NIST SP 1065 Table 5, flicker FM, m = 1: 2(N−2)²/(2.3N − 4.9) ≈ 0.87 N (allantools 2024.6 has
    2(N−2)/(2.3N − 4.9) < 1, which would make the m = 1 interval of 10⁵ samples span decades)."""
    n = 100_001
    assert edf_simple(n, 1, -1)[0] == pytest.approx(2 * (n - 2) ** 2 / (2.3 * n - 4.9), rel=1e-12)
    assert 0.5 < edf_simple(n, 1, -1)[0] / edf_simple(n, 2, -1)[0] < 2.0  # continuous with m = 2


# ---- confidence intervals ---------------------------------------------------------------------
def test_ci_contains_estimate_and_narrows_with_more_data():
    rng = np.random.default_rng(3)
    widths = []
    for n in (10_000, 100_000):
        r = overlapping_adev(white(rng, n, 100.0, 0.005), 100.0)
        assert np.all(r.adev_lo < r.adev) and np.all(r.adev < r.adev_hi)
        k = int(np.flatnonzero(r.m == 8)[0])
        widths.append((r.adev_hi[k] - r.adev_lo[k]) / r.adev[k])
    assert widths[1] < widths[0] / 2.5  # ~1/√10


def test_ci_coverage_white_fm():
    """The ±1σ (68.3 %) chi-squared intervals hold the true σ(τ) = σ/√m about 68 % of the time."""
    rng = np.random.default_rng(5)
    trials, hits = 400, np.zeros(4)
    for _ in range(trials):
        r = overlapping_adev(rng.standard_normal(1000), 1.0, [1, 4, 16, 64])
        truth = 1.0 / np.sqrt(r.m)
        hits += (r.adev_lo <= truth) & (truth <= r.adev_hi)
    assert r.confidence == pytest.approx(ONE_SIGMA)
    assert np.all(np.abs(hits / trials - ONE_SIGMA) < 0.08), hits / trials


# ---- read-outs ---------------------------------------------------------------------------------
def test_white_noise_arw_within_10_percent():
    rng = np.random.default_rng(11)
    fs, arw = 100.0, 0.005  # deg/√s = 0.3 deg/√h
    res = calibrate(make_ds(0.3 + white(rng, 200_000, fs, arw), fs))
    x = res.json["axes"]["x"]
    assert x["arw_deg_per_sqrt_h"] == pytest.approx(arw * 60, rel=0.10)
    assert x["detected"]["arw"] and not x["detected"]["quantization"] and not x["detected"]["rrw"]
    assert x["quantization_deg"] is None and x["terms"]["quantization"]["reason"]
    assert x["lsb_dps"] is None
    assert res.method == "noise" and res.calibration is None
    assert res.json["sample_rate_hz"] == 100.0
    assert set(x) >= {"arw_deg_per_sqrt_h", "bias_instability_deg_per_h", "rrw_deg_per_h_per_sqrt_h", "quantization_deg",
                      "taus_s", "adev_dps", "adev_lo_dps", "adev_hi_dps"}
    assert len(x["taus_s"]) == len(x["adev_dps"]) == len(x["adev_lo_dps"]) == len(x["adev_hi_dps"])
    json.dumps(res.json, allow_nan=False)
    assert any("still falling" in n for n in res.notes)  # white noise only: no flat region


def test_rate_random_walk_within_20_percent():
    rng = np.random.default_rng(12)
    fs, n, arw, k = 10.0, 200_000, 0.005, 2e-4  # K in deg/s/√s; the -½ and +½ lines cross at τ ≈ 43 s
    rate = white(rng, n, fs, arw) + np.cumsum(rng.standard_normal(n)) * k / math.sqrt(fs)
    x = calibrate(make_ds(rate, fs)).json["axes"]["x"]
    assert x["rrw_deg_per_h_per_sqrt_h"] == pytest.approx(k * 3600 ** 1.5, rel=0.20)
    assert x["arw_deg_per_sqrt_h"] == pytest.approx(arw * 60, rel=0.10)
    assert x["detected"]["rrw"] and x["detected"]["arw"]


def test_angle_quantization_separated_from_arw():
    """IEEE 952 quantization noise (white angle error, uniform over one count q) on top of white rate:
    the −1 slope is fitted as Q = q/√12 and not read as angle random walk."""
    rng = np.random.default_rng(13)
    fs, n, arw, q = 100.0, 100_000, 0.005, 0.01  # q in deg
    rate = white(rng, n, fs, arw) + np.diff(rng.uniform(-q / 2, q / 2, n + 1)) * fs
    x = calibrate(make_ds(rate, fs)).json["axes"]["x"]
    assert x["detected"]["quantization"]
    assert x["quantization_deg"] == pytest.approx(q / math.sqrt(12), rel=0.10)
    assert x["arw_deg_per_sqrt_h"] == pytest.approx(arw * 60, rel=0.10)
    naive = x["adev_dps"][0] * math.sqrt(x["taus_s"][0]) * 60  # a −½ line through the first point
    assert naive > 3 * arw * 60


@pytest.mark.parametrize("lsb, sigma", [(250.0 / 32768, 0.022), (0.061, 0.1)])
def test_rate_quantised_16_bit_output_arw_still_correct(lsb, sigma):
    """A digital 16-bit rate output (LSB 0.0076 deg/s MPU-6000 ±250 deg/s, or 0.061 deg/s): the LSB is
    found and the read ARW stays within 10 % of the sensor's."""
    rng = np.random.default_rng(14)
    fs = 100.0
    counts = np.round((0.37 + rng.standard_normal(200_000) * sigma) / lsb)
    res = calibrate(make_ds(counts * lsb, fs))
    x = res.json["axes"]["x"]
    assert x["lsb_dps"] == pytest.approx(lsb, rel=1e-9)
    assert x["arw_deg_per_sqrt_h"] == pytest.approx(sigma / math.sqrt(fs) * 60, rel=0.10)
    assert not x["detected"]["quantization"]  # rounding a noisy rate is white: no −1 slope


def test_coarse_lsb_correction():
    """Noise only 0.66 LSB: rounding adds LSB²/12 of white variance (+9 % in ARW); the corrected ARW
    removes it."""
    rng = np.random.default_rng(15)
    fs, lsb, sigma = 100.0, 0.061, 0.04
    res = calibrate(make_ds(np.round((0.37 + rng.standard_normal(200_000) * sigma) / lsb) * lsb, fs))
    x = res.json["axes"]["x"]
    truth = sigma / math.sqrt(fs) * 60
    assert x["arw_deg_per_sqrt_h"] / truth - 1 > 0.06
    assert x["arw_lsb_corrected_deg_per_sqrt_h"] == pytest.approx(truth, rel=0.03)
    assert any("output resolution" in n for n in res.notes)


def test_noise_below_one_lsb_is_flagged():
    rng = np.random.default_rng(16)
    lsb = 0.061
    res = calibrate(make_ds(np.round((0.37 + rng.standard_normal(20_000) * 0.01) / lsb) * lsb, 100.0))
    assert any("quantization-limited" in n for n in res.notes)
    assert res.json["axes"]["x"]["arw_lsb_corrected_deg_per_sqrt_h"] is None


def test_bias_instability_on_flicker_plateau():
    rng = np.random.default_rng(17)
    fs, n, b, arw = 100.0, 200_000, 1e-3, 0.001  # B = 3.6 deg/h
    f = np.fft.rfftfreq(n, 1 / fs)
    psd = np.zeros_like(f)
    psd[1:] = b ** 2 / (2 * math.pi * f[1:])  # two-sided S(f) = B²/(2πf), IEEE 952 Eq. C.13
    flicker = np.fft.irfft(np.fft.rfft(rng.standard_normal(n)) * np.sqrt(psd * fs), n)
    x = calibrate(make_ds(white(rng, n, fs, arw) + flicker, fs)).json["axes"]["x"]
    assert x["detected"]["bias_instability"]
    assert x["bias_instability_deg_per_h"] == pytest.approx(b * 3600, rel=0.25)
    assert x["arw_deg_per_sqrt_h"] == pytest.approx(arw * 60, rel=0.10)


def test_fit_of_pure_model_curve_is_exact():
    taus = np.logspace(-2, 4, 30)
    q, nn, b, k = 3e-4, 2e-3, 5e-4, 3e-5
    avar = 3 * q * q / taus ** 2 + nn * nn / taus + 2 * math.log(2) / math.pi * b * b + k * k * taus / 3
    r = overlapping_adev(np.random.default_rng(0).standard_normal(10), 1.0)
    fake = type(r)(taus, np.arange(1, 31), np.sqrt(avar), np.full(30, 1000), np.full(30, 100.0), avar, avar,
                   np.zeros(30, int), r.confidence, 10**6, 1.0)
    t = fit_noise_terms(fake)
    assert (t.q_deg, t.n_deg_rts, t.b_dps, t.k_dps_rts) == pytest.approx((q, nn, b, k), rel=1e-6)
    assert all(t.dominant.values())


# ---- read-out by the book (IEEE Std 952 Annex C, NPSAT1 IV.G.3) --------------------------------
FLAT_KEYS = {"quantization": "quantization_deg", "arw": "arw_deg_per_sqrt_h",
             "bias_instability": "bias_instability_deg_per_h", "rrw": "rrw_deg_per_h_per_sqrt_h",
             "rate_ramp": "rate_ramp_deg_per_h_per_h"}


def gauss_markov(rng: np.random.Generator, n: int, fs: float, sigma: float, tau_c: float) -> np.ndarray:
    """First-order Gauss-Markov rate (white noise through a low-pass, correlation time ``tau_c``): its
    Allan deviation rises as +½, peaks near 1.9·τ_c and falls as −½ (a hump, like the S5 log's)."""
    from scipy.signal import lfilter

    a = math.exp(-1.0 / (fs * tau_c))
    return lfilter([1.0], [1.0, -a], rng.standard_normal(n) * sigma * math.sqrt(1 - a * a))


def _flicker(rng: np.random.Generator, n: int, fs: float, b: float) -> np.ndarray:
    """Flicker (1/f) rate noise, two-sided S(f) = B²/(2πf) (IEEE 952 Eq. C.13): shaped in the frequency
    domain over 4n samples and cut to n, so the record is not one period of a circular signal (which
    would make the longest-τ Allan deviations dive)."""
    big = 4 * n
    f = np.fft.rfftfreq(big, 1 / fs)
    psd = np.zeros_like(f)
    psd[1:] = b ** 2 / (2 * math.pi * f[1:])
    return np.fft.irfft(np.fft.rfft(rng.standard_normal(big)) * np.sqrt(psd * fs), big)[n:2 * n]


LINES = {  # σ(τ) of each term's line from its reading in the customary unit (IEEE 952 Annex C, NPSAT1 Eq. 23)
    "quantization": lambda v, tau: math.sqrt(3) * v / tau,
    "arw": lambda v, tau: v / 60 / np.sqrt(tau),
    "bias_instability": lambda v, tau: FLICKER_FLOOR * v / 3600 + 0 * tau,
    "rrw": lambda v, tau: v / 3600 ** 1.5 * np.sqrt(tau / 3),
    "rate_ramp": lambda v, tau: v / 3600 ** 2 * tau / math.sqrt(2),
}


def assert_by_the_book(x: dict) -> None:
    """Every term: a positive value with where and how it was read, or null with a reason; the flat
    keys follow the terms; no reported line lies above the curve's upper band from where it was read
    on (the bias instability's nowhere)."""
    # the contradiction test uses the curve's 3σ band: with tens of τ a 1σ band is crossed somewhere by chance
    taus = np.array(x["taus_s"])
    hi = chi2_interval(np.array(x["adev_dps"]), np.array(x["edf"]), math.erf(3 / math.sqrt(2)))[1]
    for name, t in x["terms"].items():
        if t["value"] is not None:
            start = 0.0 if name == "bias_instability" else t["tau_range_s"][0]
            past = taus >= start * (1 - 1e-12)
            assert np.all(LINES[name](t["value"], taus[past]) <= hi[past] * (1 + 1e-9)), name
        assert x[FLAT_KEYS[name]] == t["value"]
        if t["value"] is None:
            assert isinstance(t["reason"], str) and t["reason"], name
            continue
        assert t["value"] > 0, name  # never 0
        assert t["reason"] is None
        assert t["tau_range_s"][0] <= t["tau_s"] <= t["tau_range_s"][1], name
        assert 0 <= t["ci"][0] <= t["value"] <= t["ci"][1], name
        assert t["n_terms"] + 1 >= t["clusters"] >= 1 and math.isfinite(t["slope_at_read"]) and t["slope_uncertainty"] > 0
    json.dumps(x, allow_nan=False)


def test_by_the_book_white_noise():
    """White noise only: N exact within its interval; no floor (still falling), no Q, K or R."""
    rng = np.random.default_rng(31)
    fs, arw = 100.0, 0.005
    res = calibrate(make_ds(0.3 + white(rng, 200_000, fs, arw), fs))
    x = res.json["axes"]["x"]
    assert_by_the_book(x)
    n = x["terms"]["arw"]
    assert n["ci"][0] <= arw * 60 <= n["ci"][1]
    assert n["value"] == pytest.approx(arw * 60, rel=0.02)
    assert n["slope_range_s"][0] <= 1.0 <= n["slope_range_s"][1]  # 1 s on the −½ stretch: the same line everywhere
    b = x["terms"]["bias_instability"]
    assert b["value"] is None or b["estimate_only"]
    if b["value"] is None:
        assert "still falling" in b["reason"] and b["upper_bound"] > 0
    for t in ("quantization", "rrw", "rate_ramp"):
        assert x["terms"][t]["value"] is None and x["terms"][t]["reason"]
    assert x["detected"] == {"quantization": False, "arw": True, "bias_instability": False, "rrw": False, "rate_ramp": False}


def test_by_the_book_white_plus_rrw():
    rng = np.random.default_rng(32)
    fs, n, arw, k = 10.0, 200_000, 0.005, 2e-4  # the −½ and +½ lines cross at τ = √3·N/K ≈ 43 s
    rate = white(rng, n, fs, arw) + np.cumsum(rng.standard_normal(n)) * k / math.sqrt(fs)
    x = calibrate(make_ds(rate, fs)).json["axes"]["x"]
    assert_by_the_book(x)
    assert x["rrw_deg_per_h_per_sqrt_h"] == pytest.approx(k * 3600 ** 1.5, rel=0.20)
    assert x["arw_deg_per_sqrt_h"] == pytest.approx(arw * 60, rel=0.10)
    assert x["terms"]["rrw"]["tau_s"] > 43  # read where the +½ slope holds
    b = x["terms"]["bias_instability"]  # a V where −½ meets +½: NPSAT1's "estimate only"
    assert b["value"] is not None and b["estimate_only"] and not x["detected"]["bias_instability"]
    assert 20 < b["tau_s"] < 90


def test_by_the_book_white_plus_angle_quantization():
    rng = np.random.default_rng(33)
    fs, n, arw, q = 100.0, 100_000, 0.005, 0.01  # −1 and −½ lines cross at τ = 3Q²/N² = 1 s
    rate = white(rng, n, fs, arw) + np.diff(rng.uniform(-q / 2, q / 2, n + 1)) * fs
    x = calibrate(make_ds(rate, fs)).json["axes"]["x"]
    assert_by_the_book(x)
    assert x["quantization_deg"] == pytest.approx(q / math.sqrt(12), rel=0.10)
    assert x["terms"]["quantization"]["tau_s"] < 0.3
    assert x["arw_deg_per_sqrt_h"] == pytest.approx(arw * 60, rel=0.10)


def test_by_the_book_white_plus_flicker_floor():
    rng = np.random.default_rng(34)
    fs, n, b, arw = 100.0, 200_000, 1e-3, 0.001  # B = 3.6 deg/h
    x = calibrate(make_ds(white(rng, n, fs, arw) + _flicker(rng, n, fs, b), fs)).json["axes"]["x"]
    assert_by_the_book(x)
    t = x["terms"]["bias_instability"]
    assert t["value"] == pytest.approx(b * 3600, rel=0.25) and not t["estimate_only"]
    assert t["slope_range_s"][1] / t["slope_range_s"][0] >= 2  # a flat stretch of an octave or more
    assert x["arw_deg_per_sqrt_h"] == pytest.approx(arw * 60, rel=0.10)


def test_by_the_book_white_plus_rate_ramp():
    """A linear drift of the rate (NPSAT1 Eq. 23: σ = R·τ/√2) read from the +1 slope."""
    rng = np.random.default_rng(35)
    fs, n, arw = 10.0, 200_000, 0.005
    ramp = math.sqrt(2 * arw ** 2 / 20.0 ** 3)  # deg/s²: the −½ and +1 lines cross at τ = 20 s
    x = calibrate(make_ds(white(rng, n, fs, arw) + ramp * np.arange(n) / fs, fs)).json["axes"]["x"]
    assert_by_the_book(x)
    assert x["rate_ramp_deg_per_h_per_h"] == pytest.approx(ramp * 3600 ** 2, rel=0.20)
    assert x["terms"]["rate_ramp"]["slope_at_read"] == pytest.approx(1.0, abs=0.2)
    assert x["arw_deg_per_sqrt_h"] == pytest.approx(arw * 60, rel=0.10)
    assert x["rrw_deg_per_h_per_sqrt_h"] is None  # the rise is +1, not +½


def test_by_the_book_correlated_hump_is_not_rrw():
    """A Gauss-Markov hump (as on the S5 log): the rising side has slope ≈ +½ over an octave, but a +½
    line through it would lie far above the curve at longer τ: not reported as rate random walk. The
    ARW is the −½ line at τ = 1 s with a note that the curve rises there, and the −½ tail is given."""
    rng = np.random.default_rng(36)
    fs, n = 10.0, 200_000
    rate = white(rng, n, fs, 1e-4) + gauss_markov(rng, n, fs, 0.02, 5.0)
    res = calibrate(make_ds(rate, fs))
    x = res.json["axes"]["x"]
    assert_by_the_book(x)
    assert x["rrw_deg_per_h_per_sqrt_h"] is None and "above the curve" in x["terms"]["rrw"]["reason"]
    a = x["terms"]["arw"]
    assert a["tau_s"] == 1.0 and x["arw_slope_at_read"] > 0.3
    assert a["value"] == pytest.approx(x["adev_dps"][x["taus_s"].index(0.8)] * 60, rel=0.3)
    tail = a["where_slope"]  # the GM tail integrates like ARW σ·√(2τ_c) = 0.063 deg/√s
    assert tail["value"] == pytest.approx(0.02 * math.sqrt(2 * 5.0) * 60, rel=0.15)
    assert any("rises there" in m and "where_slope" in m for m in res.notes)


def test_by_the_book_data_not_reaching_one_second():
    rng = np.random.default_rng(37)
    fs, arw = 0.5, 0.01  # one sample every 2 s
    res = calibrate(make_ds(white(rng, 20_000, fs, arw), fs))
    x = res.json["axes"]["x"]
    assert_by_the_book(x)
    assert x["terms"]["arw"]["tau_s"] >= 2.0
    assert x["arw_deg_per_sqrt_h"] == pytest.approx(arw * 60, rel=0.05)
    assert any("do not reach τ = 1 s" in m for m in res.notes)


def adis_like(rng: np.random.Generator, n: int, fs: float, arw_dps_rt_s: float, fc_hz: float) -> np.ndarray:
    """White rate noise through the sensor's first-order low-pass at ``fc_hz`` (an ADIS16405-like
    output: its Allan deviation is flatter than −½ at short τ, where the filter averages, and −½ from
    a few filter time constants on)."""
    from scipy.signal import lfilter

    a = math.exp(-2 * math.pi * fc_hz / fs)
    return lfilter([1 - a], [1, -a], white(rng, n, fs, arw_dps_rt_s))


@pytest.mark.parametrize("seed", [1, 2])
def test_arw_read_at_one_second_where_short_taus_are_flatter(seed):
    """IEEE 952: N is the −½ line read at τ = 1 s. An ADIS-like curve (slope +0.1 … −0.4 below 0.3 s,
    −½ from there on) lies under the −½ line at short τ; the old read-out took the lowest −½ line
    touching the curve and read it far from 1 s (0.005-460 s, 17-23 % low). Now: read at 1 s, within
    the statistics and the filter's 1 % of the true N, and no note claiming another reason."""
    rng = np.random.default_rng(seed)
    fs, n, arw = 200.0, 240_000, 2.0 / 60  # 20 min at 200 Hz, N = 2 deg/√h, 10 Hz low-pass
    res = calibrate(make_ds(adis_like(rng, n, fs, arw, 10.0), fs))
    x = res.json["axes"]["x"]
    assert_by_the_book(x)
    a = x["terms"]["arw"]
    slopes = np.array([np.nan if v is None else v for v in x["slope"]])
    taus = np.array(x["taus_s"])
    assert np.all(slopes[taus < 0.1] > -0.35)  # the case: flatter than −½ at short τ
    assert a["read"] == "1 s" and a["tau_s"] == 1.0 and a["not_at_1s"] is None
    assert abs(a["slope_at_read"] + 0.5) < 0.15
    assert a["value"] == pytest.approx(arw * 60, rel=0.06)
    assert a["where_slope"] is None
    assert not any("ARW" in m and "read at τ" in m for m in res.notes)


def test_arw_note_gives_the_reason_taken():
    """When the −½ line cannot be read at 1 s, the note's reason is the one in the reading
    (``not_at_1s``), not a fixed text."""
    rng = np.random.default_rng(37)
    fs, arw = 0.5, 0.01
    res = calibrate(make_ds(white(rng, 20_000, fs, arw), fs))
    a = res.json["axes"]["x"]["terms"]["arw"]
    assert a["read"] == "slope region" and a["not_at_1s"].startswith("the data do not reach τ = 1 s (τ = 2-")
    assert any(a["not_at_1s"] in m and "ARW" in m for m in res.notes)


def test_by_the_book_quantised_register_is_said():
    rng = np.random.default_rng(38)
    lsb = 250.0 / 32768
    res = calibrate(make_ds(np.round((0.37 + rng.standard_normal(100_000) * 0.022) / lsb) * lsb, 100.0))
    x = res.json["axes"]["x"]
    assert x["lsb_dps"] == lsb and x["output_levels"] < 100
    assert any("the output is quantised" in m and "0.007629 deg/s" in m for m in res.notes)
    assert_by_the_book(x)


@pytest.mark.parametrize("seed", range(6))
def test_by_the_book_never_reports_zero(seed):
    """Whatever the mix (terms switched on and off at random), a term is a positive number or null
    with a reason; the old NNLS read-out reported 0.000 for terms it put no weight on."""
    rng = np.random.default_rng(100 + seed)
    fs, n = 10.0, 50_000
    on = rng.random(4) < 0.5
    rate = white(rng, n, fs, 0.003 * (1 + 9 * on[0]) * 0.1)
    if on[1]:
        rate = rate + np.cumsum(rng.standard_normal(n)) * 1e-4 / math.sqrt(fs)
    if on[2]:
        rate = rate + _flicker(rng, n, fs, 5e-4)
    if on[3]:
        rate = rate + gauss_markov(rng, n, fs, 0.01, 3.0)
    x = calibrate(make_ds(rate, fs)).json["axes"]["x"]
    assert_by_the_book(x)


# ---- the S5 phone log of the issue ---------------------------------------------------------------
def _s5(real_log) -> tuple[np.ndarray, Dataset]:
    h5py = pytest.importorskip("h5py")
    with h5py.File(real_log("samsung_galaxy_s5.nc"), "r") as f:
        gyro = np.degrees(np.asarray(f["angular_velocity"][:, 3:6], dtype=float))  # rad/s -> deg/s
    n = gyro.shape[0]
    cols = {"time_s": np.arange(n) / 10.0, **{f"gyro_{a}_dps": gyro[:, k] for k, a in enumerate("xyz")}}
    return gyro, Dataset(cols, {"sample_rate_hz": 10.0}, "samsung_galaxy_s5.nc")


def test_s5_log_read_by_the_book(real_log):
    """The issue's log (Samsung Galaxy S5 still for 6 h at 10 Hz): ARW within 10 % of σ(τ = 1 s) and
    bias instability within 25 % of the minimum / 0.664 of the Allan deviation computed by allantools
    (octave τ, σ at 1 s interpolated between 0.8 and 1.6 s as the issue did), every axis; nothing
    reported as 0; the +½ rise at 0.3-2 s (correlated noise) not taken for rate random walk; the float
    output not taken for a quantised one."""
    gyro, ds = _s5(real_log)
    res = calibrate(ds)
    for k, a in enumerate("xyz"):
        t, d, _, _ = allantools.oadev(gyro[:, k], rate=10.0, data_type="freq", taus="octave")
        arw_ref = np.interp(1.0, t, d) * 60  # deg/s at τ = 1 s -> deg/√h
        b_ref = d.min() / FLICKER_FLOOR * 3600
        x = res.json["axes"][a]
        assert_by_the_book(x)
        assert x["arw_deg_per_sqrt_h"] == pytest.approx(arw_ref, rel=0.10), a
        assert x["bias_instability_deg_per_h"] == pytest.approx(b_ref, rel=0.25), a
        assert x["terms"]["arw"]["tau_s"] == 1.0 and x["arw_slope_at_read"] > 0.3  # the curve rises at 1 s
        assert x["terms"]["arw"]["read"] == "1 s" and x["terms"]["arw"]["not_at_1s"] is None
        assert 200 < x["terms"]["bias_instability"]["tau_s"] < 3000
        assert x["rrw_deg_per_h_per_sqrt_h"] is None and "above the curve" in x["terms"]["rrw"]["reason"]
        assert x["quantization_deg"] is None
        assert x["lsb_dps"] is None
    assert sum("rises there" in m for m in res.notes) == 3
    assert not any("quantised" in m for m in res.notes)


def test_cats_log_arw_reason_is_the_one_taken(real_log):
    """The CATS tag log (1 Hz, quantised output): the −½ line through τ = 1 s is refused on every axis
    (x: quantization holds the variance there; y, z: the line would cross the curve's 3σ band at longer
    τ); the ARW is read on the −½ stretch and the note gives exactly the reason the read-out took (the
    old note said "no −½ line read at τ ≥ 1 s holds half of the curve there" whatever the reason, and
    the JSON called it "slope region with 1 s")."""
    h5py = pytest.importorskip("h5py")
    with h5py.File(real_log("cats_temperature_calib.nc"), "r") as f:
        gyro = np.degrees(np.asarray(f["angular_velocity"][:], dtype=float) / 1000.0)  # mrad/s -> deg/s
    n = gyro.shape[0]
    ds = Dataset({"time_s": np.arange(n) / 1.0, **{f"gyro_{a}_dps": gyro[:, k] for k, a in enumerate("xyz")}},
                 {"sample_rate_hz": 1.0}, "cats_temperature_calib.nc")
    res = calibrate(ds)
    reasons = {}
    for a in "xyz":
        t = res.json["axes"][a]["terms"]["arw"]
        assert t["read"] == "slope region" and t["tau_s"] > 1.0
        reasons[a] = t["not_at_1s"]
        note = next(m for m in res.notes if m.startswith(f"{a}: ARW "))
        assert note.endswith(f"where the slope is −½ ({t['not_at_1s']})"), note
    assert "would hold only" in reasons["x"] and "quantization" in " ".join(res.notes)
    assert all("would lie above the curve's upper 3σ bound" in reasons[a] for a in "yz")
    assert not any("holds half of the curve" in m for m in res.notes)


# ---- static selection and bad input -----------------------------------------------------------
def test_uses_only_static_rows():
    rng = np.random.default_rng(18)
    fs, n = 100.0, 100_000
    ref = np.where(np.arange(n) < 40_000, 10.0, 0.0)
    rate = ref + white(rng, n, fs, 0.005)
    zeros = np.zeros(n)
    res = calibrate(make_ds(rate, fs, ref_rate_x_dps=zeros, ref_rate_y_dps=zeros, ref_rate_z_dps=ref))
    assert res.json["static_samples"] == 60_000
    assert res.json["static_t_s"][0] == pytest.approx(400.0)
    assert res.json["axes"]["x"]["arw_deg_per_sqrt_h"] == pytest.approx(0.3, rel=0.10)
    assert any("40000 moving rows" in n for n in res.notes)


def test_no_static_rows_is_input_error():
    n = 1000
    ds = make_ds(np.zeros(n), 100.0, source="run_0042.h5", ref_rate_z_dps=np.full(n, 10.0))
    with pytest.raises(InputError, match=r"run_0042\.h5.*no static rows.*ref_rate_z_dps"):
        calibrate(ds)
    with pytest.raises(InputError, match="no static rows"):
        calibrate_moving_average(ds)


def test_time_gap_uses_longest_even_stretch():
    rng = np.random.default_rng(19)
    fs, n = 100.0, 30_000
    ds = make_ds(white(rng, n, fs, 0.005), fs)
    ds.columns["time_s"][10_000:] += 5.0  # 5 s of lost frames
    res = calibrate(ds)
    assert res.json["static_samples"] == 20_000
    assert any("uneven time step" in n and "rows 10001-30000" in n for n in res.notes)


def test_bad_inputs_raise_input_error():
    rng = np.random.default_rng(20)
    ok = make_ds(white(rng, 5000, 100.0, 0.005), 100.0)
    with pytest.raises(InputError, match="at least 64"):
        calibrate(make_ds(np.zeros(20), 100.0))
    nan = make_ds(white(rng, 5000, 100.0, 0.005), 100.0)
    nan.columns["gyro_x_dps"][123] = np.nan
    with pytest.raises(InputError, match=r"gyro_x_dps.*row 124"):
        calibrate(nan)
    with pytest.raises(InputError, match="unknown option"):
        calibrate(ok, tau=[1.0])
    with pytest.raises(InputError, match="taus"):
        calibrate(ok, taus=[-1.0])
    with pytest.raises(InputError, match="no usable averaging time"):
        calibrate(ok, taus=[1e6])
    with pytest.raises(InputError, match="gyro_y_dps"):
        calibrate(ok, axes=["y"])
    with pytest.raises(InputError, match="confidence"):
        calibrate(ok, confidence=1.5)
    wrong_rate = make_ds(white(rng, 5000, 100.0, 0.005), 100.0)
    wrong_rate.meta["sample_rate_hz"] = 50.0
    with pytest.raises(InputError, match=r"time_s.*do not match sample_rate_hz = 50 Hz"):
        calibrate(wrong_rate)
    with pytest.raises(InputError, match="no gyro column"):
        calibrate(Dataset({"time_s": np.arange(100.0)}, {}, "x.csv"))
    with pytest.raises(InputError, match="buffer_lengths"):
        calibrate_moving_average(ok, buffer_lengths=[0, 2])
    with pytest.raises(InputError, match="whole numbers"):
        calibrate_moving_average(ok, buffer_lengths=[2.5])


def test_csv_round_trip(tmp_path):
    rng = np.random.default_rng(21)
    fs, n = 50.0, 4000
    rate = white(rng, n, fs, 0.01)
    p = tmp_path / "static.csv"
    lines = ["# sample_rate_hz: 50", "time_s,gyro_x_dps,gyro_z_dps"]
    lines += [f"{i / fs:.4f},{a:.9f},{b:.9f}" for i, (a, b) in enumerate(zip(rate, -rate))]
    p.write_text("\n".join(lines) + "\n")
    res = calibrate(dataset_from_csv(p), taus="0.02, 0.1, 1")
    assert set(res.json["axes"]) == {"x", "z"}
    assert res.json["axes"]["x"]["taus_s"] == pytest.approx([0.02, 0.1, 1.0])
    assert res.json["axes"]["x"]["adev_dps"] == pytest.approx(res.json["axes"]["z"]["adev_dps"], rel=1e-6)
    assert res.tables[0].rows[0][0] == "x" and len(res.tables[2].rows) == 3


def test_detect_lsb():
    rng = np.random.default_rng(0)
    lsb = 250.0 / 32768  # 16-bit register at ±250 deg/s
    register = np.round((0.37 + rng.standard_normal(50_000) * 0.022) / lsb).astype(np.int16)
    assert detect_lsb(register * lsb) == lsb  # the step exactly
    assert detect_lsb(np.tile(np.arange(-50, 50), 3) * 0.0076) == pytest.approx(0.0076, rel=1e-9)
    assert detect_lsb(rng.standard_normal(1000)) is None
    assert detect_lsb(np.full(100, 0.5)) is None
    assert detect_lsb(np.arange(-50, 50) * 0.0076) is None  # every value distinct: not "few levels"


def test_detect_lsb_float_data_is_not_quantised():
    """S5-like phone output: float32 rad/s converted to deg/s, ~200 000 distinct values whose smallest
    gap is float resolution (1e-16 deg/s): not an output step (the old detector returned 1.1e-16 and
    the notes printed a 300-digit percentage)."""
    rng = np.random.default_rng(1)
    rate = np.degrees(rng.standard_normal(200_000) * 0.004 - 0.015)
    rate[1] = np.nextafter(rate[0], np.inf)  # two readings one float step apart, as in the S5 log
    u = np.unique(rate)
    assert u.size > 100_000 and np.diff(u).min() < 1e-15
    assert detect_lsb(rate) is None
    res = calibrate(make_ds(rate, 10.0))
    assert res.json["axes"]["x"]["lsb_dps"] is None
    assert not any("output resolution" in n or "quantised" in n for n in res.notes)
    assert all(len(n) < 2000 for n in res.notes)


def test_octave_m():
    np.testing.assert_array_equal(octave_m(3), [1])
    np.testing.assert_array_equal(octave_m(64), [1, 2, 4, 8, 16])


# ---- moving average (ESTCube-2 3.3) ------------------------------------------------------------
def test_moving_average_white_noise_follows_inverse_sqrt_n():
    rng = np.random.default_rng(22)
    sigma = 0.02
    res = calibrate_moving_average(make_ds(0.1 + rng.standard_normal(100_000) * sigma, 100.0))
    x = res.json["axes"]["x"]
    assert x["n"] == list(DEFAULT_BUFFER_LENGTHS)
    n = np.array(x["n"], dtype=float)
    np.testing.assert_allclose(x["std_dps"], sigma / np.sqrt(n), rtol=0.04)
    np.testing.assert_allclose(x["white_noise_std_dps"], x["std_dps"][0] / np.sqrt(n), rtol=1e-12)
    assert res.method == "moving-average" and not any("above the white-noise line" in m for m in res.notes)
    json.dumps(res.json, allow_nan=False)


def test_moving_average_flattens_with_drift():
    rng = np.random.default_rng(23)
    n = 20_000
    rate = rng.standard_normal(n) * 0.02 + np.cumsum(rng.standard_normal(n)) * 2e-4
    res = calibrate_moving_average(make_ds(rate, 100.0), buffer_lengths=(1, 10, 100, 1000, 50_000))
    x = res.json["axes"]["x"]
    assert x["n"] == [1, 10, 100, 1000]  # 50 000 exceeds the record
    assert x["std_dps"][3] > 1.5 * x["white_noise_std_dps"][3]
    assert any("exceed the 20000-sample" in m for m in res.notes)
    assert any("above the white-noise line" in m for m in res.notes)


# ---- run files (simulated lab) -------------------------------------------------------------------
def _sim_run(tmp_path, procedure: str, *params: str):
    from tests.conftest import ROOT, SIM_CONFIG, run_cli

    runs = tmp_path / "runs"
    args = ["run", str(ROOT / "procedures" / procedure), "--config", str(SIM_CONFIG), "--sim", "--runs-dir", str(runs)]
    for p in params:
        args += ["-p", p]
    r = run_cli(*args)
    assert r.returncode == 0, r.stdout + r.stderr
    (path,) = runs.glob("*.h5")
    return path


def test_allan_static_run_uses_static_window(tmp_path):
    from bench.analysis.dataset import load_dataset

    ds = load_dataset(_sim_run(tmp_path, "allan_static.yaml", "warmup=10 s", "duration=100 s"))
    res = calibrate(ds)
    assert res.json["static_samples"] == 10_000  # the 10-s warm-up window is left out
    assert res.json["static_t_s"][0] == pytest.approx(10.01)
    assert any("recording window 'static'" in n for n in res.notes)
    # simulator: 0.005 deg/s/√Hz through a 12.5-Hz low-pass, white, 16-bit output -> N = 0.0222/√100 deg/√s
    for a in "xyz":
        ax = res.json["axes"][a]
        assert ax["arw_deg_per_sqrt_h"] == pytest.approx(0.005 * math.sqrt(math.pi / 2 * 12.5) / 10 * 60, rel=0.10)
        assert ax["lsb_dps"] == pytest.approx(250.0 / 32768, rel=1e-9)
    assert calibrate(ds, window="all").json["static_samples"] == 11_000
    with pytest.raises(InputError, match="no recording window 'hot'.*warmup, static"):
        calibrate(ds, window="hot")


def test_moving_average_sweep_run_uses_board_windows(tmp_path):
    from bench.analysis.dataset import load_dataset

    ds = load_dataset(_sim_run(tmp_path, "moving_average_sweep.yaml", "n_max=4"))
    res = calibrate_moving_average(ds)
    x = res.json["axes"]["x"]
    assert res.json["mode"] == "board" and x["n"] == [1, 2, 3, 4]
    assert all(c >= 2000 for c in x["outputs"])
    np.testing.assert_allclose(x["std_dps"], x["std_dps"][0] / np.sqrt([1, 2, 3, 4]), rtol=0.10)
    assert calibrate_moving_average(ds, window="all").json["mode"] == "software"
    assert any("moving average between" in n for n in calibrate(ds).notes)
