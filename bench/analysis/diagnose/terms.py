"""Candidate causes as regressors: for each vocabulary term, which data it needs, where it can be
seen, its grid of nonlinear parameters and its design columns (or fixed offsets) for given ones.

The columns are built with the same helpers as the forward model (``bench/model/effects.py``), so
a fitted term re-simulated is the same function. Coefficients of the columns are the physical
parameters (deg/s, deg/s per °C^k, fraction, deg/s/g) when the columns are unscaled.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from bench.analysis.diagnose.data import Prepared
from bench.model import effects as fx
from bench.model.effects import T_REF_C

AXES = ("x", "y", "z")


@dataclass
class Built:
    """A term's regressors for one choice of its nonlinear parameters.

    ``cols``: axis → (n, q) raw columns with free coefficients; ``offsets``: axis → (n,) fixed
    contribution (no coefficient); ``penalty``: axis → (q, q) quadratic penalty on the raw
    coefficients, in SSE units (deg/s)²."""

    cols: dict[str, np.ndarray] = field(default_factory=dict)
    offsets: dict[str, np.ndarray] = field(default_factory=dict)
    penalty: dict[str, np.ndarray] = field(default_factory=dict)
    relag: dict[str, float] = field(default_factory=dict)
    """axis → τ (s): the baseline's temperature cubic is evaluated at temp_c lagged by τ instead."""

    @property
    def axes(self) -> list[str]:
        return sorted(set(self.cols) | set(self.offsets) | set(self.relag), key=AXES.index)


@dataclass
class Context:
    """What some candidates need from the current model: residual and its variance per axis."""

    resid: dict[str, np.ndarray]
    sigma2: dict[str, float]


class Candidate(ABC):
    """Base class of a vocabulary term as a candidate cause."""

    name: str = ""
    shared: bool = False
    """One parameter set for all axes (earth_rate, time_skew): candidate axis "all"."""
    nonlinear: tuple[str, ...] = ()
    """Names of the grid-searched parameters (each counts as one parameter in the criterion)."""
    refine: tuple[tuple[str, bool], ...] = ()
    """Continuous nonlinear parameters refined after the grid: (name, log-scale)."""
    select_by_cv: bool = False
    """Choose the grid value by held-out error (penalised terms) instead of nested training error."""
    resolved: tuple[str, ...] = ()
    """Nonlinear parameters that must come out below the top of their grid: a transient whose time
    constant is as long as the data allow is a drift, not an identified transient."""
    family: str | None = None
    """The generic probe that can imitate this term, a key of :data:`FAMILY_PROBE`: ``"time"`` for
    slow terms, ``"rate"`` for static functions of the rate, ``"specific_force"``, ``"spectrum"``,
    ``"angle_rate"``. A term whose family's probe still finds structure after selection must be
    needed on top of that probe, or it is only a partial explanation (``docs/diagnose.md``)."""
    noise_term: bool = False
    """Named from the Allan deviation of the residual (a random process), not fitted as a regressor."""

    def refine_interval(self, p: Prepared, name: str, value: float) -> tuple[float, float] | None:
        """Bounds for refining nonlinear parameter ``name`` around ``value`` (None: between the
        neighbouring grid values)."""
        return None

    def missing(self, p: Prepared) -> list[str]:
        """Columns or metadata this term needs that the data lack."""
        return []

    def candidate_axes(self, p: Prepared) -> list[str]:
        return ["all"] if self.shared else list(p.axes)

    def not_excited(self, p: Prepared, axis: str) -> str | None:
        """Why the data cannot show this term on ``axis`` (None: it can)."""
        return None

    def grid(self, p: Prepared, axis: str, ctx: Context) -> list[dict[str, Any]]:
        return [{}]

    @abstractmethod
    def build(self, p: Prepared, axis: str, nl: dict[str, Any], ctx: Context) -> Built:
        """The term's design columns on ``axis`` for nonlinear values ``nl``."""

    @abstractmethod
    def params(self, p: Prepared, axis: str, nl: dict[str, Any], coef: dict[str, np.ndarray]) -> dict[str, Any]:
        """Physical parameters (the effect's ``params``) from nonlinear values and raw coefficients."""

    def describe(self, params: dict[str, Any]) -> str:
        """A short phrase for the summary line."""
        return ", ".join(f"{k} {_g(v)}" for k, v in params.items())


def _g(v: Any, d: int = 2) -> str:
    if isinstance(v, float):
        return f"{v:.{d}g}"
    if isinstance(v, list):
        return "[" + ", ".join(_g(x, d) for x in v) + "]"
    return str(v)


COLUMN_CACHE = 96
"""Most candidate columns kept between evaluations (least recently used dropped): bounds memory
at ~96 columns of n rows while the grids are revisited every round."""


def _cached(p: Prepared, key: tuple, fn: Callable[[], Any]) -> Any:
    from collections import OrderedDict

    lru = p.cache.setdefault("columns", OrderedDict())
    if key in lru:
        lru.move_to_end(key)
        return lru[key]
    value = fn()
    lru[key] = value
    if len(lru) > COLUMN_CACHE:
        for k in list(lru):
            if k not in (("rrw_basis",), ("earth",)) and not (isinstance(k, tuple) and k and k[0] == "ref_spline"):
                del lru[k]
                break
    return value


