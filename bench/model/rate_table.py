"""The rate table's motion defaults, as the planner assumes them (deg/s, deg/s²).

A step that gives no rate or acceleration leaves the drive's own profile values in force; these are
the defaults of ``drivers/rate_table.eds`` (objects 0x6081 Profile velocity and 0x6083 Profile
acceleration: 10000 counts at 0.001 deg/count), which ``tests/test_technician_defects.py`` checks
against the EDS. Motions are acceleration-limited trapezoids (CiA 402 profile modes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class TableParams:
    """Profile velocity (deg/s) and acceleration (deg/s²) of both axes until a step sets others."""

    profile_velocity_dps: float = 10.0
    profile_accel_dps2: float = 10.0


def move_time_s(distance_deg: float, rate_dps: float, accel_dps2: float) -> float:
    """Time (s) of a trapezoidal move over ``distance_deg`` at most ``rate_dps``, accelerating and
    braking at ``accel_dps2``, from and to rest (a triangle when the distance is too short to
    reach the rate)."""
    d = abs(distance_deg)
    if d == 0.0:
        return 0.0
    if d >= rate_dps * rate_dps / accel_dps2:
        return d / rate_dps + rate_dps / accel_dps2
    return 2.0 * math.sqrt(d / accel_dps2)
