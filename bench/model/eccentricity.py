"""A periodic error of a turning axis's true rate (worm-gear eccentricity, microstep ripple).

A model parameter, not a simulator: the lab config reads it (``sim: {eccentricity: ...}``), the
simulated table and stage apply it (:mod:`bench.sim.table_motion`, :mod:`bench.sim.stage`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Eccentricity:
    """Worm-gear eccentricity: a periodic error of the true table rate (ESTCube-2, seed 004 section 4.3).

    ESTCube-2 found "a periodical noise ... in the axis the system was revolving around but at every
    speed, the noise had a different period": the error is periodic in the table *angle*, not in
    time. Modelled as ``true_rate = rate * (1 + amplitude * sin(harmonic * theta + phase))`` with
    ``theta`` the commanded table angle (rad); its exact integral gives the true angle. The seed gives
    no amplitude: the default 0 turns the term off.

    :param amplitude: fractional rate error (dimensionless, e.g. 0.002 = 0.2 %)
    :param harmonic: integer number of error periods per table revolution (>= 1)
    :param phase_rad: phase at angle 0 (rad)
    """

    amplitude: float = 0.0
    harmonic: int = 1
    phase_rad: float = 0.0

    def __post_init__(self) -> None:
        if int(self.harmonic) != self.harmonic or self.harmonic < 1:
            raise ValueError(f"eccentricity harmonic must be an integer >= 1, got {self.harmonic!r}")
        if not 0.0 <= abs(self.amplitude) < 1.0:
            raise ValueError(f"eccentricity amplitude must be a fraction below 1, got {self.amplitude!r}")

    def true_rate(self, angle_deg: np.ndarray, rate_dps: np.ndarray) -> np.ndarray:
        if self.amplitude == 0.0:
            return rate_dps
        arg = self.harmonic * np.radians(angle_deg) + self.phase_rad
        return rate_dps * (1.0 + self.amplitude * np.sin(arg))

    def true_angle(self, angle_deg: np.ndarray) -> np.ndarray:
        if self.amplitude == 0.0:
            return angle_deg
        arg = self.harmonic * np.radians(angle_deg) + self.phase_rad
        k = self.amplitude * 180.0 / (math.pi * self.harmonic)
        return angle_deg + k * (math.cos(self.phase_rad) - np.cos(arg))
