"""Driver of the stepper rotating bench (Arduino + EasyDriver at 1/8 microstep, ESTCube-2 3.2).

GRBL-style line protocol (docs/stepper-bench.md, docs/golden/grbl.md): each command line is
answered by ``ok`` or ``error:N``; ``?``, ``!``, ``~`` and 0x18 are one-byte realtime commands; a
pushed ``ALARM:N`` raises :class:`DeviceFault`. Status reports have GRBL 1.1's form
``<State|MPos:x,y,z|...>`` (the table angle is the X position) plus the firmware's ``N:`` field.
The firmware takes an integer speed parameter n; this driver works in deg/s and converts with the
bench's measured calibration (:class:`drivers.stepper_speed.BenchSpeedCalibration`, Eq. 3.1:
n = k·(1/v − b)).
"""

from __future__ import annotations

import re

import serial

from drivers.base import Driver, check_timeout
from drivers.errors import ProtocolError
from drivers.stepper_speed import BenchSpeedCalibration
from drivers.transport import LineChannel, open_serial

DEFAULT_BAUDRATE = 115200  # GRBL 1.1 default
N_MAX = 65535
MEANINGS = {  # gnea/grbl doc/markdown/interface.md, "Grbl Response Messages" / "Alarm Message"
    "error:2": "numeric value format is not valid or missing an expected value",
    "error:3": "'$' system command was not recognized or supported",
    "error:9": "locked out during alarm or jog state",
    "error:11": "max characters per line exceeded, line not executed",
    "error:22": "feed rate (speed parameter n) has not yet been set",
    "ALARM:3": "reset while in motion, position may be lost; unlock with $X",
}
# interface.md "Real-time Status Reports": state first, position (MPos or WPos, X,Y,Z) second,
# other fields optional and in any order
_NUMBER = r"-?[0-9]{1,9}(?:\.[0-9]{1,9})?"
_STATUS = re.compile(rf"^<(?P<state>[A-Za-z]+)(?::[0-9])?\|[MW]Pos:(?P<pos>{_NUMBER})(?:,{_NUMBER}){{2,3}}"
                     r"(?P<fields>(?:\|[A-Za-z]+:[^|<>]*)*)>$")
_N_FIELD = re.compile(r"\|N:(?P<n>-?[0-9]{1,9})(?=\||$)")
_VERSION = re.compile(r"^\[VER:(?P<firmware>[^:\]]*):(?P<serial>[^\]]*)\]$")


class StepperBench(Driver):
    """One stepper rotating bench on a serial port. Rates in deg/s, angles in deg."""

    kind = "stepper_bench"
    streams = False  # no data stream: the runner records its commands and answers only

    def __init__(self, port: serial.SerialBase, *, timeout_s: float = 0.5, calibration: BenchSpeedCalibration | None = None,
                 on_traffic=None):
        self.port = port
        self.name = "stepper_bench"
        self.timeout_s = check_timeout(timeout_s)
        self.calibration = calibration or BenchSpeedCalibration()
        self.channel = LineChannel(port, self.timeout_s, self.name, on_traffic, meanings=MEANINGS)

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
        """State (``Idle`` | ``Run`` | ``Hold`` | ``Alarm``, GRBL's sub-state dropped), speed
        parameter n and angle (deg, 0..360)."""
        lines = self.channel.transact("$S")
        for text in lines:
            m = _STATUS.match(text)
            n = _N_FIELD.search(m["fields"]) if m else None
            if n:
                return {"state": m["state"], "n": int(n["n"]), "angle_deg": float(m["pos"])}
        raise ProtocolError(f"stepper_bench: no status report with an N: field in {lines!r}")

    def monitor_columns(self) -> list[tuple[str, str]]:
        return [("angle", "deg"), ("n", "1")]

    def monitor(self) -> dict[str, float]:
        """Angle (deg) and speed parameter n of the bench, logged every poll interval."""
        s = self.status()
        return {"angle": s["angle_deg"], "n": float(s["n"])}

    def safe_state(self) -> str:
        """Stop turning: realtime hold first (acts at once), then a confirmed ``$STOP``."""
        self.channel.send_realtime(b"!")
        self.stop()
        return "feed hold (!), then $STOP: stopped"
