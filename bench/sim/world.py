"""The simulated physical world the device simulators read.

In this first version the world is a level, stationary bench in a room: constant ambient
temperature, Earth rate, gravity and the local geomagnetic field. Later issues add the chamber,
the rate table and the stepper bench; device simulators only ever call :meth:`World.environment`
and :meth:`World.unit_temperature_c`, so they will not change.

Defaults (``docs/simulation.md``):

* ambient 20 °C: "lab temperature of around 20°C" (ESTCube-2 thesis section 3.4);
* latitude 36.4°: geocentric latitude of Monterey, CA, where NPSAT1 was tested (NPSAT1 thesis
  section IV.E: "the turntable was tilted at -36.4°");
* geomagnetic field at Monterey, horizontal 23.6 µT north, vertical 42.0 µT down (NOAA World
  Magnetic Model WMM2025 at 36.6° N 121.9° W, rounded; declination neglected);
* gravity: the accelerometer of a level, stationary unit reads +1 g on its up (z) axis.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.model.imu_simple import Environment, earth_rate_dps
from bench.params import dataclass_from_dict


@dataclass
class WorldParams:
    """Parameters of the world (units in the names)."""

    ambient_temp_c: float = 20.0
    latitude_deg: float = 36.4
    field_ut: list[float] = field(default_factory=lambda: [23.6, 0.0, -42.0])

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "WorldParams":
        """Build from a mapping; unknown keys raise ``KeyError`` naming them."""
        return dataclass_from_dict(cls, data)


class World:
    """A level, stationary unit on a bench in a room at constant temperature."""

    def __init__(self, params: WorldParams):
        self.p = params
        self._env = Environment(
            rate_dps=earth_rate_dps(params.latitude_deg),
            specific_force_g=np.array([0.0, 0.0, 1.0]),
            field_ut=np.asarray(params.field_ut, dtype=float),
        )

    def environment(self, t_s: np.ndarray) -> Environment:
        """Rate, specific force and field seen by the unit at run times ``t_s`` (s); broadcastable (3,) here."""
        return self._env

    def unit_temperature_c(self, t_s: np.ndarray) -> np.ndarray:
        """Temperature of the unit under test (°C) at run times ``t_s`` (s)."""
        return np.full(np.shape(t_s), self.p.ambient_temp_c, dtype=float)
