"""Time-explicit kinematics of one axis of the 2-axis rate table (rotation or tilt).

An :class:`AxisMotion` holds a piecewise constant-acceleration history: segment *k* starts at run
time ``t0[k]`` (s) with angle ``angle0[k]`` (deg), rate ``rate0[k]`` (deg/s) and constant
acceleration ``accel[k]`` (deg/s^2) until the next segment starts. Commands plan exact trapezoidal
profiles (acceleration limited, like a CiA 402 drive in profile velocity/position mode) from the
state at the command time; the history before a command is never rewritten (a command earlier than
the previous one raises ``ValueError``), only the planned, not yet reached part is replaced.

Three views of the same axis:

* ``commanded_*``: the profile the drive runs (what the motor-side encoder follows);
* ``rate_dps`` / ``angle_deg``: the true motion of the table top seen by the sensor, which adds the
  optional worm-gear eccentricity (:class:`Eccentricity`, off by default);
* ``position_counts`` / ``velocity_counts``: the encoder-quantised values the drive reports.

Memory stays bounded: segments that ended more than ``horizon_s`` before the latest command are
dropped, and at most ``max_segments`` are kept; querying a time older than the retained history
raises ``ValueError``.

Defaults (one place, each cited; [U] = assumed, no datasheet at hand):

* ``DEFAULT_MAX_RATE_DPS`` 60 deg/s [U]: the NPSAT1 thesis (seed 000, section IV.E, App. B Table 2)
  only runs the HAAS TRT-7 up to 5 deg/s; 60 deg/s is an assumed table limit, well above that.
* ``DEFAULT_MAX_ACCEL_DPS2`` 60 deg/s^2 [U]: assumed.
* ``DEFAULT_COUNTS_PER_REV`` 360000 (0.001 deg/count) [U]: a typical rotary-table positioning
  resolution; the same number is object 0x608F of drivers/rate_table.eds.
"""

from __future__ import annotations

import bisect
import math
import threading
import numpy as np

from bench.model.eccentricity import Eccentricity

__all__ = ["AxisMotion", "Eccentricity", "TableMotion"]

DEFAULT_MAX_RATE_DPS = 60.0  # [U] assumed TRT-7 limit; NPSAT1 App. B uses <= 5 deg/s
DEFAULT_MAX_ACCEL_DPS2 = 60.0  # [U] assumed
DEFAULT_COUNTS_PER_REV = 360_000  # [U] 0.001 deg/count; = 0x608F in drivers/rate_table.eds
DEFAULT_HORIZON_S = 3600.0  # keep one hour of history behind the latest command (chosen)
DEFAULT_MAX_SEGMENTS = 10_000  # hard bound on retained segments (chosen)

# NPSAT1 thesis section IV.E: tilt -36.4 deg cancels Earth rate at Monterey (geocentric latitude)
NPSAT1_TILT_DEG = -36.4


