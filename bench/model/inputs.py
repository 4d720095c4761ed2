"""What a sensor experiences over a batch of samples: the inputs of every sensor error model.

The same :class:`SensorInputs` drives the simulator (built from :class:`bench.sim.world.World`) and
the analysis (built from a recorded run and the reference instruments), so both evaluate the same
model on the same quantities.

Conventions (``docs/sensor-models.md``):

* ``rate_dps`` is the *true* angular rate of the sensor in its own frame, deg/s, **including
  Earth rate** (the model adds no Earth rate of its own; the caller projects Earth's rotation, e.g.
  :func:`bench.model.imu_simple.earth_rate_dps` or the world's environment, NPSAT1 thesis
  Appendix L / Eq. 13-14);
* ``temp_c`` is the temperature channel in °C: one channel for all axes (n,) or one per axis (n, 3)
  (NPSAT1 has one temperature output per QRS11 sensor, Eq. 10-12);
* ``pressure_torr`` defaults to ambient, 760 Torr (NPSAT1 Fig. 36 ambient samples at
  7.5E+2 / 7.6E+2 Torr);
* ``power_on_s`` is the time since the sensor was powered (s); when it decreases from one sample to
  the next, or the power-on instant ``time_s − power_on_s`` moves, the sensor was power-cycled (a
  new run, a new run-to-run bias);
* ``specific_force_g`` (n, 3) in g, for g-sensitivity terms; zeros when not given;
* ``table_angle_deg`` (n,) the rate-table / stage angle, for effects periodic in the table angle
  (worm-gear eccentricity, ESTCube-2 section 4.3); None when unknown.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

AMBIENT_PRESSURE_TORR = 760.0
"""Standard atmosphere, Torr (NPSAT1 thesis Fig. 36: ambient 7.5E+2 to 7.6E+2 Torr)."""


def _vec_n(x: object, n: int, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim == 0:
        return np.full(n, float(a))
    if a.shape != (n,):
        raise ValueError(f"{name}: expected shape ({n},), got {a.shape}")
    return a


def _vec_n3(x: object, n: int, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.shape == (3,):
        return np.broadcast_to(a, (n, 3)).copy()
    if a.shape != (n, 3):
        raise ValueError(f"{name}: expected shape ({n}, 3) or (3,), got {a.shape}")
    return a


@dataclass
class SensorInputs:
    """Inputs of a sensor model for n samples (units in the field names, see the module docstring).

    Arrays are broadcast on construction: ``rate_dps`` and ``specific_force_g`` may be (3,),
    ``temp_c`` and ``pressure_torr`` scalars. ``power_on_s`` defaults to ``time_s - time_s[0]``
    (powered at the first sample).
    """

    time_s: np.ndarray
    rate_dps: np.ndarray
    temp_c: np.ndarray
    pressure_torr: np.ndarray | float | None = None
    power_on_s: np.ndarray | None = None
    specific_force_g: np.ndarray | None = None
    table_angle_deg: np.ndarray | None = None

    def __post_init__(self) -> None:
        t = np.atleast_1d(np.asarray(self.time_s, dtype=float))
        if t.ndim != 1:
            raise ValueError(f"time_s: expected shape (n,), got {t.shape}")
        n = t.shape[0]
        self.time_s = t
        self.rate_dps = _vec_n3(self.rate_dps, n, "rate_dps")
        temp = np.asarray(self.temp_c, dtype=float)
        self.temp_c = temp if temp.shape == (n, 3) else _vec_n(temp, n, "temp_c")
        self.pressure_torr = _vec_n(AMBIENT_PRESSURE_TORR if self.pressure_torr is None else self.pressure_torr, n, "pressure_torr")
        self.power_on_s = (t - t[0] if n else t.copy()) if self.power_on_s is None else _vec_n(self.power_on_s, n, "power_on_s")
        self.specific_force_g = np.zeros((n, 3)) if self.specific_force_g is None else _vec_n3(self.specific_force_g, n, "specific_force_g")
        if self.table_angle_deg is not None:
            self.table_angle_deg = _vec_n(self.table_angle_deg, n, "table_angle_deg")

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.time_s.shape[0])

    def temp_per_axis_c(self) -> np.ndarray:
        """Temperature channel per axis (n, 3), °C."""
        t = np.asarray(self.temp_c)
        return t if t.ndim == 2 else np.repeat(t[:, None], 3, axis=1)

    def select(self, index: slice | np.ndarray) -> "SensorInputs":
        """The samples at ``index`` (a slice or index array) as a new :class:`SensorInputs`."""
        return SensorInputs(
            time_s=self.time_s[index],
            rate_dps=self.rate_dps[index],
            temp_c=np.asarray(self.temp_c)[index],
            pressure_torr=np.asarray(self.pressure_torr)[index],
            power_on_s=np.asarray(self.power_on_s)[index],
            specific_force_g=np.asarray(self.specific_force_g)[index],
            table_angle_deg=None if self.table_angle_deg is None else np.asarray(self.table_angle_deg)[index],
        )


def stationary_inputs(
    duration_s: float,
    rate_hz: float,
    rate_dps: np.ndarray | tuple[float, float, float] = (0.0, 0.0, 0.0),
    temp_c: float = 25.0,
    pressure_torr: float = AMBIENT_PRESSURE_TORR,
    t0_s: float = 0.0,
    power_on_at_s: float = 0.0,
) -> SensorInputs:
    """Inputs of a sensor at rest: ``duration_s`` of samples at ``rate_hz`` from ``t0_s`` (s),
    constant true rate (deg/s, Earth rate included by the caller), temperature (°C) and pressure
    (Torr), powered at ``power_on_at_s``."""
    n = int(round(duration_s * rate_hz))
    t = t0_s + np.arange(n) / rate_hz
    return SensorInputs(time_s=t, rate_dps=np.asarray(rate_dps, dtype=float), temp_c=temp_c,
                        pressure_torr=pressure_torr, power_on_s=t - power_on_at_s)
