"""Hidden effects for the diagnose tests, written from the source documents independently of
``bench/model/effects.py`` (whose forward functions the engine builds its candidates from), and the
real noise backgrounds they are hidden in.

Each shape is the document's equation coded here again, in other numerics where it has some: the
first-order lag and the thermal lag by an explicit exact-discretisation loop (not ``lfilter``), the
hysteresis play operator by its own loop, the time skew by linear (not cubic-spline) interpolation,
the pressure transition in log-pressure form. A test that hides these shows that the search finds
the physics, not its own functions.

Sources: NPSAT1 thesis IV.A (warm-up A·e^(−t/τ)), IV.B.3 (die temperature lagging the thermocouple),
IV.C (up/down ramp offsets), V and Table 6 (vacuum bias shift); ESTCube-2 thesis 4.3 (worm-gear
period in the table angle); IEEE Std 1431 (scale-factor asymmetry and nonlinearity); IEEE Std 952
(bias shifts, g-sensitivity).

Backgrounds (:func:`background`): the real gyro noise of the S5 phone (10-sample means: 1 Hz) and of
the CATS tag (1 Hz) at rest, handling left out, each axis' mean removed: a generated session's
white noise is replaced by a stretch of it (its place drawn from the test's seed).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

S5_MAP = ["gyro=angular_velocity[3:6]:rad/s", "accel=acceleration:m/s2"]
CATS_MAP = ["gyro=angular_velocity:mrad/s", "accel=acceleration:m/s2", "temp=temperature:degC"]


# ---- shapes from the documents ---------------------------------------------------------------------
def first_order_lag(t: np.ndarray, x: np.ndarray, tau_s: float) -> np.ndarray:
    """dy/dt = (x − y)/τ, x held between samples, y(0) = x(0): exact step by step (a loop)."""
    y = np.empty_like(x, dtype=float)
    y[0] = x[0]
    for i in range(1, x.size):
        a = math.exp(-(t[i] - t[i - 1]) / tau_s)
        y[i] = a * y[i - 1] + (1.0 - a) * x[i - 1]
    return y


def play_operator(temp: np.ndarray, deadband_c: float) -> np.ndarray:
    """+1 after the temperature rose by more than the deadband from its lowest point since it last
    fell, −1 after it fell by more than the deadband from its highest point since it last rose, 0
    before the first such move (NPSAT1 IV.C: different offsets on up and down ramps)."""
    out = np.zeros(temp.size)
    state, hi, lo = 0, float(temp[0]), float(temp[0])
    for i, v in enumerate(temp):
        v = float(v)
        hi, lo = max(hi, v), min(lo, v)
        if state != 1 and v - lo > deadband_c:
            state, hi = 1, v
        elif state != -1 and hi - v > deadband_c:
            state, lo = -1, v
        out[i] = state
    return out


def shape(name: str, inp, k: int, p: dict) -> np.ndarray:
    """Contribution (deg/s) of effect ``name`` with parameters ``p`` to sensor axis ``k`` of the
    session inputs ``inp`` (``bench.sessions.SessionInputs``)."""
    t = inp.time_s
    w = inp.rate_dps[:, k]
    if name == "warmup_transient":
        return p["amplitude_dps"] * np.exp(-inp.power_on_s / p["tau_s"])
    if name == "pressure_bias":  # full shift in vacuum, none at ambient, the transition at p0 (decades)
        x = np.log10(np.maximum(inp.pressure_torr, 1e-12)) - math.log10(p["p0_torr"])
        return p["shift_dps"] / (1.0 + 10.0 ** x)
    if name == "thermal_lag":
        c = p["tempco_dps"]
        bias = lambda temp: sum(ci * (temp - 25.0) ** (j + 1) for j, ci in enumerate(c))  # noqa: E731
        return bias(first_order_lag(t, inp.temp_c, p["tau_s"])) - bias(inp.temp_c)
    if name == "hysteresis":
        return p["amplitude_dps"] * play_operator(inp.temp_c, p["deadband_c"])
    if name == "gear_eccentricity":
        return p["fraction"] * np.sin(p["harmonic"] * np.radians(inp.table_angle_deg) + p["phase_rad"]) * w
    if name == "g_sensitivity":
        return inp.specific_force_g @ np.asarray(p["dps_per_g"], float)
    if name == "scale_factor_asymmetry":
        return p["asymmetry"] * np.abs(w)
    if name == "scale_factor_tempco":
        return p["tempco_per_c"] * (inp.temp_c - 25.0) * w
    if name == "scale_factor_nonlinearity":
        return p["quadratic_per_dps"] * w * w
    if name == "time_skew":  # the gyro sample at t shows the rate at t − d (linear interpolation)
        return np.interp(t - p["delay_s"], t, w) - w
    if name == "bias_step":
        return np.where(t >= p["t_step_s"], p["step_dps"], 0.0)
    if name == "periodic":
        return p["amplitude_dps"] * np.sin(2.0 * math.pi * p["frequency_hz"] * t + p["phase_rad"])
    raise KeyError(name)


INDEPENDENT = ("warmup_transient", "pressure_bias", "thermal_lag", "hysteresis", "gear_eccentricity", "g_sensitivity",
               "scale_factor_asymmetry", "scale_factor_tempco", "scale_factor_nonlinearity", "time_skew", "bias_step",
               "periodic")
"""Effects with a shape written here (the noise terms and the Earth rate come from the generator)."""

SHAPE_LEFTOVER = {"time_skew": "rate_derivative"}
"""Shapes here that carry more than their term -> the probe that must find the rest. The time skew is a
linear interpolation between samples: a delay plus the interpolation's own smoothing,
½·δ(1 − δ)·Δ²·ω'' at a delay δ·Δ (at 1 Hz and δ = 0.1, 0.045 s²·ω''), which no term names: it must be
unexplained against the rate's derivatives (``docs/diagnose.md``), with no other name."""


