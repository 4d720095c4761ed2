"""Which recording windows of a run are *static*: the unit at rest (no rate step, rate table and
stepper bench not turning or tilting, no shaker) and its temperature stable. The report computes
noise (the Allan deviation) only over a static window (``docs/report.md``, "Noise only on static
windows").

A window is judged by what the run file says about it:

* its metadata: a commanded rate in its name (``z_set1_+0.5`` is a rate step at +0.5 deg/s; the
  zero references ``..._zero_before`` carry none) and the type of the step that recorded it
  (a ``vibrate`` or table step records while the unit moves);
* the motion streams: the rate table's ``rate`` and ``tilt`` and the stepper bench's ``angle``
  (``/streams/NAME/monitor``), over the monitor samples inside the window;
* the temperatures: the sensor's own (the board's gyro-die channel, every board sample of the
  window) and the chamber air (``tvac/monitor``): the drift over the window, |slope of a
  straight-line fit| × window length, must stay within :data:`TEMP_DRIFT_MAX_C`.

Units: run time in s, rates in deg/s, angles in deg, temperatures in °C.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

STATIC_RATE_DPS = 1e-3
"""Largest rate (deg/s) of the table or bench that still counts as at rest: a quarter of the Earth
rate (0.0042 deg/s) and a fifth of the smallest rate the procedure library commands (0.005 deg/s)."""
TEMP_DRIFT_MAX_C = 0.5
"""Largest temperature drift over a static window (°C): the 0.5 °C fluctuation below which the
procedures (ESTCube-2 section 3.4, ``band: 0.5 degC``) and the thermal calibration's reversal test
count a temperature as stable. A thermal ramp at NPSAT1's 0.47 °C/min exceeds it within 65 s."""
CORE_MOVING_STEP_TYPES = frozenset({"vibrate", "mount"})
"""Core step types during which a window that they record has the unit moving."""


def moving_step_types() -> frozenset[str]:
    """Step types during which a window that they record has the unit moving: the core's and the
    kinds' steps that move the unit (``StepDef.moves``: a table or bench turning)."""
    from bench.kinds import registry

    return CORE_MOVING_STEP_TYPES | {d.type for k in registry.kinds().values() for d in k.steps if d.moves}


@dataclass
class Trace:
    """A recorded quantity: ``label`` for messages, run times ``t`` (s), values ``y`` (its units)."""

    label: str
    t: np.ndarray
    y: np.ndarray


@dataclass
class WindowCheck:
    """Whether one recording window is static: ``name``, run-time span ``t0``..``t1`` (s), board
    ``samples`` in it, the largest measured table/bench rate ``motion_dps`` (deg/s, ``None`` without
    a motion stream), the largest temperature drift ``temp_drift_c`` (°C, ``None`` without a
    temperature) and ``reasons`` why it is not static (empty: static)."""

    name: str
    t0: float
    t1: float
    samples: int
    motion_dps: float | None = None
    temp_drift_c: float | None = None
    reasons: list[str] = field(default_factory=list)

    @property
    def static(self) -> bool:
        """True when nothing excludes the window."""
        return not self.reasons

    @property
    def duration_s(self) -> float:
        """Window length (s)."""
        return self.t1 - self.t0


def in_window(t: np.ndarray, t0: float, t1: float) -> np.ndarray:
    """Rows of run times ``t`` (s) inside the window ``t0 < t <= t1``: a sample at ``t0`` closed the
    previous window (the convention of ``bench.analysis.noise_cal``)."""
    return (t > t0) & (t <= t1)


