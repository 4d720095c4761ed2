"""The simulated physical world the device simulators read.

The world is a unit on a mount inside a thermal-vacuum chamber (:class:`bench.sim.chamber.Chamber`;
with no chamber instrument nobody commands it and it stays at the room's ambient temperature and
pressure), with Earth rate, gravity and the local geomagnetic field, on a stage (the stepper
bench) that can turn it about its z axis. Device simulators only ever call
:meth:`World.environment`, :meth:`World.unit_temperature_c` and the chamber's methods.

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
from bench.sim.chamber import Chamber, ChamberParams
from bench.sim.stage import RotatingStage


@dataclass
class WorldParams:
    """Parameters of the world (units in the names)."""

    ambient_temp_c: float = 20.0
    latitude_deg: float = 36.4
    field_ut: list[float] = field(default_factory=lambda: [23.6, 0.0, -42.0])
    chamber: ChamberParams = field(default_factory=ChamberParams)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "WorldParams":
        """Build from a mapping; unknown keys raise ``KeyError`` naming them."""
        return dataclass_from_dict(cls, data)


class World:
    """A level unit in a room at constant temperature, on a stage that can turn about its z axis."""

    def __init__(self, params: WorldParams):
        self.p = params
        self.stage = RotatingStage()
        self.chamber = Chamber(params.chamber, ambient_temp_c=params.ambient_temp_c)
        self._earth = earth_rate_dps(params.latitude_deg)
        self._field = np.asarray(params.field_ut, dtype=float)
        self._env = Environment(rate_dps=self._earth, specific_force_g=np.array([0.0, 0.0, 1.0]), field_ut=self._field)

    def environment(self, t_s: np.ndarray) -> Environment:
        """Rate, specific force and field seen by the unit at run times ``t_s`` (s).

        Stationary: (3,) vectors. Once the stage has turned: (n, 3) arrays, with Earth rate and
        field rotated into the turned sensor frame and the stage rate added on z.
        """
        if not self.stage.ever_moved:
            return self._env
        t = np.asarray(t_s, dtype=float)
        theta = np.radians(self.stage.angle_deg(t))
        c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
        rate = _rotate_z(self._earth, c, s)
        rate[:, 2] += self.stage.rate_dps(t)
        return Environment(rate_dps=rate, specific_force_g=self._env.specific_force_g, field_ut=_rotate_z(self._field, c, s))

    def unit_temperature_c(self, t_s: np.ndarray) -> np.ndarray:
        """Temperature of the sensor die (°C) at run times ``t_s`` (s): chamber, mount and self-heating."""
        return self.chamber.unit_temperature_c(t_s)

    def set_unit_power(self, t_s: float, on: bool) -> None:
        """The unit's electronics switched on or off at run time ``t_s`` (s): self-heating."""
        self.chamber.set_unit_power(t_s, on)


def _rotate_z(v: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """World vector ``v`` (3,) expressed in a sensor frame turned by angle θ about z (cos c, sin s)."""
    out = np.empty((c.shape[0], 3))
    out[:, 0] = c[:, 0] * v[0] + s[:, 0] * v[1]
    out[:, 1] = -s[:, 0] * v[0] + c[:, 0] * v[1]
    out[:, 2] = v[2]
    return out
