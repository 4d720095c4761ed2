"""The digital output path of a MEMS gyro with an MCU moving average (ESTCube-2 thesis, seed 004).

* quantisation: 16-bit two's-complement output, LSB = full scale / 2^15 unless the datasheet gives
  the sensitivity (ESTCube-2 Table 2.1: "16 bits / 0.0076 deg/s" for the MPU-6000 at ±250 deg/s,
  "16 bits / 0.0038 deg/s" for the BMG160 at ±125 deg/s); counts saturate at −32768..32767;
* moving average (section 3.3): a FIFO of the last N samples, output Sum/N at every sample; the
  buffer is filled with real measurements first, not zeros ("it is reasonable to fill the buffer
  with real measurements first"), here with the first sample after power-on or a reset; N = 40
  was chosen for all gyroscopes (section 4.1).

The moving average acts on counts (what the MCU holds), so its output is a float count; converting
to deg/s multiplies by the LSB.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from bench.params import dataclass_from_dict


@dataclass
class DigitalParams:
    """Digital output path (units in the names)."""

    bits: int = 16  # ESTCube-2 Table 2.1: all candidate gyros 16 bits
    full_scale_dps: float = 250.0  # ESTCube-2 section 4.2.2: MPU-6000 / L3GD20H range ±250 deg/s
    lsb_dps: float | None = None
    """Sensitivity of one count, deg/s; None: full_scale_dps / 2^(bits−1)."""
    moving_average_n: int = 1  # 1 = no averaging; ESTCube-2 section 4.1 chose N = 40

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "DigitalParams":
        """Build from a mapping; unknown keys raise ``KeyError`` naming them."""
        return dataclass_from_dict(cls, data)

    @property
    def lsb(self) -> float:
        """Deg/s per count."""
        return float(self.lsb_dps) if self.lsb_dps else self.full_scale_dps / 2 ** (self.bits - 1)

    @property
    def count_range(self) -> tuple[int, int]:
        """Lowest and highest count (two's complement)."""
        return -(2 ** (self.bits - 1)), 2 ** (self.bits - 1) - 1


def quantise(rate_dps: np.ndarray | float, p: DigitalParams) -> np.ndarray:
    """Rate (deg/s) → counts: round to nearest, saturate at the two's-complement range; int64."""
    lo, hi = p.count_range
    return np.clip(np.rint(np.asarray(rate_dps, dtype=float) / p.lsb), lo, hi).astype(np.int64)


def counts_to_dps(counts: np.ndarray | float, p: DigitalParams) -> np.ndarray:
    """Counts (integer or averaged) → deg/s."""
    return np.asarray(counts, dtype=float) * p.lsb


def moving_average(x: np.ndarray, n_avg: int, history: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """N-sample boxcar over consecutive rows of ``x`` (m, k) (ESTCube-2 section 3.3).

    ``history`` holds the previous N−1 rows (None: pre-fill with the first row of ``x``). Returns the
    averaged rows (m, k) and the new history, so successive calls equal one call on the
    concatenation.
    """
    x = np.asarray(x, dtype=float)
    if n_avg <= 1 or x.shape[0] == 0:
        return x.copy(), history
    if history is None:
        history = np.repeat(x[:1], n_avg - 1, axis=0)
    full = np.concatenate([history, x], axis=0)
    csum = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:]), full], axis=0), axis=0)
    out = (csum[n_avg:] - csum[:-n_avg])[-x.shape[0]:] / n_avg
    return out, full[-(n_avg - 1):].copy()


class MovingAverage:
    """Stateful :func:`moving_average` (the MCU's FIFO); :meth:`reset` at power-on."""

    def __init__(self, n_avg: int):
        self.n_avg = int(n_avg)
        self.history: np.ndarray | None = None

    def reset(self) -> None:
        """Forget the buffer: the next sample pre-fills it."""
        self.history = None

    def __call__(self, x: np.ndarray) -> np.ndarray:
        out, self.history = moving_average(x, self.n_avg, self.history)
        return out
