"""A rotating stage in the simulated world: the stepper bench turning the unit about its z axis.

The stage holds a rate history (deg/s) set by the device simulator that drives it, piecewise
linear in time: constant rates, or GRBL's constant-acceleration ramps between them
(bench/sim/grbl_motion.py). The world turns it into per-sample rate and angle, so a sensor
simulator sampling any interval afterwards sees exactly the motion commanded in it. The driving
simulator may replace the planned future (a cancel, a new block) but never the past.

The true motion differs from the commanded one by errors periodic in the stage angle
(:class:`bench.model.eccentricity.Eccentricity`, applied in turn): the worm gear's eccentricity
(ESTCube-2 section 4.3: "a periodical noise ... at every speed, the noise had a different period")
with one period per worm turn, and the microstep ripple with one period per microstep. Both are
off by default: the seed gives no amplitude (``docs/stepper-bench.md``).
"""

from __future__ import annotations

import threading

import numpy as np

from bench.model.eccentricity import Eccentricity


class RotatingStage:
    """Rate (deg/s) and angle (deg) of a stage about the unit's z axis as functions of run time (s)."""

    def __init__(self, periodic_errors: tuple[Eccentricity, ...] = ()) -> None:
        self.periodic_errors = tuple(e for e in periodic_errors if e.amplitude != 0.0)
        self._lock = threading.Lock()
        self._t = np.array([0.0])
        self._rate = np.array([0.0])
        self._accel = np.array([0.0])
        self._angle = np.array([0.0])
        self._fixed_s = 0.0  # history before this run time is the past: never rewritten

    def set_rate(self, t_s: float, rate_dps: float) -> None:
        """From run time ``t_s`` on, turn at ``rate_dps`` (positive: counter-clockwise seen from +z)."""
        self.set_motion(t_s, [(t_s, rate_dps, 0.0)])

    def set_motion(self, t_s: float, pieces: list[tuple[float, float, float]], t_end_s: float | None = None) -> None:
        """From run time ``t_s`` on, the planned motion: ``pieces`` of (start s, rate deg/s,
        acceleration deg/s²), contiguous and in order, then at rest from ``t_end_s`` (None: the
        last piece goes on). Whatever was planned after ``t_s`` is replaced."""
        with self._lock:
            if t_s < self._fixed_s:
                raise ValueError(f"stage history cannot be rewritten: {t_s} s is before {self._fixed_s} s")
            self._fixed_s = t_s
            keep = int(np.searchsorted(self._t, t_s, side="right"))
            i = keep - 1
            dt = t_s - self._t[i]
            rate0 = self._rate[i] + self._accel[i] * dt
            angle0 = self._angle[i] + self._rate[i] * dt + 0.5 * self._accel[i] * dt * dt
            ts, rs, acs, ang = list(self._t[:keep]), list(self._rate[:keep]), list(self._accel[:keep]), list(self._angle[:keep])
            if ts[-1] == t_s:
                ts.pop(), rs.pop(), acs.pop(), ang.pop()
            ts.append(t_s), rs.append(rate0), acs.append(0.0), ang.append(angle0)
            for t, r, a in pieces:
                if t < t_s:
                    continue
                dt = t - ts[-1]
                angle = ang[-1] + rs[-1] * dt + 0.5 * acs[-1] * dt * dt
                if t == ts[-1]:
                    rs[-1], acs[-1] = r, a
                    continue
                ts.append(t), rs.append(r), acs.append(a), ang.append(angle)
            if pieces and t_end_s is not None and t_end_s > ts[-1]:
                dt = t_end_s - ts[-1]
                ts.append(t_end_s), rs.append(0.0), acs.append(0.0), ang.append(ang[-1] + rs[-1] * dt + 0.5 * acs[-1] * dt * dt)
            elif not pieces:
                rs[-1], acs[-1] = 0.0, 0.0
            self._t, self._rate, self._accel, self._angle = (np.asarray(ts, float), np.asarray(rs, float),
                                                               np.asarray(acs, float), np.asarray(ang, float))

    @property
    def ever_moved(self) -> bool:
        return bool(np.any(self._rate != 0.0))

    def commanded_rate_dps(self, t_s: np.ndarray) -> np.ndarray:
        """Rate (deg/s) the bench was told to turn at, at run times ``t_s`` (s)."""
        with self._lock:
            i = np.maximum(np.searchsorted(self._t, t_s, side="right") - 1, 0)
            return self._rate[i] + self._accel[i] * (np.asarray(t_s) - self._t[i])

    def commanded_angle_deg(self, t_s: np.ndarray) -> np.ndarray:
        """Angle (deg) by step counting: what the bench's firmware reports."""
        with self._lock:
            i = np.maximum(np.searchsorted(self._t, t_s, side="right") - 1, 0)
            dt = np.asarray(t_s) - self._t[i]
            return self._angle[i] + self._rate[i] * dt + 0.5 * self._accel[i] * dt * dt

    def rate_dps(self, t_s: np.ndarray) -> np.ndarray:
        """True rate (deg/s) of the stage top, with the periodic errors."""
        rate = self.commanded_rate_dps(t_s)
        if not self.periodic_errors:
            return rate
        angle = self.commanded_angle_deg(t_s)
        for err in self.periodic_errors:
            rate = err.true_rate(angle, rate)
            angle = err.true_angle(angle)
        return rate

    def angle_deg(self, t_s: np.ndarray) -> np.ndarray:
        """True angle (deg) of the stage top, with the periodic errors."""
        angle = self.commanded_angle_deg(t_s)
        for err in self.periodic_errors:
            angle = err.true_angle(angle)
        return angle
