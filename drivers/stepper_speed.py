"""Speed calibration of the stepper rotating bench (ESTCube-2 thesis section 3.2.1).

The bench's Arduino takes an integer speed parameter n; the measured relation is linear in the
inverse speed (Eq. 3.1/3.8): n = k·(1/v − b) with 1/v in s/rad, i.e. n = k·(t/2π − b) for a
rotation time t (s). The thesis fit of Table 3.1 gives k = 19.5154, b = 0.4088 s/rad.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

ESTCUBE_K = 19.5154
"""k of Eq. 3.1 (ESTCube-2 thesis, fit of Table 3.1), dimensionless n per s/rad."""
ESTCUBE_B_S_PER_RAD = 0.4088
"""b of Eq. 3.1 (ESTCube-2 thesis, fit of Table 3.1), s/rad."""


@dataclass(frozen=True)
class BenchSpeedCalibration:
    """n = k·(1/v − b): ``k`` (per s/rad), ``b_s_per_rad`` (s/rad)."""

    k: float = ESTCUBE_K
    b_s_per_rad: float = ESTCUBE_B_S_PER_RAD

    def n_for_speed(self, speed_dps: float) -> float:
        """Speed parameter n (not rounded) for a rate in deg/s (> 0)."""
        if not speed_dps > 0:
            raise ValueError(f"the bench speed must be > 0 deg/s, got {speed_dps!r}")
        return self.k * (1.0 / math.radians(speed_dps) - self.b_s_per_rad)

    def speed_for_n(self, n: float) -> float:
        """Rate in deg/s produced by speed parameter n (> -k·b)."""
        inv = n / self.k + self.b_s_per_rad
        if not inv > 0:
            raise ValueError(f"n = {n!r} gives no positive speed with k = {self.k}, b = {self.b_s_per_rad} s/rad")
        return math.degrees(1.0 / inv)

    def rotation_time_s(self, n: float) -> float:
        """Time of one full rotation (s) at speed parameter n: t = 2π·(n/k + b)."""
        return 2 * math.pi * (n / self.k + self.b_s_per_rad)
