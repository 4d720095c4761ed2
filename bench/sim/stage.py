"""A rotating stage in the simulated world: the stepper bench turning the unit about its z axis.

The stage holds a piecewise-constant rate history (deg/s) set by the device simulator that drives
it; the world turns it into per-sample rate and angle, so a sensor simulator sampling any interval
afterwards sees exactly the motion commanded in it. Changes of rate are instantaneous: at the
bench's 0.1-3 deg/s (ESTCube-2 section 3.2) a stepper reaches speed within one microstep.

The true motion differs from the commanded one by errors periodic in the stage angle
(:class:`bench.sim.table_motion.Eccentricity`, applied in turn): the worm gear's eccentricity
(ESTCube-2 section 4.3: "a periodical noise ... at every speed, the noise had a different period")
with one period per worm turn, and the microstep ripple with one period per microstep. Both are
off by default: the seed gives no amplitude (``docs/stepper-bench.md``).
"""

from __future__ import annotations

import threading

import numpy as np

from bench.sim.table_motion import Eccentricity


class RotatingStage:
    """Rate (deg/s) and angle (deg) of a stage about the unit's z axis as functions of run time (s)."""

    def __init__(self, periodic_errors: tuple[Eccentricity, ...] = ()) -> None:
        self.periodic_errors = tuple(e for e in periodic_errors if e.amplitude != 0.0)
        self._lock = threading.Lock()
        self._t = np.array([0.0])
        self._rate = np.array([0.0])
        self._angle = np.array([0.0])

    def set_rate(self, t_s: float, rate_dps: float) -> None:
        """From run time ``t_s`` on, turn at ``rate_dps`` (positive: counter-clockwise seen from +z)."""
        with self._lock:
            if t_s < self._t[-1]:
                raise ValueError(f"stage history cannot be rewritten: {t_s} s is before {self._t[-1]} s")
            angle = self._angle[-1] + self._rate[-1] * (t_s - self._t[-1])
            if t_s == self._t[-1]:
                self._rate[-1] = rate_dps
                return
            self._t = np.append(self._t, t_s)
            self._rate = np.append(self._rate, rate_dps)
            self._angle = np.append(self._angle, angle)

    @property
    def ever_moved(self) -> bool:
        return bool(np.any(self._rate != 0.0))

    def commanded_rate_dps(self, t_s: np.ndarray) -> np.ndarray:
        """Rate (deg/s) the bench was told to turn at, at run times ``t_s`` (s)."""
        with self._lock:
            i = np.searchsorted(self._t, t_s, side="right") - 1
            return self._rate[np.maximum(i, 0)]

    def commanded_angle_deg(self, t_s: np.ndarray) -> np.ndarray:
        """Angle (deg) by step counting: what the bench's firmware reports."""
        with self._lock:
            i = np.maximum(np.searchsorted(self._t, t_s, side="right") - 1, 0)
            return self._angle[i] + self._rate[i] * (np.asarray(t_s) - self._t[i])

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
