"""The NPSAT1 analog output path: QRS11 rate and temperature voltages through the ACS 12-bit ADC.

Source: NPSAT1 thesis (seed 000) section III.D "Data flow" and section IV.B:

* the ACS "uses a 12-bit analog to digital (A/D) converter with a dynamic range of 0 to 5 V;
  2^12 or 0 to 4095 counts ... step size is 1.22 mV"; the MEMS outputs are shifted by a 2.5 V
  reference whose measured values R_shift (rate) and T_shift (temperature) are used in the
  conversion;
* Eq. (4)  T_m(V)   = T_m(bits)/4095 · 5 − T_shift
* Eq. (5)  R_ave(V) = R_ave(bits)/4095 · 5 − R_shift
* Eq. (6)  BIT(V)   = BIT(bits)/4095 · 5
* Eq. (7)  V_out = S_f · ω,  Eq. (8)  I_ω = R_ave / S_f,  S_f = 0.5 V/(deg/s) ideal
* Eq. (9)  T = 25 °C − (V_n − T_m)/(0.0033 · G), G = 8 → 0.0264 V/°C; per sensor Eq. (10)-(12)
  T = T_ave + (T_m − V_n)/0.0264 with V_n and T_ave from Table 2:
  T_x = 25.7 + (0.5042 + T_mx)/0.0264, T_y = 25.4 + (0.4909 + T_my)/0.0264,
  T_z = 25.3 + (0.5071 + T_mz)/0.0264.

``encode_*`` are the forward (physical → counts) direction the simulator needs; ``decode_*`` are the
thesis's equations (counts → physical) the analysis applies. Encoding rounds to the nearest count
and clips to 0..4095, so decode(encode(x)) is within half a count of x inside the range.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.params import dataclass_from_dict


@dataclass
class AdcParams:
    """The ACS ADC and QRS11 output scaling (units in the names; sources in the comments)."""

    bits: int = 12  # NPSAT1 III.D: 12-bit A/D
    full_scale_v: float = 5.0  # NPSAT1 III.D: dynamic range 0 to 5 V; Eq. (4)-(6)
    r_shift_v: float = 2.5  # NPSAT1 III.D: rate reference, nominally the 2.5 V regulator
    t_shift_v: float = 2.5  # NPSAT1 III.D: temperature reference, nominally 2.5 V
    scale_factor_v_per_dps: float = 0.5  # NPSAT1 Eq. (7)-(8): ideal S_f 0.5 V/(deg/s)
    temp_nominal_v: list[float] = field(default_factory=lambda: [-0.5042, -0.4909, -0.5071])
    """V_n per sensor X/Y/Z (NPSAT1 Table 2; Eq. 10-12)."""
    temp_nominal_c: list[float] = field(default_factory=lambda: [25.7, 25.4, 25.3])
    """Temperature at V_n (T_ave) per sensor X/Y/Z (NPSAT1 Table 2; Eq. 10-12)."""
    temp_slope_v_per_c: float = 0.0264  # NPSAT1 Eq. (9): 0.0033 V/°C nominal slope × gain G = 8

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "AdcParams":
        """Build from a mapping; unknown keys raise ``KeyError`` naming them."""
        return dataclass_from_dict(cls, data)

    @property
    def max_count(self) -> int:
        """Largest count (4095 for 12 bits); Eq. (4)-(6) divide by it."""
        return 2**self.bits - 1

    @property
    def lsb_v(self) -> float:
        """One count in volts (1.22 mV, NPSAT1 III.D)."""
        return self.full_scale_v / self.max_count

    @property
    def lsb_dps(self) -> float:
        """One count of the rate channel in deg/s (2.44 mdeg/s at 0.5 V/(deg/s))."""
        return self.lsb_v / self.scale_factor_v_per_dps

    def rate_range_dps(self) -> tuple[float, float]:
        """Lowest and highest representable rate, deg/s (±5 deg/s nominal: the QRS11-00005
        high-performance ±5 deg/s range, NPSAT1 Appendix A, ±2.5 V full-scale output)."""
        return (-self.r_shift_v / self.scale_factor_v_per_dps,
                (self.full_scale_v - self.r_shift_v) / self.scale_factor_v_per_dps)


def counts_to_volts(counts: np.ndarray | int, p: AdcParams) -> np.ndarray:
    """ADC counts → volts at the converter input, NPSAT1 Eq. (6) (no reference subtracted)."""
    return np.asarray(counts, dtype=float) / p.max_count * p.full_scale_v


def volts_to_counts(volts: np.ndarray | float, p: AdcParams) -> np.ndarray:
    """Volts at the converter input → counts (round to nearest, clip to 0..max_count); int64."""
    c = np.rint(np.asarray(volts, dtype=float) / p.full_scale_v * p.max_count)
    return np.clip(c, 0, p.max_count).astype(np.int64)


def encode_rate(rate_dps: np.ndarray | float, p: AdcParams) -> np.ndarray:
    """Rate (deg/s) → rate-channel counts: V = S_f·ω (Eq. 7) shifted by R_shift (inverse of Eq. 5)."""
    return volts_to_counts(np.asarray(rate_dps, dtype=float) * p.scale_factor_v_per_dps + p.r_shift_v, p)


def decode_rate(counts: np.ndarray | int, p: AdcParams) -> np.ndarray:
    """Rate-channel counts → rate (deg/s): R_ave = counts/4095·5 − R_shift (Eq. 5), I = R_ave/S_f (Eq. 8)."""
    return (counts_to_volts(counts, p) - p.r_shift_v) / p.scale_factor_v_per_dps


def rate_saturated(counts: np.ndarray, p: AdcParams) -> np.ndarray:
    """True where a rate count sits at either end of the converter range."""
    c = np.asarray(counts)
    return (c <= 0) | (c >= p.max_count)


def temp_c_to_channel_v(temp_c: np.ndarray | float, p: AdcParams) -> np.ndarray:
    """Temperature (°C) → temperature-channel voltage T_m (V) per axis, inverting Eq. (10)-(12):
    T_m = V_n + (T − T_ave)·0.0264. ``temp_c`` (n,) gives (n, 3); (n, 3) gives (n, 3); scalar gives (3,)."""
    t = np.asarray(temp_c, dtype=float)
    if t.ndim == 1:
        t = t[:, None]
    return np.asarray(p.temp_nominal_v) + (t - np.asarray(p.temp_nominal_c)) * p.temp_slope_v_per_c


def channel_v_to_temp_c(channel_v: np.ndarray, p: AdcParams) -> np.ndarray:
    """Temperature-channel voltage T_m (V, per axis, last dimension 3) → °C, NPSAT1 Eq. (10)-(12)."""
    tm = np.asarray(channel_v, dtype=float)
    return np.asarray(p.temp_nominal_c) + (tm - np.asarray(p.temp_nominal_v)) / p.temp_slope_v_per_c


def encode_temperature(temp_c: np.ndarray | float, p: AdcParams) -> np.ndarray:
    """Temperature (°C) → temperature-channel counts per axis (inverse of Eq. 4 and 10-12)."""
    return volts_to_counts(temp_c_to_channel_v(temp_c, p) + p.t_shift_v, p)


def decode_temperature(counts: np.ndarray, p: AdcParams) -> np.ndarray:
    """Temperature-channel counts per axis (last dimension 3) → °C: Eq. (4) then Eq. (10)-(12)."""
    return channel_v_to_temp_c(counts_to_volts(counts, p) - p.t_shift_v, p)
