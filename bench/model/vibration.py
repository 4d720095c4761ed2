"""Vibration of the simulated world: shaker random vibration and sine sweeps (``docs/vibration.md``).

The vibration functional test (NPSAT1 thesis section IV.F, Table 1) shakes the unit along one of
its axes: a low-level sine sweep (20-1000 Hz, 0.25 g, 4 oct/min), the GEVS component minimum
workmanship random vibration (20-2000 Hz, 6.8 grms, 1 min per axis), and the sine sweep again.
This module gives the world that input as a specific force in the unit's frame (g), evaluable
lazily at any array of run times, so a sensor simulator samples it at its own output data rate in
virtual time:

* :class:`AsdProfile` - an acceleration spectral density (ASD) from breakpoints, log-log
  interpolated as vibration specifications are, with its exact overall RMS (:meth:`AsdProfile.grms`);
* :class:`RandomVibration` - random-phase multi-sine synthesis of a profile over a time window;
* :class:`SineSweep` - logarithmic sine sweep with the exact phase integral;
* :class:`VibrationSchedule` - the events of a run, summed (the world adds the sum to gravity);
* :func:`load_vibration` - ``bench-vibration/1`` YAML files (``configs/vibration/``).

Both event types take ``lowpass_hz``: each spectral component is multiplied by the complex
response of a Butterworth low-pass (the sensor's digital low-pass filter) before sampling. What
the filter does not remove aliases when the sensor samples slowly; that is the physics, not an
artefact (see ``docs/vibration.md``).
"""

from __future__ import annotations

import abc
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, Sequence, Union

import numpy as np

from bench.errors import InputError, InputErrors, Location
from bench.units import to_units
from bench.yamlsrc import Fields, Node, Source, load_yaml, parse_yaml

VIBRATION_SCHEMA = "bench-vibration/1"
KINDS = ("random", "sine_sweep")
ASD_UNITS = "g0^2/Hz"
"""Canonical ASD unit for pint: ``g0`` is pint's standard gravity (9.80665 m/s²); pint's ``g`` is
the gram, so the loader reads a ``g`` written alone as ``g0`` (``0.01 g^2/Hz`` = ``0.01 g0^2/Hz``)."""
SLOPE_TOLERANCE_DB_PER_OCT = 0.1
"""A breakpoint giving both a level and the slope that reaches it must agree to this (dB/oct)."""
OVERALL_TOLERANCE = 0.01
"""A stated ``overall_rms`` must match the integral of the breakpoints to 1 %."""
MAX_TONES = 200_000
DB_PER_DECADE_POWER = 10.0  # ASD is a power quantity: dB = 10 log10(ratio)
_G_ALONE = re.compile(r"(?<![A-Za-z_])g(?![A-Za-z0-9_])")
_NUMBER = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"
_SLOPE = re.compile(rf"^\s*({_NUMBER})\s*dB\s*/\s*(?:oct|octave)\s*$")
_RATE = re.compile(rf"^\s*({_NUMBER})\s*(?:oct|octave|octaves)\s*/\s*([A-Za-z]+)\s*$")
_FAST_MIN_SAMPLES = 32
_UNIFORM_ATOL_S = 1e-9
_BLOCK_SAMPLES = 1 << 16
_DIRECT_CHUNK_ELEMENTS = 1 << 20


