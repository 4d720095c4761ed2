"""A rotating stage in the simulated world: the stepper bench turning the unit about its z axis.

The stage holds a piecewise-constant rate history (deg/s) set by the device simulator that drives
it; the world turns it into per-sample rate and angle, so a sensor simulator sampling any interval
afterwards sees exactly the motion commanded in it. Changes of rate are instantaneous: at the
bench's 0.1-3 deg/s (ESTCube-2 section 3.2) a stepper reaches speed within one microstep.
"""

from __future__ import annotations

import threading

import numpy as np


class RotatingStage:
    """Rate (deg/s) and angle (deg) of a stage about the unit's z axis as functions of run time (s)."""

    def __init__(self) -> None:
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

    def rate_dps(self, t_s: np.ndarray) -> np.ndarray:
        with self._lock:
            i = np.searchsorted(self._t, t_s, side="right") - 1
            return self._rate[np.maximum(i, 0)]

    def angle_deg(self, t_s: np.ndarray) -> np.ndarray:
        with self._lock:
            i = np.maximum(np.searchsorted(self._t, t_s, side="right") - 1, 0)
            return self._angle[i] + self._rate[i] * (np.asarray(t_s) - self._t[i])