def _temp_range(p: Prepared) -> float:
    return 0.0 if p.temp is None else float(np.ptp(p.temp))


# ---- the vocabulary ----------------------------------------------------------------------------
class ThermalLag(Candidate):
    """The die temperature lags ``temp_c``: the baseline cubic is evaluated at the lagged
    temperature (one parameter, τ); its coefficients become the effect's ``tempco_dps``."""

    name = "thermal_lag"
    family = "time"
    nonlinear = ("tau_s",)
    refine = (("tau_s", True),)

    def missing(self, p):
        return [] if p.temp is not None else ["temp_c"]

    def not_excited(self, p, axis):
        if _temp_range(p) < 2.0:
            return "temperature varies by less than 2 °C"
        return None

    def grid(self, p, axis, ctx):
        hi = min(3000.0, p.duration_s / 3)
        lo = max(10.0, 3.0 / p.fs)
        return [{"tau_s": float(v)} for v in np.geomspace(lo, max(hi, 2 * lo), 11)]

    def build(self, p, axis, nl, ctx):
        return Built(relag={axis: float(nl["tau_s"])})

    def params(self, p, axis, nl, coef):
        return {"tau_s": float(nl["tau_s"]), "tempco_dps": [float(c) for c in coef[axis]]}

    def describe(self, params):
        c = params["tempco_dps"][0]
        return f"die temperature lags temp_c by tau = {params['tau_s']:.0f} s (bias slope {c:+.2g} deg/s/°C at 25 °C)"


def lagged_temp(p: Prepared, tau_s: float | None) -> np.ndarray:
    """temp_c, or temp_c through the first-order lag τ (cached), °C."""
    if not tau_s:
        return p.temp
    return _cached(p, ("lag", round(float(tau_s), 6)), lambda: fx.lagged(p.t, p.temp, float(tau_s)))


class WarmupTransient(Candidate):
    name = "warmup_transient"
    family = "time"
    nonlinear = ("tau_s",)
    refine = (("tau_s", True),)
    resolved = ("tau_s",)

    def missing(self, p):
        return [] if p.power_on is not None else ["power_on_s, or its time with --power-on-at TIME or # power_on_at_s"]

    def not_excited(self, p, axis):
        if float(np.min(p.power_on)) > 600.0 and not np.any(np.diff(p.power_on) < 0):
            return "no data within 10 min of a power-on"
        return None

    def grid(self, p, axis, ctx):
        hi = min(3600.0, p.duration_s / 3)
        lo = max(10.0, 3.0 / p.fs)
        return [{"tau_s": float(v)} for v in np.geomspace(lo, max(hi, 2 * lo), 14)]

    def build(self, p, axis, nl, ctx):
        col = _cached(p, ("warm", round(nl["tau_s"], 6)), lambda: np.exp(-np.clip(p.power_on, 0, None) / nl["tau_s"])[:, None])
        return Built(cols={axis: col})

    def params(self, p, axis, nl, coef):
        return {"amplitude_dps": float(coef[axis][0]), "tau_s": float(nl["tau_s"])}

    def describe(self, params):
        return f"{params['amplitude_dps']:+.2g} deg/s at power-on decaying with tau = {params['tau_s']:.0f} s"


class PressureBias(Candidate):
    name = "pressure_bias"
    family = "time"
    nonlinear = ("p0_torr",)
    refine = (("p0_torr", True),)

    def missing(self, p):
        return [] if p.pressure is not None else ["pressure_torr"]

    def not_excited(self, p, axis):
        lp = np.log10(p.pressure)
        if np.ptp(lp) < 1.5:
            return "pressure spans less than 1.5 decades"
        return None

    def grid(self, p, axis, ctx):
        lp = np.log10(p.pressure)
        lo, hi = float(lp.min()), float(lp.max())
        return [{"p0_torr": float(10 ** v)} for v in np.arange(math.floor(lo * 2) / 2, hi + 1e-9, 0.5)]

    def build(self, p, axis, nl, ctx):
        slope = float(nl.get("slope", 1.0))
        col = _cached(p, ("press", round(math.log10(nl["p0_torr"]), 6), slope),
                      lambda: fx.pressure_transition(p.pressure, nl["p0_torr"], slope)[:, None])
        return Built(cols={axis: col})

    def params(self, p, axis, nl, coef):
        return {"shift_dps": float(coef[axis][0]), "p0_torr": float(nl["p0_torr"]), "slope": float(nl.get("slope", 1.0))}

    def describe(self, params):
        return f"{params['shift_dps']:+.2g} deg/s below ~{params['p0_torr']:.1g} Torr"