# --------------------------------------------------------------------------------------------
# Profile
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class AsdProfile:
    """An ASD (g²/Hz) through breakpoints ``(frequency_hz[i], asd_g2_per_hz[i])``, straight lines
    in log-log between them (constant dB/oct), zero outside ``[frequency_hz[0], frequency_hz[-1]]``.
    """

    frequency_hz: tuple[float, ...]
    asd_g2_per_hz: tuple[float, ...]

    def __post_init__(self) -> None:
        f = np.asarray(self.frequency_hz, dtype=float)
        a = np.asarray(self.asd_g2_per_hz, dtype=float)
        if f.ndim != 1 or f.shape != a.shape or f.size < 2:
            raise ValueError("an ASD profile needs at least two breakpoints (frequency, ASD)")
        if not (np.all(np.isfinite(f)) and np.all(np.isfinite(a))):
            raise ValueError("ASD profile breakpoints must be finite")
        if f[0] <= 0 or np.any(np.diff(f) <= 0):
            raise ValueError("ASD profile frequencies must be positive and strictly increasing")
        if np.any(a <= 0):
            raise ValueError("ASD levels must be > 0 (log-log interpolation)")

    @property
    def f_min_hz(self) -> float:
        return float(self.frequency_hz[0])

    @property
    def f_max_hz(self) -> float:
        return float(self.frequency_hz[-1])

    def exponents(self) -> np.ndarray:
        """Log-log slope n of each segment, ASD ∝ fⁿ (n = dB/oct / (10 log10 2))."""
        f = np.asarray(self.frequency_hz)
        a = np.asarray(self.asd_g2_per_hz)
        return np.log(a[1:] / a[:-1]) / np.log(f[1:] / f[:-1])

    def slopes_db_per_oct(self) -> np.ndarray:
        """Slope of each segment in dB/oct."""
        return self.exponents() * DB_PER_DECADE_POWER * math.log10(2.0)

    def asd(self, f_hz: np.ndarray | float) -> np.ndarray:
        """ASD (g²/Hz) at ``f_hz`` (any shape); 0 outside the profile band."""
        f = np.asarray(f_hz, dtype=float)
        fb = np.asarray(self.frequency_hz)
        ab = np.asarray(self.asd_g2_per_hz)
        inside = (f >= fb[0]) & (f <= fb[-1])
        fc = np.clip(np.where(inside, f, fb[0]), fb[0], fb[-1])
        seg = np.clip(np.searchsorted(fb, fc, side="right") - 1, 0, fb.size - 2)
        n = self.exponents()[seg]
        out = ab[seg] * (fc / fb[seg]) ** n
        return np.where(inside, out, 0.0)

    def band_power(self, f_lo_hz: np.ndarray | float, f_hi_hz: np.ndarray | float) -> np.ndarray:
        """Exact ∫ ASD df (g²) over ``[f_lo, f_hi]`` (arrays broadcast), clipped to the profile band."""
        lo = np.asarray(f_lo_hz, dtype=float)
        hi = np.asarray(f_hi_hz, dtype=float)
        return self._cumulative(hi) - self._cumulative(lo)

    def grms(self) -> float:
        """Overall RMS acceleration (g): square root of the exact integral of the log-log segments."""
        return float(math.sqrt(self._cumulative(np.asarray(self.f_max_hz))))

    def _cumulative(self, f_hz: np.ndarray) -> np.ndarray:
        """∫ from f_min to f of ASD (g²), exact for each power-law segment."""
        fb = np.asarray(self.frequency_hz)
        ab = np.asarray(self.asd_g2_per_hz)
        n = self.exponents()
        seg_power = _powerlaw_integral(ab[:-1], fb[:-1], fb[1:], n)
        before = np.concatenate([[0.0], np.cumsum(seg_power)])
        f = np.clip(np.asarray(f_hz, dtype=float), fb[0], fb[-1])
        seg = np.clip(np.searchsorted(fb, f, side="right") - 1, 0, fb.size - 2)
        return before[seg] + _powerlaw_integral(ab[seg], fb[seg], f, n[seg])

    # --- files ---------------------------------------------------------------------------

    @classmethod
    def load(cls, path: str | Path) -> "AsdProfile":
        """The profile of a ``bench-vibration/1`` file of kind ``random``."""
        spec = load_vibration(path)
        if not isinstance(spec, RandomVibrationSpec):
            raise InputError("expected a file of kind 'random' (an ASD profile)", spec.location, "kind")
        return spec.profile

    def to_yaml(self, name: str = "ASD profile", duration_s: float = 60.0) -> str:
        """A ``bench-vibration/1`` random file with these breakpoints (levels given; exact repr floats)."""
        lines = [f"schema: {VIBRATION_SCHEMA}", "kind: random", f"name: {_yaml_str(name)}", f"duration: {duration_s!r} s", "profile:"]
        for f, a in zip(self.frequency_hz, self.asd_g2_per_hz):
            lines.append(f"  - {{frequency: {float(f)!r} Hz, asd: {float(a)!r} g^2/Hz}}")
        return "\n".join(lines) + "\n"


def _powerlaw_integral(a1: np.ndarray, f1: np.ndarray, f2: np.ndarray, n: np.ndarray) -> np.ndarray:
    """∫_{f1}^{f2} a1 (f/f1)ⁿ df, exact, stable near n = -1 (where it is a1 f1 ln(f2/f1))."""
    a1, f1, f2, n = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (a1, f1, f2, n)))
    r = np.log(f2 / f1)
    m = (n + 1.0) * r
    # (e^m - 1)/m -> 1 as m -> 0; expm1 keeps full precision
    small = np.abs(m) < 1e-12
    factor = np.where(small, 1.0, np.expm1(m) / np.where(small, 1.0, m))
    return a1 * f1 * r * factor


