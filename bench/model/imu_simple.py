"""A simple IMU error model: bias, bias temperature dependence, warm-up transient, white noise.

The same model is evaluated by the simulator and (later) fitted by the analysis. Outputs are in
lab units: gyro deg/s, accelerometer g (specific force), magnetometer µT. Quantisation and
saturation happen where the hardware does them: in the board's ADC, i.e. when the simulator encodes
frames (:func:`drivers.acs_protocol.physical_to_raw`).

Defaults and their sources (see ``docs/simulation.md``):

* gyro bias vs temperature: the ESTCube-1 MPU-6000 z-axis correction polynomial at 0 deg/s
  (ESTCube-2 thesis Table 4.1, Eq. 4.1: offset(T) = p1·T² + p2·T + p3 with p1 = 1.124e-4,
  p2 = 7.561e-3, p3 = 1.150e-1, "the offset which needs to be added to the taken measurement"),
  so the bias is its negative; applied to all three axes until per-axis data exist;
* warm-up transient: NPSAT1 thesis section IV.A, outputs changed by 0.024 / 0.017 / 0.019 deg/s
  (X/Y/Z) from turn-on until stable, warm-up 12 min (X) and 5 min (Z); Y is not given and is
  interpolated at 8.5 min. Modelled as A·exp(-t/τ) with τ = settling time / 3 (95 % settled);
* gyro noise density 0.005 deg/s/√Hz (MPU-6000, ESTCube-2 Table 2.1), accelerometer
  400 µg/√Hz (MPU-6000, Table 2.2), magnetometer 0.32 µT RMS (LIS3MDL, Table 2.3);
* digital low-pass cut-off 12.5 Hz (ESTCube-2 section 4.2 test configuration); the white noise
  standard deviation per sample is density·sqrt(min(π/2·f_c, f_s/2)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.params import dataclass_from_dict

EARTH_RATE_DPS = 360.0 / 86164.0905  # sidereal day, deg/s


@dataclass
class ImuModelParams:
    """Parameters of :class:`SimpleImuModel`. Units in the field names."""

    gyro_bias_dps: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    gyro_bias_poly_degc: list[float] = field(default_factory=lambda: [-1.150e-1, -7.561e-3, -1.124e-4])
    """Bias added to every axis as a polynomial in die temperature (°C), ascending powers, deg/s."""
    warmup_amplitude_dps: list[float] = field(default_factory=lambda: [0.024, 0.017, 0.019])
    warmup_settling_s: list[float] = field(default_factory=lambda: [720.0, 510.0, 300.0])
    gyro_noise_density_dps_rthz: float = 0.005
    accel_bias_g: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    accel_noise_density_g_rthz: float = 400e-6
    mag_bias_ut: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    mag_noise_rms_ut: float = 0.32
    lowpass_cutoff_hz: float = 12.5

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "ImuModelParams":
        """Build from a mapping; unknown keys raise ``KeyError`` naming them."""
        return dataclass_from_dict(cls, data)


@dataclass
class Environment:
    """What the sensor experiences, in the sensor frame (x north, y west, z up when level).

    ``rate_dps``: true angular rate (3,); ``specific_force_g`` (3,); ``field_ut`` (3,).
    """

    rate_dps: np.ndarray
    specific_force_g: np.ndarray
    field_ut: np.ndarray


def earth_rate_dps(latitude_deg: float) -> np.ndarray:
    """Earth's rotation in a level north-west-up frame at ``latitude_deg`` (deg/s)."""
    lat = math.radians(latitude_deg)
    return np.array([EARTH_RATE_DPS * math.cos(lat), 0.0, EARTH_RATE_DPS * math.sin(lat)])


class SimpleImuModel:
    """Evaluate gyro, accelerometer and magnetometer outputs for a batch of sample times."""

    def __init__(self, params: ImuModelParams, rng: np.random.Generator):
        self.p = params
        self.rng = rng

    def noise_sigma(self, density: float, odr_hz: float) -> float:
        """Per-sample white-noise standard deviation for a noise density at output rate ``odr_hz``."""
        bandwidth = min(math.pi / 2 * self.p.lowpass_cutoff_hz, odr_hz / 2)
        return density * math.sqrt(bandwidth)

    def gyro_bias_dps(self, since_power_s: np.ndarray, temp_c: np.ndarray) -> np.ndarray:
        """Deterministic gyro bias (n, 3) in deg/s at times since sensor power-on (s) and die temperature (°C)."""
        poly = np.polynomial.polynomial.polyval(temp_c, self.p.gyro_bias_poly_degc)
        tau = np.asarray(self.p.warmup_settling_s) / 3.0
        warm = np.asarray(self.p.warmup_amplitude_dps) * np.exp(-since_power_s[:, None] / tau)
        return np.asarray(self.p.gyro_bias_dps) + poly[:, None] + warm

    def sample(
        self, since_power_s: np.ndarray, temp_c: np.ndarray, env: Environment, odr_hz: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Gyro (deg/s), accelerometer (g) and magnetometer (µT) outputs, each (n, 3), before quantisation."""
        n = since_power_s.shape[0]
        gyro = env.rate_dps + self.gyro_bias_dps(since_power_s, temp_c)
        gyro += self.rng.standard_normal((n, 3)) * self.noise_sigma(self.p.gyro_noise_density_dps_rthz, odr_hz)
        accel = env.specific_force_g + np.asarray(self.p.accel_bias_g)
        accel = accel + self.rng.standard_normal((n, 3)) * self.noise_sigma(self.p.accel_noise_density_g_rthz, odr_hz)
        mag = env.field_ut + np.asarray(self.p.mag_bias_ut) + self.rng.standard_normal((n, 3)) * self.p.mag_noise_rms_ut
        return gyro, accel, mag