class GearEccentricity(Candidate):
    name = "gear_eccentricity"
    family = "spectrum"
    nonlinear = ("harmonic", "phase_rad")
    N_MAX = 360
    SHORTLIST = 6

    def missing(self, p):
        out = [] if p.angle is not None else ["table_angle_deg"]
        return out + ([] if p.ref is not None else ["ref_rate_*_dps"])

    def candidate_axes(self, p):
        return [a for a in p.axes if p.rate_excited(a)]

    def not_excited(self, p, axis):
        if float(np.ptp(np.unwrap(np.radians(p.angle)))) < 2 * math.pi:
            return "the table turns less than one revolution"
        return None

    def spectrum(self, p: Prepared, axis: str, resid: np.ndarray, n_max: int | None = None) -> np.ndarray:
        """Least-squares power (SSE reduction, (deg/s)²) of r on ω·sin(Nθ), ω·cos(Nθ) for N = 1..N_max."""
        n_max = n_max or self.N_MAX
        w = p.ref_axis(axis)
        z = np.exp(1j * np.radians(p.angle))
        e = np.ones_like(z)
        rw = resid * w
        w2 = w * w
        s0 = float(w2.sum())
        out = np.zeros(n_max)
        for k in range(n_max):
            e = e * z
            hc = complex(np.dot(rw, e))  # Σ rω cos + i Σ rω sin
            g2 = complex(np.dot(w2, e * e))  # Σ ω² cos2 + i Σ ω² sin2
            gss = 0.5 * (s0 - g2.real)
            gcc = 0.5 * (s0 + g2.real)
            gsc = 0.5 * g2.imag
            hs, hcos = hc.imag, hc.real
            det = gss * gcc - gsc * gsc
            if det <= 1e-12 * s0 * s0:
                continue
            out[k] = (gcc * hs * hs - 2 * gsc * hs * hcos + gss * hcos * hcos) / det
        return out

    def grid(self, p, axis, ctx):
        spec = per_residual(p, "gear_spectrum", axis, ctx.resid[axis], lambda r: self.spectrum(p, axis, r))
        top = np.argsort(spec)[::-1][: self.SHORTLIST] + 1
        return [{"harmonic": int(N)} for N in top]

    def build(self, p, axis, nl, ctx):
        th = np.radians(p.angle) * nl["harmonic"]
        w = p.ref_axis(axis)
        return Built(cols={axis: np.column_stack([w * np.sin(th), w * np.cos(th)])})

    def params(self, p, axis, nl, coef):
        a, b = (float(v) for v in coef[axis])
        return {"fraction": math.hypot(a, b), "harmonic": int(nl["harmonic"]), "phase_rad": math.atan2(b, a)}

    def describe(self, params):
        return (f"{100 * params['fraction']:.2g} % of the table rate, periodic in table angle at harmonic "
                f"N = {params['harmonic']}")


class GSensitivity(Candidate):
    name = "g_sensitivity"
    family = "specific_force"

    def missing(self, p):
        return [] if p.accel is not None else ["accel_*_g"]

    def not_excited(self, p, axis):
        if float(np.max(np.std(p.accel, axis=0))) < 0.02:
            return "specific force does not turn in the sensor frame"
        if distinct_directions(p.accel) < 4:
            return ("the specific force takes fewer than 4 distinct directions: a g-sensitivity (3 coefficients and "
                    "the bias) cannot be told from a bias that shifts between orientations")
        return None

    def build(self, p, axis, nl, ctx):
        return Built(cols={axis: p.accel})

    def params(self, p, axis, nl, coef):
        return {"dps_per_g": [float(c) for c in coef[axis]]}

    def describe(self, params):
        g = params["dps_per_g"]
        return f"{math.sqrt(sum(v * v for v in g)):.2g} deg/s per g (x {g[0]:+.2g}, y {g[1]:+.2g}, z {g[2]:+.2g})"


def distinct_directions(accel: np.ndarray, step: float = 0.3, share: float = 0.005) -> int:
    """Number of specific-force directions (unit vectors rounded to ``step``) held by at least
    ``share`` of the rows: the orientations a g-sensitivity is learnt from."""
    u = accel / np.maximum(np.linalg.norm(accel, axis=1, keepdims=True), 1e-9)
    _, counts = np.unique(np.round(u / step).astype(np.int64), axis=0, return_counts=True)
    return int(np.count_nonzero(counts >= share * accel.shape[0]))


class ScaleFactorAsymmetry(Candidate):
    name = "scale_factor_asymmetry"
    family = "rate"

    def missing(self, p):
        return [] if p.ref is not None else ["ref_rate_*_dps"]

    def candidate_axes(self, p):
        return [a for a in p.axes if p.rate_excited(a)]

    def not_excited(self, p, axis):
        r = p.ref_axis(axis)
        if not (np.any(r > RATE_SIGN_DPS) and np.any(r < -RATE_SIGN_DPS)):
            return "rates of one sign only"
        return None

    def build(self, p, axis, nl, ctx):
        return Built(cols={axis: np.abs(p.ref_axis(axis))[:, None]})

    def params(self, p, axis, nl, coef):
        return {"asymmetry": float(coef[axis][0])}

    def describe(self, params):
        a = params["asymmetry"]
        return f"scale factor {100 * a:+.2g} % for positive, {-100 * a:+.2g} % for negative rates"


RATE_SIGN_DPS = 0.05


class ScaleFactorTempco(Candidate):
    name = "scale_factor_tempco"
    family = "rate_scale"

    def missing(self, p):
        out = [] if p.ref is not None else ["ref_rate_*_dps"]
        return out + ([] if p.temp is not None else ["temp_c"])

    def candidate_axes(self, p):
        return [a for a in p.axes if p.rate_excited(a)]

    def not_excited(self, p, axis):
        return "temperature varies by less than 3 °C" if _temp_range(p) < 3.0 else None

    def build(self, p, axis, nl, ctx):
        return Built(cols={axis: ((p.temp - T_REF_C) * p.ref_axis(axis))[:, None]})

    def params(self, p, axis, nl, coef):
        return {"tempco_per_c": float(coef[axis][0]), "t_ref_c": T_REF_C}

    def describe(self, params):
        return f"scale factor {1e6 * params['tempco_per_c']:+.3g} ppm/°C"