def _inside(trace: Trace, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
    """(times, values) of the finite samples of ``trace`` with ``t0 < t <= t1``; the run times of a
    stream increase, so the window is found by bisection (long recordings have many windows)."""
    i0, i1 = np.searchsorted(trace.t, [t0, t1], side="right")
    t, y = trace.t[i0:i1], trace.y[i0:i1]
    ok = np.isfinite(y)
    return t[ok], y[ok]


def drift(trace: Trace, t0: float, t1: float) -> float | None:
    """Temperature drift over the window (units of ``trace``): |slope of a least-squares line through
    the samples inside| × (``t1`` − ``t0``); ``None`` with fewer than 2 finite samples. The line, not
    the peak-to-peak, so that sample noise and quantisation (0.01 °C steps) do not count as drift."""
    t, y = _inside(trace, t0, t1)
    if t.size < 2 or np.ptp(t) <= 0:
        return None
    slope = np.polyfit(t - t[0], y, 1)[0]
    return float(abs(slope) * (t1 - t0))


def peak_rate(trace: Trace, t0: float, t1: float) -> float | None:
    """Largest |rate| (deg/s) of a rate trace over the monitor samples inside the window, or, when no
    sample falls inside (a window shorter than the poll interval), the last sample before its end;
    ``None`` without one."""
    _, y = _inside(trace, t0, t1)
    if y.size:
        return float(np.max(np.abs(y)))
    _, y = _inside(trace, -np.inf, t1)
    return float(abs(y[-1])) if y.size else None


def angle_rate(trace: Trace, t0: float, t1: float) -> float | None:
    """Mean rate (deg/s) of an angle trace over the window: its range over the samples inside
    divided by the window length; ``None`` with fewer than 2 samples or an empty window."""
    _, y = _inside(trace, t0, t1)
    if y.size < 2 or t1 <= t0:
        return None
    return float(np.ptp(np.unwrap(y, period=360.0)) / (t1 - t0))


def check_window(name: str, t0: float, t1: float, samples: int, *, commanded_rate_dps: float | None = None,
                 step_type: str = "record", rates: list[Trace] | None = None, angles: list[Trace] | None = None,
                 temperatures: list[Trace] | None = None, rate_tol_dps: float = STATIC_RATE_DPS,
                 drift_max_c: float = TEMP_DRIFT_MAX_C) -> WindowCheck:
    """Judge one window (span ``t0``..``t1`` s, ``samples`` board rows) from its commanded rate (deg/s,
    from its name), the type of the step that recorded it, rate traces (deg/s), angle traces (deg)
    and temperature traces (°C); see the module docstring."""
    w = WindowCheck(name, t0, t1, samples)
    if commanded_rate_dps:
        w.reasons.append(f"rate step at {commanded_rate_dps:+g} deg/s (window name)")
    if step_type in moving_step_types():
        w.reasons.append(f"recorded during a {step_type} step")
    motions = [(tr.label, peak_rate(tr, t0, t1)) for tr in rates or []]
    motions += [(tr.label, angle_rate(tr, t0, t1)) for tr in angles or []]
    motions = [(label, v) for label, v in motions if v is not None]
    if motions:
        label, w.motion_dps = max(motions, key=lambda m: m[1])
        if w.motion_dps > rate_tol_dps:
            w.reasons.append(f"{label} moving at up to {w.motion_dps:.3g} deg/s (at rest: ≤ {rate_tol_dps:g} deg/s)")
    drifts = [(tr.label, drift(tr, t0, t1)) for tr in temperatures or []]
    drifts = [(label, v) for label, v in drifts if v is not None]
    if drifts:
        label, w.temp_drift_c = max(drifts, key=lambda d: d[1])
        if w.temp_drift_c > drift_max_c:
            w.reasons.append(f"{label} drifts {w.temp_drift_c:.2f} °C (stable: ≤ {drift_max_c:g} °C)")
    if samples == 0:
        w.reasons.append("no sensor samples")
    return w


def longest_static(checks: list[WindowCheck]) -> WindowCheck | None:
    """The static window with the most samples (the Allan deviation needs one contiguous record),
    ``None`` when no window is static."""
    static = [c for c in checks if c.static and c.samples > 0]
    return max(static, key=lambda c: (c.samples, c.duration_s)) if static else None


def no_static_reason(checks: list[WindowCheck]) -> str:
    """Why no window is static, in one sentence: every window's first reason, grouped."""
    if not checks:
        return "the run has no recording window of the sensor board"
    groups: dict[str, list[str]] = {}
    for c in checks:
        key = _reason_kind(c.reasons[0]) if c.reasons else "static"
        groups.setdefault(key, []).append(c.name)
    parts = []
    for kind, names in groups.items():
        shown = ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")
        parts.append(f"{len(names)} window(s) {kind} ({shown})")
    return "no window is static: " + "; ".join(parts)


def _reason_kind(reason: str) -> str:
    """A reason's category, for grouping: what precedes its numbers."""
    if reason.startswith("rate step"):
        return "at a commanded rate"
    if reason.startswith("recorded during"):
        return reason
    if "drifts" in reason:
        return f"with a temperature drift over {TEMP_DRIFT_MAX_C:g} °C"
    if "moving" in reason:
        return "with the table or bench moving"
    return reason


def finite_span(values: np.ndarray) -> tuple[float, float] | None:
    """(min, max) of the finite values, ``None`` when there is none."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return (float(v.min()), float(v.max())) if v.size else None