# --------------------------------------------------------------------------------------------
# Filter
# --------------------------------------------------------------------------------------------


def butterworth_response(f_hz: np.ndarray | float, cutoff_hz: float, order: int = 1) -> np.ndarray:
    """Complex frequency response H(j2πf) of an analog Butterworth low-pass (|H(fc)|² = 1/2)."""
    if not (isinstance(cutoff_hz, (int, float)) and cutoff_hz > 0 and math.isfinite(cutoff_hz)):
        raise ValueError(f"low-pass cutoff must be a positive frequency in Hz, got {cutoff_hz!r}")
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or order < 1:
        raise ValueError(f"low-pass order must be an integer >= 1, got {order!r}")
    s = 1j * np.asarray(f_hz, dtype=float) / cutoff_hz  # normalised s = jω/ωc
    k = np.arange(1, order + 1)
    poles = np.exp(1j * np.pi * (2 * k + order - 1) / (2 * order))  # left half-plane, unit circle
    h = np.ones(s.shape, dtype=complex)
    for p in poles:
        h = h * (-p) / (s - p)
    return h


# --------------------------------------------------------------------------------------------
# Events
# --------------------------------------------------------------------------------------------

Axis = Union[str, Sequence[float], np.ndarray]


def axis_vector(axis: Axis) -> np.ndarray:
    """Unit vector (3,) in the unit's frame from ``"x"``/``"y"``/``"z"`` (optionally signed) or a 3-vector."""
    if isinstance(axis, str):
        name = axis.strip().lower()
        sign = -1.0 if name.startswith("-") else 1.0
        name = name.lstrip("+-")
        if name not in ("x", "y", "z"):
            raise ValueError(f"axis must be 'x', 'y', 'z' or a 3-vector, got {axis!r}")
        v = np.zeros(3)
        v["xyz".index(name)] = sign
        return v
    v = np.asarray(axis, dtype=float)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"axis must be 'x', 'y', 'z' or a finite 3-vector, got {axis!r}")
    norm = float(np.linalg.norm(v))
    if norm == 0.0:
        raise ValueError("axis vector must not be zero")
    return v / norm


class VibrationEvent(Protocol):
    """What :class:`VibrationSchedule` needs of an event."""

    t_start_s: float

    @property
    def t_end_s(self) -> float: ...

    def specific_force_g(self, t_s: np.ndarray, lowpass_hz: float | None = None, lowpass_order: int = 1) -> np.ndarray: ...


