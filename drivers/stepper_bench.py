"""Driver of the stepper rotating bench (Arduino + EasyDriver at 1/8 microstep, ESTCube-2 3.2).

GRBL-style line protocol (docs/stepper-bench.md): each command line is answered by ``ok`` or
``error:N``; ``?`` and ``!`` are one-byte realtime commands. The firmware takes an integer speed
parameter n; this driver works in deg/s and converts with the bench's measured calibration
(:class:`drivers.stepper_speed.BenchSpeedCalibration`, Eq. 3.1: n = k·(1/v − b)).
"""

from __future__ import annotations

import re

import serial

from drivers.errors import ProtocolError
from drivers.stepper_speed import BenchSpeedCalibration
from drivers.transport import LineChannel, open_serial

DEFAULT_BAUDRATE = 115200  # GRBL 1.1 default
N_MAX = 65535
_STATUS = re.compile(r"^<(?P<state>[A-Za-z]+)\|N:(?P<n>-?[0-9]{1,9})\|Pos:(?P<pos>-?[0-9]{1,9}(?:\.[0-9]{0,9})?)>$")
_VERSION = re.compile(r"^\[VER:(?P<firmware>[^:\]]*):(?P<serial>[^\]]*)\]$")


class StepperBench:
    """One stepper rotating bench on a serial port. Rates in deg/s, angles in deg."""

    kind = "stepper_bench"
    streams = False  # no data stream: the runner records its commands and answers only

    def __init__(self, port: serial.SerialBase, *, timeout_s: float = 0.5, calibration: BenchSpeedCalibration | None = None,
                 on_traffic=None):
        self.port = port
        self.calibration = calibration or BenchSpeedCalibration()
        self.channel = LineChannel(port, timeout_s, "stepper_bench", on_traffic)

    @property
    def on_traffic(self):
        return self.channel.on_traffic

    @on_traffic.setter
    def on_traffic(self, hook) -> None:
        self.channel.on_traffic = hook

    @classmethod
    def open(cls, url: str, *, baudrate: int = DEFAULT_BAUDRATE, timeout_s: float = 0.5, **kwargs) -> "StepperBench":
        return cls(open_serial(url, baudrate, timeout_s), timeout_s=timeout_s, **kwargs)

    def close(self) -> None:
        self.port.close()

    def identify(self) -> dict[str, str]:
        """Firmware and serial number from ``$I``."""
        for line in self.channel.transact("$I"):
            m = _VERSION.match(line)
            if m:
                return {"vendor": "bench", "model": "stepper rotating bench (EasyDriver 1/8 step)", **m.groupdict()}
        raise ProtocolError("stepper_bench: $I answered without a [VER:...] line")

    def n_for_rate(self, rate_dps: float) -> int:
        """The integer speed parameter for ``rate_dps`` (sign = direction); ValueError if unreachable."""
        if rate_dps == 0:
            raise ValueError("a rate of 0 deg/s is a stop, not a speed")
        n = round(self.calibration.n_for_speed(abs(rate_dps)))
        if not 1 <= n <= N_MAX:
            raise ValueError(f"{rate_dps:g} deg/s needs n = {n}, outside 1..{N_MAX} for this bench")
        return n if rate_dps > 0 else -n

    def set_rate(self, rate_dps: float) -> float:
        """Set the rate (deg/s, signed) and return the rate the integer n actually gives."""
        n = self.n_for_rate(rate_dps)
        self.channel.transact(f"$N={n}")
        sign = 1.0 if n > 0 else -1.0
        return sign * self.calibration.speed_for_n(abs(n))

    def run(self) -> None:
        self.channel.transact("$RUN")

    def stop(self) -> None:
        self.channel.transact("$STOP")

    def status(self) -> dict:
        """State (``Idle`` | ``Run``), speed parameter n and angle (deg, 0..360)."""
        lines = self.channel.transact("$S")
        for text in lines:
            m = _STATUS.match(text)
            if m:
                return {"state": m["state"], "n": int(m["n"]), "angle_deg": float(m["pos"])}
        raise ProtocolError(f"stepper_bench: no status report in {lines!r}")

    def monitor_columns(self) -> list[tuple[str, str]]:
        return [("angle", "deg"), ("n", "1")]

    def monitor(self) -> dict[str, float]:
        """Angle (deg) and speed parameter n of the bench, logged every poll interval."""
        s = self.status()
        return {"angle": s["angle_deg"], "n": float(s["n"])}

    def safe_state(self) -> None:
        """Stop turning: realtime hold first (acts at once), then a confirmed ``$STOP``."""
        self.channel.send_realtime(b"!")
        self.stop()