class Hysteresis(Candidate):
    name = "hysteresis"
    family = "time"
    nonlinear = ("deadband_c",)
    refine = (("deadband_c", True),)
    DEADBANDS = tuple(float(v) for v in np.geomspace(0.1, 3.0, 11))

    def missing(self, p):
        return [] if p.temp is not None else ["temp_c"]

    def not_excited(self, p, axis):
        s = fx.hysteresis_state(p.temp, 0.5)
        if not (np.any(s > 0) and np.any(s < 0)):
            return "the temperature never reverses"
        return None

    def grid(self, p, axis, ctx):
        return [{"deadband_c": d} for d in self.DEADBANDS if d < _temp_range(p) / 4]

    def build(self, p, axis, nl, ctx):
        col = _cached(p, ("hyst", round(nl["deadband_c"], 9)), lambda: fx.hysteresis_state(p.temp, nl["deadband_c"])[:, None])
        return Built(cols={axis: col})

    def params(self, p, axis, nl, coef):
        return {"amplitude_dps": float(coef[axis][0]), "deadband_c": float(nl["deadband_c"])}

    def describe(self, params):
        return (f"±{abs(params['amplitude_dps']):.2g} deg/s by temperature direction "
                f"({'+' if params['amplitude_dps'] >= 0 else '-'} when rising, deadband {params['deadband_c']:g} °C)")


class TimeSkew(Candidate):
    name = "time_skew"
    shared = True
    nonlinear = ("delay_s",)
    refine = (("delay_s", False),)

    def missing(self, p):
        return [] if p.ref is not None else ["ref_rate_*_dps"]

    def not_excited(self, p, axis):
        if p.ref is None or float(np.max(np.abs(np.diff(p.ref, axis=0)))) < 1e-6:
            return "the reference rate never changes"
        return None

    def grid(self, p, axis, ctx):
        span = max(1.0, 2.0 / p.fs)
        mags = np.geomspace(min(2e-3, 0.02 / p.fs), span, 14)
        return [{"delay_s": float(d)} for d in np.concatenate([-mags[::-1], mags])]

    def build(self, p, axis, nl, ctx):
        from scipy.interpolate import CubicSpline

        d = nl["delay_s"]
        off = {}
        tq = np.clip(p.t - d, p.t[0], p.t[-1])
        for a in p.axes:
            r = p.ref_axis(a)
            if np.ptp(r) > 0:
                spline = _cached(p, ("ref_spline", a), lambda: CubicSpline(p.t, r))  # as fx.delayed
                off[a] = spline(tq) - r
        return Built(offsets=off)

    def params(self, p, axis, nl, coef):
        return {"delay_s": float(nl["delay_s"])}

    def describe(self, params):
        d = params["delay_s"]
        return f"gyro samples {1e3 * abs(d):.3g} ms {'late' if d > 0 else 'early'} against the reference"


class RateRandomWalk(Candidate):
    """A random walk of the bias: a linear spline with the random-walk prior as a penalty. The search
    takes it as the catch-all of slow structure (named causes get their second chance against it);
    it never keeps the name: noise terms are named by the noise model (``noise.py``)."""

    name = "rate_random_walk"
    nonlinear = ("k_dps_per_sqrt_s",)
    select_by_cv = True
    KNOTS = 100
    K_GRID = tuple(float(v) for v in np.geomspace(3e-6, 1e-3, 11))

    def grid(self, p, axis, ctx):
        return [{"k_dps_per_sqrt_s": k} for k in self.K_GRID]

    def knots(self, p: Prepared) -> np.ndarray:
        n_k = int(min(self.KNOTS, max(p.duration_s / max(p.blocks.length / p.fs, 1.0), 4)))
        return np.linspace(p.t[0], p.t[-1], n_k + 1)

    def basis(self, p: Prepared):
        """The linear-spline basis over the knots (sparse: two non-zeros per row)."""
        from bench.analysis.diagnose.cv import SparseHat

        def hats():
            kn = self.knots(p)
            j = np.clip(np.searchsorted(kn, p.t, side="right") - 1, 0, kn.size - 2)
            w = (p.t - kn[j]) / (kn[j + 1] - kn[j])
            return SparseHat(j, 1.0 - w, w, kn.size)
        return _cached(p, ("rrw_basis",), hats)

    def build(self, p, axis, nl, ctx):
        hat = self.basis(p)
        kn = self.knots(p)
        delta = float(kn[1] - kn[0])
        k = nl["k_dps_per_sqrt_s"]
        lam = ctx.sigma2[axis] / (k * k * delta)
        d = np.diff(np.eye(hat.shape[1]), axis=0)
        return Built(cols={axis: hat}, penalty={axis: lam * (d.T @ d)})

    def params(self, p, axis, nl, coef):
        return {"k_dps_per_sqrt_s": float(nl["k_dps_per_sqrt_s"])}

    def describe(self, params):
        return f"bias random walk {params['k_dps_per_sqrt_s']:.2g} deg/s/√s"


