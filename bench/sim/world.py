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

import numpy as np

from bench.model.geometry import mount_matrix
from bench.model.imu_simple import Environment, earth_rate_dps
from bench.model.world import WorldParams
from bench.sim.chamber import Chamber
from bench.sim.stage import RotatingStage
from bench.sim.table_motion import TableMotion
from bench.model.vibration import VibrationSchedule

__all__ = ["World", "WorldParams"]


class World:
    """A level unit in a room at constant temperature, on a stage that can turn about its z axis."""

    def __init__(self, params: WorldParams):
        self.p = params
        self.stage = RotatingStage()
        self.table = TableMotion()
        self.vibration = VibrationSchedule()
        """Shaker events (random vibration, sine sweeps) in the unit's frame; sensor simulators add
        them to the specific force through their own low-pass (docs/vibration.md)."""
        self.chamber = Chamber(params.chamber, ambient_temp_c=params.ambient_temp_c)
        self._earth = earth_rate_dps(params.latitude_deg)
        self._field = np.asarray(params.field_ut, dtype=float)
        self._gravity = np.array([0.0, 0.0, 1.0])
        self.mount = np.eye(3)
        """Sensor frame from platter frame: v_sensor = mount @ v_platter (:meth:`set_mount`)."""
        self._env = Environment(rate_dps=self._earth, specific_force_g=self._gravity, field_ut=self._field)

    def set_mount(self, up: str) -> None:
        """Mount the unit with sensor axis ``up`` (x, y, z, -x, -y, -z) along the platter normal
        (the table's rotation axis), as a technician does between the axes of a rate-transfer test."""
        self.mount = mount_matrix(up)
        m = self.mount
        self._env = Environment(rate_dps=m @ self._earth, specific_force_g=m @ self._gravity, field_ut=m @ self._field)

    def environment(self, t_s: np.ndarray) -> Environment:
        """Rate, specific force and field seen by the unit at run times ``t_s`` (s).

        Stationary: (3,) vectors. Once the stage or the rate table has moved: (n, 3) arrays. The
        unit sits on the table's platter (and, when a stepper bench is configured, on its stage,
        about the same z axis): its frame is the world frame turned by the tilt φ about the west
        (y) axis — φ > 0 tips the platter normal from up toward north — then by the platter and
        stage angles θ about the platter normal. Earth rate, gravity and field are expressed in
        that frame; the platter, stage and tilt rates are added (NPSAT1 Appendix L: with
        φ = −latitude the table axis is perpendicular to Earth's axis and sees no Earth rate).
        """
        if not self.stage.ever_moved and not self.table.ever_moved:
            return self._env  # already in the sensor frame of the current mount
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        theta = np.radians(self.stage.angle_deg(t) + self.table.rotation.angle_deg(t))
        phi = np.radians(self.table.tilt.angle_deg(t))
        c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
        cp, sp = np.cos(phi)[:, None], np.sin(phi)[:, None]

        def to_sensor(v: np.ndarray) -> np.ndarray:
            # undo the tilt (Ry(φ)ᵀ), then the rotation about the platter normal (Rz(θ)ᵀ)
            v = np.broadcast_to(v, (t.shape[0], 3))
            x = cp[:, 0] * v[:, 0] - sp[:, 0] * v[:, 2]
            z = sp[:, 0] * v[:, 0] + cp[:, 0] * v[:, 2]
            return _rotate_z_rows(np.stack([x, v[:, 1], z], axis=1), c, s)

        tilt_rate = np.zeros((t.shape[0], 3))
        tilt_rate[:, 1] = self.table.tilt.rate_dps(t)
        rate = to_sensor(self._earth) + _rotate_z_rows(tilt_rate, c, s)
        rate[:, 2] += self.stage.rate_dps(t) + self.table.rotation.rate_dps(t)
        m = self.mount.T  # rows @ mountᵀ = (mount @ row) for each row
        return Environment(rate_dps=rate @ m, specific_force_g=to_sensor(self._gravity) @ m, field_ut=to_sensor(self._field) @ m)

    def unit_temperature_c(self, t_s: np.ndarray) -> np.ndarray:
        """Temperature of the sensor die (°C) at run times ``t_s`` (s): chamber, mount and self-heating."""
        return self.chamber.unit_temperature_c(t_s)

    def set_unit_power(self, t_s: float, on: bool) -> None:
        """The unit's electronics switched on or off at run time ``t_s`` (s): self-heating."""
        self.chamber.set_unit_power(t_s, on)


def _rotate_z_rows(v: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Rows of ``v`` (n, 3) expressed in a frame turned by angle θ about z (cos c, sin s, (n, 1))."""
    out = np.empty_like(v)
    out[:, 0] = c[:, 0] * v[:, 0] + s[:, 0] * v[:, 1]
    out[:, 1] = -s[:, 0] * v[:, 0] + c[:, 0] * v[:, 1]
    out[:, 2] = v[:, 2]
    return out