class _EventBase(abc.ABC):
    axis: np.ndarray
    t_start_s: float
    duration_s: float

    @property
    def t_end_s(self) -> float:
        """End of the event's window (exclusive): it acts for t_start_s <= t < t_end_s."""
        return self.t_start_s + self.duration_s

    def active(self, t_s: np.ndarray | float) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)
        return (t >= self.t_start_s) & (t < self.t_end_s)

    def specific_force_g(self, t_s: np.ndarray | float, lowpass_hz: float | None = None, lowpass_order: int = 1) -> np.ndarray:
        """Specific force (n, 3) in g along the axis at run times ``t_s``; zero outside the window.

        With ``lowpass_hz`` the signal is the one a sensor with that Butterworth low-pass
        (``lowpass_order``) sees: every spectral component scaled by |H(f)| and shifted by ∠H(f).
        """
        t = np.atleast_1d(np.asarray(t_s, dtype=float)).ravel()
        return self.acceleration_g(t, lowpass_hz, lowpass_order)[:, None] * self.axis[None, :]

    def acceleration_g(self, t_s: np.ndarray, lowpass_hz: float | None = None, lowpass_order: int = 1) -> np.ndarray:
        """Scalar acceleration (n,) in g along the axis at run times ``t_s`` (zero outside the window)."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float)).ravel()
        out = np.zeros(t.shape)
        inside = self.active(t)
        if np.any(inside):
            out[inside] = self._signal(t[inside] - self.t_start_s, lowpass_hz, lowpass_order)
        return out

    @abc.abstractmethod
    def _signal(self, tau: np.ndarray, lowpass_hz: float | None, lowpass_order: int) -> np.ndarray:
        """The scalar signal (g) at times ``tau`` (s) since the start, all inside the window."""


class RandomVibration(_EventBase):
    """Random vibration with a given ASD along ``axis``, in ``[t_start_s, t_start_s + duration_s)``.

    Random-phase multi-sine: a(τ) = Σₖ Aₖ cos(2π fₖ τ + φₖ), τ = t − t_start_s. The profile band is
    cut into bins of ``tone_spacing_hz``; bin k carries one tone at a frequency drawn uniformly
    inside the bin, with amplitude Aₖ = √(2 Pₖ), Pₖ the exact ∫ ASD df over the bin (≈ ASD(fₖ)Δf),
    and a uniform random phase. So the RMS is exactly :meth:`AsdProfile.grms`, the PSD averaged
    over any band wider than a few bins is the ASD, the amplitude distribution is near-Gaussian
    (central limit over ~2000 tones), and the signal does not repeat (the frequencies are not on a
    common grid). Deterministic for ``seed``.
    """

    def __init__(
        self,
        profile: AsdProfile,
        axis: Axis,
        t_start_s: float,
        duration_s: float,
        seed: int = 0,
        tone_spacing_hz: float = 1.0,
    ):
        if not (math.isfinite(t_start_s) and math.isfinite(duration_s) and duration_s > 0):
            raise ValueError("random vibration needs a finite start time and a duration > 0 s")
        if not (tone_spacing_hz > 0 and math.isfinite(tone_spacing_hz)):
            raise ValueError("tone spacing must be > 0 Hz")
        self.profile = profile
        self.axis = axis_vector(axis)
        self.t_start_s = float(t_start_s)
        self.duration_s = float(duration_s)
        self.seed = seed
        self.tone_spacing_hz = float(tone_spacing_hz)
        band = profile.f_max_hz - profile.f_min_hz
        n = max(1, int(math.ceil(band / tone_spacing_hz - 1e-9)))
        if n > MAX_TONES:
            raise ValueError(f"{n} tones exceed {MAX_TONES}; use a larger tone spacing")
        edges = profile.f_min_hz + tone_spacing_hz * np.arange(n + 1)
        edges[-1] = profile.f_max_hz
        rng = np.random.default_rng(seed)
        u = rng.random(n)
        self.tone_hz = edges[:-1] + u * (edges[1:] - edges[:-1])
        self.phase_rad = rng.uniform(0.0, 2.0 * np.pi, n)
        self.amplitude_g = np.sqrt(2.0 * np.maximum(profile.band_power(edges[:-1], edges[1:]), 0.0))

    def rms_g(self, lowpass_hz: float | None = None, lowpass_order: int = 1) -> float:
        """Long-run RMS (g) of the signal, optionally after the low-pass: √(Σ |Aₖ H(fₖ)|² / 2)."""
        a = self._complex_amplitudes(lowpass_hz, lowpass_order)
        return float(np.sqrt(np.sum(np.abs(a) ** 2) / 2.0))

    def _complex_amplitudes(self, lowpass_hz: float | None, lowpass_order: int) -> np.ndarray:
        c = self.amplitude_g * np.exp(1j * self.phase_rad)
        if lowpass_hz is not None:
            c = c * butterworth_response(self.tone_hz, lowpass_hz, lowpass_order)
        return c

    def _signal(self, tau: np.ndarray, lowpass_hz: float | None, lowpass_order: int) -> np.ndarray:
        c = self._complex_amplitudes(lowpass_hz, lowpass_order)
        w = 2.0 * np.pi * self.tone_hz
        out = np.empty(tau.shape)
        # Evaluate run by run: a stretch of uniformly spaced times goes through the factorised
        # product (exact up to the uniformity tolerance), anything else through direct cosines.
        for lo, hi, uniform in _runs(tau):
            if uniform:
                out[lo:hi] = _sum_tones_uniform(tau[lo], (tau[hi - 1] - tau[lo]) / (hi - lo - 1), hi - lo, w, c)
            else:
                out[lo:hi] = _sum_tones_direct(tau[lo:hi], w, c)
        return out


def _runs(tau: np.ndarray) -> list[tuple[int, int, bool]]:
    """Split ``tau`` into blocks; each is (lo, hi, uniformly spaced to within 1 ns)."""
    runs = []
    n = tau.size
    for lo in range(0, n, _BLOCK_SAMPLES):
        hi = min(n, lo + _BLOCK_SAMPLES)
        m = hi - lo
        uniform = False
        if m >= _FAST_MIN_SAMPLES:
            h = (tau[hi - 1] - tau[lo]) / (m - 1)
            if h > 0:
                ideal = tau[lo] + h * np.arange(m)
                uniform = bool(np.max(np.abs(tau[lo:hi] - ideal)) <= _UNIFORM_ATOL_S)
        runs.append((lo, hi, uniform))
    return runs


def _sum_tones_direct(tau: np.ndarray, w: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Re Σₖ cₖ exp(j wₖ τ) by chunks of samples (memory ~ chunk × tones)."""
    out = np.empty(tau.shape)
    amp = np.abs(c)
    ph = np.angle(c)
    step = max(1, _DIRECT_CHUNK_ELEMENTS // max(1, w.size))
    for i in range(0, tau.size, step):
        out[i:i + step] = np.cos(np.outer(tau[i:i + step], w) + ph) @ amp
    return out


def _sum_tones_uniform(tau0: float, h: float, m: int, w: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Re Σₖ cₖ exp(j wₖ (τ₀ + i h)), i = 0..m−1, as a P×K by K×Q complex matrix product.

    With i = p Q + q: exp(j w (τ₀ + pQh + qh)) = exp(j w (τ₀ + pQh)) · exp(j w q h). Cost
    (P + Q) K exponentials and one BLAS product instead of m K cosines.
    """
    q_len = int(math.ceil(math.sqrt(m)))
    p_len = -(-m // q_len)
    left = np.exp(1j * np.outer(tau0 + np.arange(p_len) * (q_len * h), w)) * c[None, :]
    right = np.exp(1j * np.outer(w, np.arange(q_len) * h))
    return (left @ right).real.ravel()[:m]


class SineSweep(_EventBase):
    """Logarithmic sine sweep of peak ``amplitude_g`` along ``axis`` from ``f_start_hz`` to ``f_end_hz``.

    f(τ) = f₀ · 2^(±R τ / 60) with R the rate in oct/min (sign of log2(f₁/f₀)); the phase is the
    exact integral φ(τ) = 2π f₀ (2^(±Rτ/60) − 1) / (±R ln2 / 60) and a(τ) = A sin φ(τ), so the sweep
    starts at zero. Duration = |log2(f₁/f₀)| / R minutes.
    """

    def __init__(
        self,
        f_start_hz: float,
        f_end_hz: float,
        amplitude_g: float,
        rate_oct_per_min: float,
        axis: Axis,
        t_start_s: float,
    ):
        for name, v in (("f_start_hz", f_start_hz), ("f_end_hz", f_end_hz), ("rate_oct_per_min", rate_oct_per_min)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be > 0, got {v!r}")
        if f_start_hz == f_end_hz:
            raise ValueError("a sweep needs different start and end frequencies")
        if not (math.isfinite(amplitude_g) and amplitude_g >= 0):
            raise ValueError("amplitude must be >= 0 g")
        if not math.isfinite(t_start_s):
            raise ValueError("start time must be finite")
        self.f_start_hz = float(f_start_hz)
        self.f_end_hz = float(f_end_hz)
        self.amplitude_g = float(amplitude_g)
        self.rate_oct_per_min = float(rate_oct_per_min)
        self.axis = axis_vector(axis)
        self.t_start_s = float(t_start_s)
        octaves = math.log2(f_end_hz / f_start_hz)
        self.octaves = abs(octaves)
        self._k = math.copysign(rate_oct_per_min / 60.0, octaves)  # signed octaves per second
        self.duration_s = self.octaves / rate_oct_per_min * 60.0

    def frequency_hz(self, t_s: np.ndarray | float) -> np.ndarray:
        """Instantaneous frequency (Hz) at run times ``t_s`` (the law, also outside the window)."""
        tau = np.asarray(t_s, dtype=float) - self.t_start_s
        return self.f_start_hz * np.exp2(self._k * tau)

    def phase_rad(self, t_s: np.ndarray | float) -> np.ndarray:
        """φ(τ) = 2π ∫₀^τ f dτ' (rad), exact."""
        tau = np.asarray(t_s, dtype=float) - self.t_start_s
        a = self._k * math.log(2.0)
        return 2.0 * np.pi * self.f_start_hz * np.expm1(a * tau) / a

    def _signal(self, tau: np.ndarray, lowpass_hz: float | None, lowpass_order: int) -> np.ndarray:
        t = tau + self.t_start_s
        phi = self.phase_rad(t)
        if lowpass_hz is None:
            return self.amplitude_g * np.sin(phi)
        # quasi-stationary: the sweep is slow (4 oct/min), the filter sees a sine at f(τ)
        h = butterworth_response(self.frequency_hz(t), lowpass_hz, lowpass_order)
        return self.amplitude_g * np.abs(h) * np.sin(phi + np.angle(h))


# --------------------------------------------------------------------------------------------
# Schedule
# --------------------------------------------------------------------------------------------


class VibrationSchedule:
    """The vibration events of a run; their specific forces add (superposition).

    Memory stays bounded over long runs: when an event is added, events that ended more than
    ``retention_s`` before the new event's start are dropped (after that, a query at those old
    times returns zero). Sensor simulators produce their samples shortly after the run time they
    describe, never ``retention_s`` (default 10 min) late, so nothing they ask for is lost.
    """

    def __init__(self, retention_s: float = 600.0):
        if not retention_s >= 0:
            raise ValueError("retention must be >= 0 s")
        self.retention_s = float(retention_s)
        self._events: list[VibrationEvent] = []

    @property
    def events(self) -> tuple[VibrationEvent, ...]:
        return tuple(self._events)

    def __len__(self) -> int:
        return len(self._events)

    def add(self, event: VibrationEvent) -> VibrationEvent:
        """Schedule ``event`` (a :class:`RandomVibration`, :class:`SineSweep` or alike); returns it."""
        self.prune(event.t_start_s - self.retention_s)
        self._events.append(event)
        return event

    def prune(self, before_s: float) -> int:
        """Drop events that ended at or before run time ``before_s``; returns how many were dropped."""
        keep = [e for e in self._events if e.t_end_s > before_s]
        dropped = len(self._events) - len(keep)
        self._events = keep
        return dropped

    def active(self, t_s: float) -> list[VibrationEvent]:
        """Events acting at run time ``t_s``."""
        return [e for e in self._events if e.t_start_s <= t_s < e.t_end_s]

    def overlaps(self, t_first_s: float, t_last_s: float) -> bool:
        """Whether any event acts somewhere in ``[t_first_s, t_last_s]`` (cheap test for callers)."""
        return any(e.t_start_s <= t_last_s and e.t_end_s > t_first_s for e in self._events)

    def specific_force_g(self, t_s: np.ndarray | float, lowpass_hz: float | None = None, lowpass_order: int = 1) -> np.ndarray:
        """Sum of the events' specific forces (n, 3) in g, in the unit's frame, at run times ``t_s``."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float)).ravel()
        out = np.zeros((t.size, 3))
        if t.size == 0:
            return out
        lo, hi = float(np.min(t)), float(np.max(t))
        for e in self._events:
            if e.t_start_s <= hi and e.t_end_s > lo:
                out += e.specific_force_g(t, lowpass_hz, lowpass_order)
        return out


# --------------------------------------------------------------------------------------------
# Files (bench-vibration/1)
# --------------------------------------------------------------------------------------------


@dataclass
class RandomVibrationSpec:
    """A ``kind: random`` file: the profile and the test duration per axis."""

    name: str
    profile: AsdProfile
    duration_s: float
    overall_rms_g: float | None = None
    location: Location | None = None

    def event(self, axis: Axis, t_start_s: float, seed: int = 0, tone_spacing_hz: float = 1.0) -> RandomVibration:
        return RandomVibration(self.profile, axis, t_start_s, self.duration_s, seed, tone_spacing_hz)


@dataclass
class SineSweepSpec:
    """A ``kind: sine_sweep`` file."""

    name: str
    f_start_hz: float
    f_end_hz: float
    amplitude_g: float
    rate_oct_per_min: float
    location: Location | None = None

    @property
    def duration_s(self) -> float:
        return abs(math.log2(self.f_end_hz / self.f_start_hz)) / self.rate_oct_per_min * 60.0

    def event(self, axis: Axis, t_start_s: float, seed: int = 0) -> SineSweep:
        """The sweep from ``t_start_s``; ``seed`` is accepted for symmetry with random profiles (a sweep is deterministic)."""
        return SineSweep(self.f_start_hz, self.f_end_hz, self.amplitude_g, self.rate_oct_per_min, axis, t_start_s)


VibrationSpec = Union[RandomVibrationSpec, SineSweepSpec]


def load_vibration(path: str | Path) -> VibrationSpec:
    """Read and validate a ``bench-vibration/1`` file; raises :class:`InputErrors` listing located problems."""
    return _spec(load_yaml(path, "vibration file"))


def parse_vibration(text: str, path: str = "<vibration>") -> VibrationSpec:
    """As :func:`load_vibration`, from text (``path`` is used in messages)."""
    return _spec(parse_yaml(text, path, "vibration file"))


def _spec(src: Source) -> VibrationSpec:
    errors: list[InputError] = []
    top = Fields(src.root, "vibration file", errors)
    schema = top.get("schema", str, required=True)
    if schema is not None and schema != VIBRATION_SCHEMA:
        errors.append(InputError(f"unsupported schema {schema!r}; expected {VIBRATION_SCHEMA!r}", top.map["schema"].location, "schema"))
    kind = top.get("kind", str, required=True)
    name = top.get("name", str, default=src.path.stem)
    spec: VibrationSpec | None = None
    if kind is not None and kind not in KINDS:
        errors.append(InputError(f"unknown kind {kind!r} (expected one of: {', '.join(KINDS)})", top.map["kind"].location, "kind"))
    elif kind == "random":
        spec = _random(top, name, src, errors)
    elif kind == "sine_sweep":
        spec = _sine(top, name, src, errors)
    top.check_unknown()
    if errors or spec is None:
        raise InputErrors(errors or [InputError("nothing to load", src.root.location)])
    return spec


def _random(top: Fields, name: str, src: Source, errors: list[InputError]) -> RandomVibrationSpec | None:
    before = len(errors)
    duration = _required_quantity(top, "duration", "s", errors)
    if duration is not None and not duration > 0:
        errors.append(InputError("duration must be > 0 s", top.map["duration"].location, "duration"))
    overall = None
    if (n := top.node_at("overall_rms")) is not None:
        overall = _quantity(n, "g0", "overall_rms", errors)
    profile = _profile(top.node_at("profile"), src, errors)
    if profile is not None and overall is not None:
        got = profile.grms()
        if abs(got - overall) > OVERALL_TOLERANCE * overall:
            errors.append(InputError(
                f"the breakpoints integrate to {got:.3f} grms, not the stated {overall:g} g "
                f"(tolerance {OVERALL_TOLERANCE:.0%})", top.map["overall_rms"].location, "overall_rms"))
    if len(errors) > before or profile is None or duration is None:
        return None
    return RandomVibrationSpec(name, profile, duration, overall, src.root.location)


def _profile(node: Node | None, src: Source, errors: list[InputError]) -> AsdProfile | None:
    if node is None or not isinstance(node.value, list) or len(node.value) < 2:
        errors.append(InputError(
            "expected a list of at least two breakpoints such as {frequency: 20 Hz, asd: 0.01 g^2/Hz}; "
            "later ones may give 'slope: +3 dB/oct' instead of (or with) 'asd'", (node or src.root).location, "profile"))
        return None
    before = len(errors)
    freqs: list[float] = []
    levels: list[float] = []
    prev_f: float | None = None
    for i, row in enumerate(node.value):
        f = Fields(row, f"profile breakpoint {i + 1}", errors)
        fnode = f.node_at("frequency")
        anode = f.node_at("asd")
        snode = f.node_at("slope")
        f.check_unknown()
        if not isinstance(row.value, dict):
            continue
        if fnode is None:
            errors.append(InputError(f"missing required field in profile breakpoint {i + 1}", row.location, "frequency"))
            return None
        freq = _quantity(fnode, "Hz", "frequency", errors)
        if freq is None:
            return None
        if not freq > 0:
            errors.append(InputError("frequency must be > 0 Hz", fnode.location, "frequency"))
            return None
        if prev_f is not None and not freq > prev_f:
            errors.append(InputError(
                f"frequencies must increase: {freq:g} Hz after {prev_f:g} Hz", fnode.location, "frequency"))
            return None
        level = None
        if anode is not None:
            level = _quantity(anode, ASD_UNITS, "asd", errors)
            if level is None:
                return None
            if not level > 0:
                errors.append(InputError("ASD must be > 0 g^2/Hz (levels are interpolated in log-log)", anode.location, "asd"))
                return None
        slope = None
        if snode is not None:
            slope = _slope(snode, errors)
            if slope is None:
                return None
            if prev_f is None:
                errors.append(InputError("the first breakpoint starts the profile: give its level 'asd', not a slope",
                                         snode.location, "slope"))
                return None
        if level is None and slope is None:
            errors.append(InputError("give the level 'asd' or the 'slope' (dB/oct) reaching this breakpoint", row.location, "asd"))
            return None
        if slope is not None and prev_f is not None:
            octaves = math.log2(freq / prev_f)
            reached = levels[-1] * 10.0 ** (slope * octaves / DB_PER_DECADE_POWER)
            if level is None:
                level = reached
            else:
                actual = DB_PER_DECADE_POWER * math.log10(level / levels[-1]) / octaves
                if abs(actual - slope) > SLOPE_TOLERANCE_DB_PER_OCT:
                    errors.append(InputError(
                        f"{slope:+g} dB/oct from {levels[-1]:g} g^2/Hz at {prev_f:g} Hz reaches {reached:.4g} g^2/Hz at "
                        f"{freq:g} Hz, not {level:g} g^2/Hz (that needs {actual:+.2f} dB/oct)", snode.location, "slope"))
                    return None
        freqs.append(freq)
        levels.append(float(level))  # type: ignore[arg-type]
        prev_f = freq
    if len(errors) > before:
        return None
    return AsdProfile(tuple(freqs), tuple(levels))


def _sine(top: Fields, name: str, src: Source, errors: list[InputError]) -> SineSweepSpec | None:
    before = len(errors)
    f0 = _required_quantity(top, "start_frequency", "Hz", errors)
    f1 = _required_quantity(top, "end_frequency", "Hz", errors)
    amp = _required_quantity(top, "amplitude", "g0", errors)
    rate = None
    if (n := top.node_at("sweep_rate")) is None:
        errors.append(InputError("missing required field in vibration file", top.node.location, "sweep_rate"))
    else:
        rate = _rate(n, errors)
    for key, v in (("start_frequency", f0), ("end_frequency", f1), ("sweep_rate", rate)):
        if v is not None and not v > 0:
            errors.append(InputError("must be > 0", top.map[key].location, key))
    if amp is not None and not amp > 0:
        errors.append(InputError("amplitude (peak) must be > 0 g", top.map["amplitude"].location, "amplitude"))
    if f0 is not None and f1 is not None and f0 == f1:
        errors.append(InputError("a sweep needs different start and end frequencies", top.map["end_frequency"].location, "end_frequency"))
    if len(errors) > before or None in (f0, f1, amp, rate):
        return None
    return SineSweepSpec(name, f0, f1, amp, rate, src.root.location)  # type: ignore[arg-type]


def _required_quantity(top: Fields, key: str, units: str, errors: list[InputError]) -> float | None:
    node = top.node_at(key)
    if node is None:
        errors.append(InputError("missing required field in vibration file", top.node.location, key))
        return None
    return _quantity(node, units, key, errors)


def _quantity(node: Node, units: str, fname: str, errors: list[InputError]) -> float | None:
    value = node.value
    if isinstance(value, str):
        value = _G_ALONE.sub("g0", value)  # acceleration in g (standard gravity), not grams
    try:
        return to_units(value, units, node.location, fname)
    except InputError as exc:
        if isinstance(node.value, str) and value != node.value:
            exc = InputError(exc.message.replace(repr(value), repr(node.value)), exc.location, exc.field)
        errors.append(exc)
        return None


def _slope(node: Node, errors: list[InputError]) -> float | None:
    """``+3 dB/oct`` -> 3.0. pint's logarithmic units cannot express a ratio per octave, so this is read here."""
    value = node.value
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
        return float(value)
    m = _SLOPE.match(value) if isinstance(value, str) else None
    if m is None:
        errors.append(InputError(f"expected a slope such as '+3 dB/oct' or '-3 dB/octave', got {value!r}", node.location, "slope"))
        return None
    return float(m.group(1))


def _rate(node: Node, errors: list[InputError]) -> float | None:
    """``4 oct/min`` -> 4.0 octaves per minute (the time unit goes through pint)."""
    value = node.value
    m = _RATE.match(value) if isinstance(value, str) else None
    if m is None:
        errors.append(InputError(f"expected a sweep rate such as '4 oct/min', got {value!r}", node.location, "sweep_rate"))
        return None
    try:
        per = to_units(f"1 {m.group(2)}", "min", node.location, "sweep_rate")
    except InputError as exc:
        errors.append(InputError(f"expected a sweep rate such as '4 oct/min', got {value!r} ({exc.message})", node.location, "sweep_rate"))
        return None
    return float(m.group(1)) / per


def _yaml_str(text: str) -> str:
    return "'" + text.replace("'", "''") + "'"


__all__ = [
    "AsdProfile",
    "RandomVibration",
    "SineSweep",
    "VibrationSchedule",
    "VibrationEvent",
    "RandomVibrationSpec",
    "SineSweepSpec",
    "butterworth_response",
    "axis_vector",
    "load_vibration",
    "parse_vibration",
]