class EarthRate(Candidate):
    name = "earth_rate"
    shared = True

    def missing(self, p):
        out = []
        if p.latitude is None:
            out.append("latitude_deg (header or run file)")
        if p.accel is None:
            out.append("accel_*_g")
        if p.angle is None and p.table_axis is not None:
            out.append("table_angle_deg")
        return out

    def build(self, p, axis, nl, ctx):
        e = _cached(p, ("earth",), lambda: fx.earth_rate_sensor(p.accel, p.angle, p.latitude, p.table_axis or "z"))
        return Built(offsets={a: e[:, AXES.index(a)] for a in p.axes})

    def params(self, p, axis, nl, coef):
        return {"latitude_deg": float(p.latitude), "scale": 1.0, "table_axis": p.table_axis or "z"}

    def describe(self, params):
        return f"Earth rate at latitude {params['latitude_deg']:.1f}° not in the reference"


class BiasStep(Candidate):
    """A bias jump at one instant: H(t − t_step), the instant from the scan of the residual's
    cumulative sum (the least-squares change point), its few best local maxima as the grid."""

    name = "bias_step"
    family = "time"
    nonlinear = ("t_step_s",)
    SHORTLIST = 4
    PERSIST_BLOCKS = 4
    """A step is a lasting change: at least this many CV blocks of data on each side of it (a jump
    in the last minute of a record cannot be told from a brief event there)."""

    def grid(self, p, axis, ctx):
        def scan(r: np.ndarray) -> list[dict[str, Any]]:
            n = r.shape[0]
            c = np.cumsum(r - r.mean())[:-1]
            k = np.arange(1, n)
            stat = np.abs(c) / np.sqrt(k * (n - k) / n)
            edge = max(self.PERSIST_BLOCKS * p.blocks.length, 2)
            stat[: edge] = 0.0
            stat[-edge:] = 0.0
            return [{"t_step_s": float(p.t[i + 1])} for i in _peaks(stat, self.SHORTLIST, 2 * max(p.blocks.length, 2))]
        return per_residual(p, "step_scan", axis, ctx.resid[axis], scan)

    def build(self, p, axis, nl, ctx):
        col = _cached(p, ("step", float(nl["t_step_s"])), lambda: (p.t >= nl["t_step_s"]).astype(float)[:, None])
        return Built(cols={axis: col})

    def params(self, p, axis, nl, coef):
        return {"step_dps": float(coef[axis][0]), "t_step_s": float(nl["t_step_s"])}

    def describe(self, params):
        return f"bias steps by {params['step_dps']:+.2g} deg/s at t = {params['t_step_s']:.0f} s"


LINE_P = 1e-3
"""False-alarm probability of the line test over the whole searched band (:func:`line_peaks`)."""
LINE_WINDOW = 4.0
"""The continuum under a peak at f is fitted over f/LINE_WINDOW … f·LINE_WINDOW."""
EULER_GAMMA = 0.5772156649015329
"""−E[ln X] for X ~ Exp(1): a log-periodogram fit is that far below the log of the spectrum."""


def line_peaks(r: np.ndarray, fs: float, f_min: float, f_max: float, count: int) -> list[float]:
    """Frequencies (Hz) of the ``count`` highest periodogram peaks of ``r`` between ``f_min`` and
    ``f_max`` that are spectral lines against the residual's own continuum, not a crest of a coloured
    (red) one: a line test against a coloured background. The continuum at a peak f₀ is the power
    law fitted to the log of the Fourier ordinates between f₀/4 and 4·f₀ (the peak's own ±1.5
    ordinates left out; + Euler's γ, the log of an Exp(1) variable being γ below the log of its mean).
    Without a line the ordinate over its continuum is Exp(1) (Gaussian noise, any smooth spectrum),
    so the highest of the M searched ordinates, counted twice for the zero-padded search, exceeds
    ln(2M/p) with probability p = :data:`LINE_P`. A random walk's few cycles in the record are part of
    its 1/f² continuum and fail; a sinusoid of amplitude A over n samples of white σ stands
    A²n/(4σ²) above it."""
    f, power = periodogram(r, fs)
    band = (f >= f_min) & (f <= f_max)
    n = r.shape[0]
    spec = np.fft.rfft(r - r.mean())
    fourier = spec.real ** 2 + spec.imag ** 2
    j = np.arange(1, fourier.size)
    lj, li = np.log(j), np.log(np.maximum(fourier[1:], 1e-300))
    m = int(np.count_nonzero((j * fs / n >= f_min) & (j * fs / n <= f_max)))
    need = math.log(2.0 * max(m, 1) / LINE_P)
    out = []
    score = np.where(band, power, 0.0)
    for i in _peaks(score, 4 * count, 3):
        j0 = f[i] * n / fs
        sel = (j >= j0 / LINE_WINDOW) & (j <= j0 * LINE_WINDOW) & (np.abs(j - j0) > 1.5)
        if np.count_nonzero(sel) < 4:
            continue
        slope, icpt = np.polyfit(lj[sel], li[sel], 1)
        if power[i] >= need * math.exp(icpt + slope * math.log(j0) + EULER_GAMMA):
            out.append(float(f[i]))
        if len(out) == count:
            break
    return out