class AxisMotion:
    """Angle (deg) and rate (deg/s) of one table axis as functions of run time (s). Thread-safe."""

    def __init__(self, *, max_rate_dps: float = DEFAULT_MAX_RATE_DPS, max_accel_dps2: float = DEFAULT_MAX_ACCEL_DPS2,
                 counts_per_rev: int = DEFAULT_COUNTS_PER_REV, eccentricity: Eccentricity | None = None,
                 start_angle_deg: float = 0.0, horizon_s: float = DEFAULT_HORIZON_S,
                 max_segments: int = DEFAULT_MAX_SEGMENTS) -> None:
        if max_rate_dps <= 0 or max_accel_dps2 <= 0:
            raise ValueError("max rate and max acceleration must be > 0")
        self.max_rate_dps = float(max_rate_dps)
        self.max_accel_dps2 = float(max_accel_dps2)
        self.counts_per_rev = int(counts_per_rev)
        self.eccentricity = eccentricity or Eccentricity()
        self.horizon_s = float(horizon_s)
        self.max_segments = max(int(max_segments), 4)
        self._lock = threading.Lock()
        self._t0 = np.array([-math.inf])
        self._a0 = np.array([float(start_angle_deg)])
        self._w0 = np.array([0.0])
        self._acc = np.array([0.0])
        self._rows = self._as_lists()
        self._last_cmd_t = -math.inf
        self._ever_moved = False

    # ---- commands ---------------------------------------------------------------------------
    def command_rate(self, t_s: float, rate_dps: float, accel_dps2: float | None = None) -> float:
        """From ``t_s`` ramp at ``accel_dps2`` (deg/s^2, default the axis limit) to ``rate_dps`` and hold.

        Returns the run time (s) at which the rate is reached. ``ValueError`` beyond the limits.
        """
        a = self._check(rate_dps, accel_dps2)
        with self._lock:
            angle, rate = self._begin(t_s)
            segs = []
            dv = rate_dps - rate
            t_ramp = abs(dv) / a
            if t_ramp > 0:
                segs.append((t_s, angle, rate, math.copysign(a, dv)))
                angle += rate * t_ramp + 0.5 * math.copysign(a, dv) * t_ramp ** 2
            segs.append((t_s + t_ramp, angle, float(rate_dps), 0.0))
            self._append(t_s, segs)
            return t_s + t_ramp

    def command_position(self, t_s: float, angle_deg: float, rate_dps: float | None = None,
                         accel_dps2: float | None = None) -> float:
        """From ``t_s`` move to ``angle_deg`` (deg) at up to ``rate_dps`` (deg/s) with ``accel_dps2``
        (deg/s^2), arriving at rest. Returns the arrival run time (s). Exact trapezoid (or triangle)."""
        v = self.max_rate_dps if rate_dps is None else abs(float(rate_dps))
        a = self._check(v, accel_dps2)
        if v == 0:
            raise ValueError("a position move needs a rate > 0 deg/s")
        with self._lock:
            angle, rate = self._begin(t_s)
            segs = []
            t = t_s
            if rate != 0.0 and (rate * (angle_deg - angle) < 0 or rate * rate / (2 * a) > abs(angle_deg - angle)):
                # moving away from the target, or too fast to stop before it: stop first
                t_stop = abs(rate) / a
                acc = -math.copysign(a, rate)
                segs.append((t, angle, rate, acc))
                angle += rate * t_stop + 0.5 * acc * t_stop ** 2
                rate = 0.0
                t += t_stop
            dist = abs(angle_deg - angle)
            s = 1.0 if angle_deg >= angle else -1.0
            u = abs(rate)
            vp = v if u > v else min(v, math.sqrt(a * dist + 0.5 * u * u))
            d1 = abs(vp * vp - u * u) / (2 * a)
            d3 = vp * vp / (2 * a)
            d2 = max(dist - d1 - d3, 0.0)
            t1 = abs(vp - u) / a
            if t1 > 0:
                acc = s * math.copysign(a, vp - u)
                segs.append((t, angle, s * u, acc))
                angle += s * d1
                t += t1
            if d2 > 0 and vp > 0:
                segs.append((t, angle, s * vp, 0.0))
                angle += s * d2
                t += d2 / vp
            t3 = vp / a
            if t3 > 0:
                segs.append((t, angle, s * vp, -s * a))
                t += t3
            segs.append((t, float(angle_deg), 0.0, 0.0))
            self._append(t_s, segs)
            return t

    def stop(self, t_s: float, decel_dps2: float | None = None) -> float:
        """Decelerate to rest from ``t_s`` at ``decel_dps2`` (deg/s^2); returns the stop time (s)."""
        return self.command_rate(t_s, 0.0, decel_dps2)

    # ---- queries ----------------------------------------------------------------------------
    @property
    def ever_moved(self) -> bool:
        return self._ever_moved

    def settled_at(self) -> float:
        """Run time (s) from which the last command's profile is constant (rate reached or arrived)."""
        with self._lock:
            return float(self._t0[-1])

    def commanded_state(self, t_s: float) -> tuple[float, float]:
        """(angle deg, rate deg/s) of the drive's profile at ``t_s``: :meth:`_eval_locked` for one
        time, in plain floats (the same operations in the same order, so the same values) — a drive
        is asked this several times per poll."""
        t = float(t_s)
        with self._lock:
            t0s, a0s, w0s, accs = self._rows
            i = bisect.bisect_right(t0s, t) - 1
            if i < 0:
                raise ValueError(f"time before the retained axis history (starts at {t0s[0]} s)")
            t0, w0, acc = t0s[i], w0s[i], accs[i]
            dt = t - t0 if math.isfinite(t0) else 0.0
            return a0s[i] + w0 * dt + 0.5 * acc * dt * dt, w0 + acc * dt

    def commanded_angle_deg(self, t_s) -> np.ndarray:
        return self._eval(np.asarray(t_s, dtype=float))[0]

    def commanded_rate_dps(self, t_s) -> np.ndarray:
        return self._eval(np.asarray(t_s, dtype=float))[1]

    def angle_deg(self, t_s) -> np.ndarray:
        """True table angle (deg) at run times ``t_s`` (s, array), eccentricity included."""
        angle, _ = self._eval(np.asarray(t_s, dtype=float))
        return self.eccentricity.true_angle(angle)

    def rate_dps(self, t_s) -> np.ndarray:
        """True table rate (deg/s) at run times ``t_s`` (s, array), eccentricity included."""
        angle, rate = self._eval(np.asarray(t_s, dtype=float))
        return self.eccentricity.true_rate(angle, rate)

    def position_counts(self, t_s: float) -> int:
        """What the drive's encoder reports (counts, floor-quantised) at ``t_s``."""
        angle, _ = self.commanded_state(t_s)
        return math.floor(angle * self.counts_per_rev / 360.0 + 1e-9)

    def velocity_counts(self, t_s: float) -> int:
        """What the drive reports as actual velocity (counts/s, rounded) at ``t_s``."""
        _, rate = self.commanded_state(t_s)
        return round(rate * self.counts_per_rev / 360.0)

    def __len__(self) -> int:
        return len(self._t0)

    # ---- internals --------------------------------------------------------------------------
    def _check(self, rate_dps: float, accel_dps2: float | None) -> float:
        if not math.isfinite(rate_dps) or abs(rate_dps) > self.max_rate_dps * (1 + 1e-12):
            raise ValueError(f"rate {rate_dps!r} deg/s is beyond the axis limit {self.max_rate_dps:g} deg/s")
        a = self.max_accel_dps2 if accel_dps2 is None else float(accel_dps2)
        if not math.isfinite(a) or a <= 0 or a > self.max_accel_dps2 * (1 + 1e-12):
            raise ValueError(f"acceleration {accel_dps2!r} deg/s^2 must be in (0, {self.max_accel_dps2:g}]")
        return a

    def _begin(self, t_s: float) -> tuple[float, float]:
        if t_s < self._last_cmd_t:
            raise ValueError(f"axis history cannot be rewritten: {t_s} s is before the last command at {self._last_cmd_t} s")
        angle, rate = self._eval_locked(np.asarray([t_s], dtype=float))
        return float(angle[0]), float(rate[0])

    def _append(self, t_s: float, segs: list[tuple[float, float, float, float]]) -> None:
        keep = np.searchsorted(self._t0, t_s, side="left")  # planned segments from t_s on are replaced
        t0 = np.concatenate([self._t0[:keep], [s[0] for s in segs]])
        a0 = np.concatenate([self._a0[:keep], [s[1] for s in segs]])
        w0 = np.concatenate([self._w0[:keep], [s[2] for s in segs]])
        acc = np.concatenate([self._acc[:keep], [s[3] for s in segs]])
        # prune: drop segments whose successor started before the horizon, and cap the count
        drop = int(np.searchsorted(t0, t_s - self.horizon_s, side="right")) - 1
        drop = max(drop, len(t0) - self.max_segments, 0)
        self._t0, self._a0, self._w0, self._acc = t0[drop:], a0[drop:], w0[drop:], acc[drop:]
        self._rows = self._as_lists()
        self._last_cmd_t = t_s
        if any(s[2] != 0.0 or s[3] != 0.0 for s in segs):
            self._ever_moved = True

    def _as_lists(self) -> tuple[list[float], list[float], list[float], list[float]]:
        """The segments (start time, angle, rate, acceleration) as lists, for :meth:`commanded_state`."""
        return self._t0.tolist(), self._a0.tolist(), self._w0.tolist(), self._acc.tolist()

    def _eval(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        with self._lock:
            return self._eval_locked(t)

    def _eval_locked(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        i = np.searchsorted(self._t0, t, side="right") - 1
        if np.any(i < 0):
            raise ValueError(f"time before the retained axis history (starts at {self._t0[0]} s)")
        t0 = self._t0[i]
        dt = np.where(np.isfinite(t0), t - t0, 0.0)
        acc = self._acc[i]
        rate = self._w0[i] + acc * dt
        angle = self._a0[i] + self._w0[i] * dt + 0.5 * acc * dt * dt
        return angle, rate


class TableMotion:
    """The two axes of the table: ``rotation`` (continuous) and ``tilt`` (limited, see docs)."""

    def __init__(self, rotation: AxisMotion | None = None, tilt: AxisMotion | None = None) -> None:
        self.rotation = rotation or AxisMotion()
        self.tilt = tilt or AxisMotion()

    @property
    def ever_moved(self) -> bool:
        return self.rotation.ever_moved or self.tilt.ever_moved