def shape_leftover(names: list[str], unexplained: list[dict]) -> list[dict]:
    """The entries of a diagnose result's ``unexplained`` that are the documented rest of the shapes
    ``names`` (:data:`SHAPE_LEFTOVER`): those whose best probe is that shape's."""
    probes = {SHAPE_LEFTOVER[n] for n in names if n in SHAPE_LEFTOVER}
    return [u for u in unexplained if u["where"] and u["where"][0]["probe"] in probes]


def extra(entries: list[dict], background_noise: np.ndarray | None = None):
    """An ``extra(inputs) -> (n, 3)`` for :func:`bench.sessions.make_session`: the entries' shapes
    (this module) plus a real noise background (n, 3) when given."""
    def add(inp):
        out = np.zeros((inp.time_s.size, 3))
        for e in entries:
            axes = [0, 1, 2] if e["axis"] == "all" else ["xyz".index(e["axis"])]
            for k in axes:
                out[:, k] += shape(e["effect"], inp, k, e["params"])
        if background_noise is not None:
            out += background_noise
        return out
    return add


# ---- real backgrounds ------------------------------------------------------------------------------
@lru_cache(maxsize=2)
def _log(name: str):
    from bench.analysis.dataset import load_dataset
    from tests.realdata import real_log

    mapping = S5_MAP if name == "s5" else CATS_MAP
    return load_dataset(real_log("samsung_galaxy_s5.nc" if name == "s5" else "cats_temperature_calib.nc"), mapping=mapping)


def static_datasets(name: str) -> list:
    """Every static stretch of the real log (at least an hour) as a Dataset of its own rows, every
    channel it has (the CATS tag's temperature too), time from 0."""
    from bench.analysis.dataset import Dataset
    from bench.analysis.diagnose.data import motion_rows

    ds = _log(name)
    t = ds["time_s"]
    fs = 1.0 / float(np.median(np.diff(t)))
    moving = motion_rows(t, [ds[f"gyro_{a}_dps"] for a in "xyz"], [ds[f"accel_{a}_g"] for a in "xyz"], fs)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], (~moving).astype(np.int8), [0]])))
    out = []
    for lo, hi in zip(edges[::2], edges[1::2]):
        if (hi - lo) / fs >= 3600:
            sub = ds.select(np.arange(lo, hi))
            sub.columns["time_s"] = sub.columns["time_s"] - sub.columns["time_s"][0]
            out.append(Dataset(sub.columns, dict(ds.meta), f"{ds.source} static rows {lo}-{hi}"))
    return out


SETTLE_S = 3600
"""A background starts at least this long after the unit was last handled: the first hour of a
static stretch carries its settling (on the CATS tag a decaying 0.13 deg/s transient on one axis and
the cooling after it was put back in the chamber), a transient, not the sensor's noise."""
STEADY_C = 0.5
"""... and, on a log with a temperature channel, its temperature moves by less than this (°C) over the
background's length. The CATS log is a temperature calibration: its bias follows the temperature
(0.3 deg/s on one axis over one stretch), which a background must not carry as 'noise'."""