class Periodic(Candidate):
    """Periodic interference A·sin(2πft + φ): f from the highest peaks of the residual's periodogram
    (at least two cycles in the data, below 0.45·f_s) that are lines against its continuum
    (:func:`line_peaks`), refined within half a periodogram bin."""

    name = "periodic"
    family = "angle_rate"
    nonlinear = ("frequency_hz", "phase_rad")
    refine = (("frequency_hz", False),)
    SHORTLIST = 4
    LINE_TEST = True
    """Only peaks that are lines against the residual's continuum (a name needs a line)."""

    def grid(self, p, axis, ctx):
        lo, hi = 2.0 / p.duration_s, 0.45 * p.fs

        def lines(r: np.ndarray) -> list[dict[str, Any]]:
            if self.LINE_TEST:
                return [{"frequency_hz": f} for f in line_peaks(r, p.fs, lo, hi, self.SHORTLIST)]
            f, power = periodogram(r, p.fs)
            return [{"frequency_hz": float(f[i])} for i in _peaks(np.where((f >= lo) & (f <= hi), power, 0.0),
                                                                   self.SHORTLIST, 3)]
        return per_residual(p, f"periodogram:{self.LINE_TEST}", axis, ctx.resid[axis], lines)

    def refine_interval(self, p, name, value):
        half = 0.5 / p.duration_s
        return (max(value - half, 1e-9), value + half)

    def build(self, p, axis, nl, ctx):
        f = float(nl["frequency_hz"])
        def cols():
            ph = 2.0 * math.pi * f * p.t
            return np.column_stack([np.sin(ph), np.cos(ph)])
        return Built(cols={axis: _cached(p, ("periodic", round(f, 12)), cols)})

    def params(self, p, axis, nl, coef):
        a, b = (float(v) for v in coef[axis])
        return {"amplitude_dps": math.hypot(a, b), "frequency_hz": float(nl["frequency_hz"]), "phase_rad": math.atan2(b, a)}

    def describe(self, params):
        f = params["frequency_hz"]
        return f"periodic interference {params['amplitude_dps']:.2g} deg/s at {f:.4g} Hz (period {1 / f:.4g} s)"


def _peaks(score: np.ndarray, count: int, halfwidth: int) -> list[int]:
    """Indices of the ``count`` highest positive local maxima of ``score``, each at least
    ``halfwidth`` samples from a higher one (greedy: take the largest, blank its neighbourhood)."""
    score = np.array(score, dtype=float)
    out = []
    for _ in range(count):
        i = int(np.argmax(score))
        if score[i] <= 0:
            break
        out.append(i)
        score[max(i - halfwidth, 0): i + halfwidth + 1] = 0.0
    return out


def per_residual(p: Prepared, key: str, axis: str, r: np.ndarray, fn: Callable[[np.ndarray], Any]) -> Any:
    """``fn(r)`` computed once per residual array of ``axis`` (the grid of a round is asked for again
    while the residual is the same object)."""
    hit = p.cache.get((key, axis))
    if hit is not None and hit[0] is r:
        return hit[1]
    value = fn(r)
    p.cache[(key, axis)] = (r, value)
    return value


def periodogram(r: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Frequencies (Hz) and power of the mean-removed residual, zero-padded twice (half-bin steps)."""
    n = r.shape[0]
    nfft = 1 << int(math.ceil(math.log2(max(2 * n, 2))))
    spec = np.fft.rfft(r - r.mean(), nfft)
    return np.fft.rfftfreq(nfft, 1.0 / fs), (spec.real ** 2 + spec.imag ** 2)


class ScaleFactorNonlinearity(Candidate):
    """k2·ω² + k3·ω³ on the axis' reference rate (IEEE Std 1431)."""

    name = "scale_factor_nonlinearity"
    family = "rate"

    def missing(self, p):
        return [] if p.ref is not None else ["ref_rate_*_dps"]

    def candidate_axes(self, p):
        """The axis on the table: cross axes see rates only during tilt moves, too few levels to
        tell a curve from a poorly learnt linear scale factor."""
        ax = (p.table_axis or "").lstrip("+-")
        return [ax] if ax in p.axes and p.rate_excited(ax) else []

    def not_excited(self, p, axis):
        r = np.abs(p.ref_axis(axis))
        if float(np.max(r)) < 1.0 or np.unique(np.round(r[r > RATE_SIGN_DPS], 2)).size < 3:
            return "fewer than three rate magnitudes above 1 deg/s"
        return None

    def build(self, p, axis, nl, ctx):
        w = p.ref_axis(axis)
        return Built(cols={axis: np.column_stack([w * w, w ** 3])})

    def params(self, p, axis, nl, coef):
        k2, k3 = (float(v) for v in coef[axis])
        return {"quadratic_per_dps": k2, "cubic_per_dps2": k3}

    def describe(self, params):
        return (f"scale-factor nonlinearity {params['quadratic_per_dps']:+.2g}·ω² "
                f"{params['cubic_per_dps2']:+.2g}·ω³ (deg/s)")


class BiasInstability(Candidate):
    """Flicker bias noise: named from the noise model (``bench/analysis/diagnose/noise.py``)."""

    name = "bias_instability"
    noise_term = True

    def build(self, p, axis, nl, ctx):
        return Built()

    def params(self, p, axis, nl, coef):
        return dict(nl)

    def describe(self, params):
        return (f"flicker bias noise B = {3600 * params['b_dps']:.3g} deg/h (Allan plateau "
                f"{3600 * 0.664 * params['b_dps']:.3g} deg/h over τ = {params['tau_min_s']:.3g}-{params['tau_max_s']:.3g} s)")


class GaussMarkov(BiasInstability):
    """Exponentially correlated (first-order Markov) bias noise: named from the noise model."""

    name = "gauss_markov"

    def describe(self, params):
        return f"correlated (Gauss-Markov) bias noise {params['sigma_dps']:.2g} deg/s, τc = {params['tau_s']:.3g} s"


CANDIDATES: dict[str, Candidate] = {c.name: c for c in (
    ThermalLag(), WarmupTransient(), PressureBias(), GearEccentricity(), GSensitivity(), ScaleFactorAsymmetry(),
    ScaleFactorTempco(), Hysteresis(), TimeSkew(), RateRandomWalk(), EarthRate(), BiasStep(), Periodic(),
    ScaleFactorNonlinearity(), BiasInstability(), GaussMarkov())}
"""Every vocabulary term as a candidate, in vocabulary order (grown with :func:`register`)."""

assert tuple(CANDIDATES) == fx.VOCABULARY


def register(candidate: Candidate, params: type, forward: Callable[..., np.ndarray], needs: tuple[str, ...] = ()) -> None:
    """Add a term to the vocabulary in one call: its forward model (``bench.model.effects.register``:
    the simulator can inject it) and its candidate (diagnose searches it). ``candidate.name`` names it."""
    fx.register(candidate.name, params, forward, needs)
    CANDIDATES[candidate.name] = candidate


# ---- generic probes: structure nobody has a name for ----------------------------------------------
class _Hats:
    """Linear-spline (hat) columns of a covariate on knots at its quantiles."""

    @staticmethod
    def columns(x: np.ndarray, knots: int) -> np.ndarray | None:
        return _Hats.columns_at(x, np.unique(np.quantile(x, np.linspace(0.0, 1.0, knots))))

    @staticmethod
    def columns_at(x: np.ndarray, kn: np.ndarray) -> np.ndarray | None:
        if kn.size < 3:
            return None
        j = np.clip(np.searchsorted(kn, x, side="right") - 1, 0, kn.size - 2)
        w = np.clip((x - kn[j]) / (kn[j + 1] - kn[j]), 0.0, 1.0)
        out = np.zeros((x.shape[0], kn.size))
        rows = np.arange(x.shape[0])
        out[rows, j] = 1.0 - w
        out[rows, j + 1] += w
        return out[:, 1:]  # the constant is in the baseline


class Probe(Candidate):
    """A generic flexible function of one covariate: finds structure without naming it."""

    where = ""
    """What the structure lives against (for the report)."""

    def params(self, p, axis, nl, coef):
        return dict(nl)


class TimeProbe(RateRandomWalk):
    """Any slow structure in time: the random-walk spline (smoothness chosen by held-out error)."""

    name = "probe:time"
    where = "time (slow drift, steps, wander)"
    noise_term = False


class RateProbe(Probe):
    name = "probe:rate"
    where = "reference rate (static function of the rate)"
    KNOTS = 12

    def candidate_axes(self, p):
        return [a for a in p.axes if p.rate_excited(a)]

    def build(self, p, axis, nl, ctx):
        def cols():
            w = p.ref_axis(axis)
            # knots at the rates the table dwells at (≥ 1 % of the samples), so any static function
            # of the rate is exact there, plus quantiles for the rates in between
            vals, counts = np.unique(np.round(w, 2), return_counts=True)
            dwell = vals[counts >= 0.01 * w.size]
            knots = np.unique(np.concatenate([dwell, np.quantile(w, np.linspace(0.0, 1.0, self.KNOTS))]))
            return _Hats.columns_at(w, knots)
        z = _cached(p, ("hats_rate", axis), cols)
        return Built(cols={axis: z}) if z is not None else Built()


class TemperatureDirectionProbe(Probe):
    """Different functions of temperature while heating and while cooling (a hysteresis loop, a
    thermal lag, a gradient across the unit that reverses with the ramp)."""

    name = "probe:temperature_direction"
    where = "temperature, heating vs cooling"
    KNOTS = 6

    def candidate_axes(self, p):
        return list(p.axes) if p.temp is not None and _temp_range(p) >= 2.0 else []

    def build(self, p, axis, nl, ctx):
        def cols():
            d = p.dtemp()
            h = _Hats.columns(p.temp, self.KNOTS)
            if h is None or d is None:
                return None
            scale = max(float(np.percentile(np.abs(d), 90)), 1e-9)
            s = np.tanh(d / (0.2 * scale))  # +1 heating, −1 cooling, 0 soaking
            return np.column_stack([h * s[:, None], s])
        z = _cached(p, ("hats_tdir",), cols)
        return Built(cols={axis: z}) if z is not None else Built()


class PressureProbe(Probe):
    name = "probe:pressure"
    where = "pressure"
    KNOTS = 8

    def candidate_axes(self, p):
        return list(p.axes) if p.pressure is not None and np.ptp(np.log10(p.pressure)) >= 1.0 else []

    def build(self, p, axis, nl, ctx):
        z = _cached(p, ("hats_p",), lambda: _Hats.columns(np.log10(p.pressure), self.KNOTS))
        return Built(cols={axis: z}) if z is not None else Built()


class RateScaleProbe(Probe):
    """A scale factor that is any smooth function of temperature and of pressure: ω·hats(T) and
    ω·hats(log p) on the axis' reference rate. It imitates a linear scale-factor tempco and finds a
    scale factor that changes with the vacuum, which no vocabulary term names."""

    name = "probe:rate_scale"
    where = "scale factor against temperature and pressure"
    KNOTS = 6

    def candidate_axes(self, p):
        if p.temp is None and p.pressure is None:
            return []
        return [a for a in p.axes if p.rate_excited(a)]

    def build(self, p, axis, nl, ctx):
        def cols():
            w = p.ref_axis(axis)[:, None]
            parts = []
            if p.temp is not None and _temp_range(p) >= 2.0:
                h = _Hats.columns(p.temp, self.KNOTS)
                if h is not None:
                    parts.append(np.column_stack([np.ones(p.n), h]) * w)
            if p.pressure is not None and np.ptp(np.log10(p.pressure)) >= 1.0:
                h = _Hats.columns(np.log10(p.pressure), self.KNOTS)
                if h is not None:
                    parts.append(h * w)
            return np.column_stack(parts) if parts else None
        z = _cached(p, ("hats_rate_scale", axis), cols)
        return Built(cols={axis: z}) if z is not None else Built()


class SpectrumProbe(Periodic):
    """A spectral line: a sinusoid at the residual's highest periodogram peaks that are lines against
    its continuum (:func:`line_peaks`, as for ``periodic``): a crest of a red continuum (a random
    walk's few slow cycles) is the time probe's to find, not a line's."""

    name = "probe:spectrum"
    where = "a spectral line"
    family = None


class SpecificForceProbe(Probe):
    """A smooth (second-order) function of the specific force direction in the sensor frame."""

    name = "probe:specific_force"
    where = "specific force (gravity direction)"

    def candidate_axes(self, p):
        return list(p.axes) if p.accel is not None and float(np.max(np.std(p.accel, axis=0))) >= 0.02 else []

    def build(self, p, axis, nl, ctx):
        def cols():
            f = p.accel
            return np.column_stack([f, f * f, f[:, [0]] * f[:, [1]], f[:, [1]] * f[:, [2]], f[:, [0]] * f[:, [2]]])
        return Built(cols={axis: _cached(p, ("probe_accel",), cols)})


class RateDerivativeProbe(Probe):
    """A function of the reference rate's derivative (a timing error, a filter, an angular
    acceleration sensitivity), and the rate's curvature ω'' (what a second-order filter, a sample
    average or a linear interpolation between samples adds: ½·δ(1 − δ)·Δ²·ω'' for a delay δ·Δ)."""

    name = "probe:rate_derivative"
    where = "rate derivative (timing, filtering)"
    KNOTS = 8

    def candidate_axes(self, p):
        if p.ref is None:
            return []
        return [a for a in p.axes if float(np.ptp(p.ref_axis(a))) > 0.05]

    def build(self, p, axis, nl, ctx):
        def cols():
            d = np.gradient(p.ref_axis(axis), p.t)
            d2 = np.gradient(d, p.t)  # a second-order filter, a sample average or an interpolation: ∝ ω''
            h = _Hats.columns(d, self.KNOTS)
            return np.column_stack([d, d2, h]) if h is not None else np.column_stack([d, d2])
        return Built(cols={axis: _cached(p, ("probe_drate", axis), cols)})


class AngleProbe(Probe):
    """A function of the table angle (harmonics 1-3): what turns with the table but not with its rate
    (Earth rate, a magnetic field, a tilted mount)."""

    name = "probe:table_angle"
    where = "table angle"

    def candidate_axes(self, p):
        if p.angle is None or float(np.ptp(np.unwrap(np.radians(p.angle)))) < 2 * math.pi:
            return []
        return list(p.axes)

    def build(self, p, axis, nl, ctx):
        def cols():
            th = np.radians(p.angle)
            return np.column_stack([f(k * th) for k in (1, 2, 3) for f in (np.sin, np.cos)])
        return Built(cols={axis: _cached(p, ("probe_angle",), cols)})


class AngleRateProbe(GearEccentricity):
    """Structure periodic in the table angle, proportional to the rate (harmonics from the spectrum)."""

    name = "probe:angle_rate"
    where = "table angle × rate (periodic in the angle)"
    family = None

    def params(self, p, axis, nl, coef):
        return dict(nl)


PROBES: dict[str, Candidate] = {c.name: c for c in (
    TimeProbe(), RateProbe(), TemperatureDirectionProbe(), PressureProbe(), SpectrumProbe(), SpecificForceProbe(),
    RateDerivativeProbe(), AngleProbe(), AngleRateProbe(), RateScaleProbe())}
"""Generic probes, evaluated after selection like candidates: an acceptable one is structure left
unexplained; ``"time"`` and ``"rate"`` also check the specific evidence of the named terms."""
FAMILY_PROBE = {"time": "probe:time", "rate": "probe:rate", "specific_force": "probe:specific_force",
                "spectrum": "probe:spectrum", "angle_rate": "probe:angle_rate", "rate_scale": "probe:rate_scale"}
"""A candidate's ``family`` -> the probe its specific evidence is checked against."""