@lru_cache(maxsize=2)
def _stretches(name: str) -> tuple[tuple[np.ndarray, np.ndarray | None], ...]:
    """The real log's gyro at rest (deg/s, 1 Hz), one (n, 3) array per static stretch, mean removed,
    with its 1-Hz temperature (None without a temperature channel)."""
    from bench.analysis.diagnose.data import motion_rows

    ds = _log(name)
    t = ds["time_s"]
    g = np.stack([ds[f"gyro_{a}_dps"] for a in "xyz"], axis=1)
    temp = ds.columns.get("temp_c")
    fs = 1.0 / float(np.median(np.diff(t)))
    moving = motion_rows(t, list(g.T), [ds[f"accel_{a}_g"] for a in "xyz"], fs)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], (~moving).astype(np.int8), [0]])))
    out = []
    for lo, hi in zip(edges[::2], edges[1::2]):
        m = int(round(fs))  # 1-Hz means
        rows = ((hi - lo) // m) * m
        part = g[lo:lo + rows].reshape(-1, m, 3).mean(axis=1)
        tc = None if temp is None else np.asarray(temp[lo:lo + rows], float).reshape(-1, m).mean(axis=1)
        if part.shape[0] >= 3600:
            out.append((part - part.mean(axis=0), tc))
    return tuple(out)


def static_stretches(name: str) -> tuple[np.ndarray, ...]:
    """Every static stretch of the real log ``"s5"`` or ``"cats"`` at 1 Hz (at least an hour each)."""
    return tuple(g for g, _ in _stretches(name))


def _quiet_starts(name: str, n: int) -> list[tuple[int, np.ndarray]]:
    """(stretch index, the starts of the ``n``-row windows at rest: :data:`SETTLE_S` after the
    handling, temperature within :data:`STEADY_C`) per stretch that has any."""
    out = []
    for i, (g, tc) in enumerate(_stretches(name)):
        starts = np.arange(SETTLE_S, g.shape[0] - n + 1)
        if tc is not None and starts.size:
            from numpy.lib.stride_tricks import sliding_window_view

            # row j: the window that starts at SETTLE_S + j (a view; indexing it with ``starts`` copied
            # every window: 11.6 s and GBs on the CATS log, 0.15 s so, the same starts)
            win = sliding_window_view(tc[SETTLE_S:], n)
            starts = starts[np.ptp(win, axis=1) < STEADY_C]
        if starts.size:
            out.append((i, starts))
    return out


def background(name: str, n: int, seed: int) -> np.ndarray:
    """``n`` consecutive 1-Hz rows (n, 3) of a static stretch of the real log, at rest (:func:`_quiet_starts`),
    at a place drawn from ``seed``; the axes shuffled too, so one log gives several backgrounds."""
    rng = np.random.default_rng([seed, 7])
    quiet = _quiet_starts(name, n)
    i, starts = quiet[int(rng.integers(len(quiet)))]
    start = int(starts[int(rng.integers(starts.size))])
    piece = _stretches(name)[i][0][start:start + n][:, rng.permutation(3)]
    return piece - piece.mean(axis=0)


BAND_S = 30
"""Block length (s) of the band the scale of the hidden effects is set on (diagnose's shortest band)."""


def band_rms(name: str) -> float:
    """RMS (deg/s) of the background's 30-s means after removing each hour's mean (the noise a slow
    effect stands against), median over the axes, over disjoint hours at rest (:func:`_quiet_starts`)."""
    out = []
    for i, starts in _quiet_starts(name, 3600):
        g = _stretches(name)[i][0]
        last = -3600
        for start in starts:
            if start < last + 3600:
                continue
            last = int(start)
            part = g[start:start + 3600]
            means = part.reshape(-1, BAND_S, 3).mean(axis=1)
            out.append(np.sqrt(np.mean((means - means.mean(axis=0)) ** 2, axis=0)))
    return float(np.median(np.concatenate(out)))


def scale_against(name: str, white_dps: float = 0.011) -> float:
    """How many times the background's band noise exceeds that of the white noise the test ranges are
    made for (0.011 deg/s per sample at 1 Hz): the hidden effects are scaled by it (at least 1)."""
    return max(1.0, band_rms(name) / (white_dps / math.sqrt(BAND_S)))
