"""Driver of a thermocouple data logger speaking 34970A-style SCPI over a serial line.

Configures type K or T thermocouples with the internal reference junction and the open-
thermocouple check on a list of channels, then reads one scan per :meth:`read`. Temperatures in
°C; an open thermocouple is reported as ``None`` with its channel in ``open_channels``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import serial

from drivers.base import Driver, check_timeout
from drivers.errors import DeviceFault, ProtocolError
from drivers.transport import LineChannel, open_serial

OPEN_TC_THRESHOLD = 9.0e37  # the 34970A's overload reading is ±9.9E+37 (docs/golden/keysight-34970a.md)
TC_TYPES = ("K", "T")
DEFAULT_CHANNELS = (101, 102, 103, 104)  # the first four channels of a 34901A multiplexer


@dataclass
class Scan:
    """One scan: °C per channel (None = open thermocouple) and the open channels."""

    temps_c: dict[int, float | None]
    open_channels: list[int] = field(default_factory=list)


class ThermocoupleReader(Driver):
    """A Keysight 34970A/34972A-class data logger scanning thermocouples (SCPI). Temperatures in degC."""

    kind = "thermocouple_reader"
    streams = False

    def __init__(self, port: serial.SerialBase, *, timeout_s: float = 1.0, on_traffic=None,
                 monitor_channels: list[int] | None = None, tc_type: str = "K"):
        self.port = port
        self.name = "thermocouples"
        self.timeout_s = check_timeout(timeout_s)
        self.channel = LineChannel(port, self.timeout_s, self.name, on_traffic)
        self.channels: list[int] = []
        self.monitor_channels = list(monitor_channels or DEFAULT_CHANNELS)
        self.tc_type = tc_type

    @classmethod
    def open(cls, url: str, *, baudrate: int = 57600, timeout_s: float = 1.0, **kwargs) -> "ThermocoupleReader":
        return cls(open_serial(url, baudrate, timeout_s), timeout_s=timeout_s, **kwargs)

    def close(self) -> None:
        self.port.close()

    def identify(self) -> dict[str, str]:
        return self.channel.identify()

    def configure(self, channels: list[int], tc_type: str = "K") -> None:
        """Type ``tc_type`` thermocouples on ``channels`` (e.g. 101..108), °C, internal reference
        junction, open-thermocouple check on, scanned in the given order. Checks the error queue."""
        if tc_type not in TC_TYPES:
            raise ValueError(f"thermocouple type must be one of {TC_TYPES}, got {tc_type!r}")
        if not 1 <= len(channels) <= 20:
            raise ValueError("between 1 and 20 channels")
        chans = "(@" + ",".join(str(c) for c in channels) + ")"
        for line in ("*CLS", f"CONF:TEMP TC,{tc_type},{chans}", f"UNIT:TEMP C,{chans}",
                     f"SENS:TEMP:TRAN:TC:RJUN:TYPE INT,{chans}", f"SENS:TEMP:TRAN:TC:CHEC ON,{chans}", f"ROUT:SCAN {chans}"):
            self.channel.send(line)
        self.check_errors()
        self.channels = list(channels)

    def check_errors(self) -> None:
        """Raise :class:`DeviceFault` with the first queued SCPI error, after draining the queue."""
        errors = []
        for _ in range(11):
            answer = self.channel.query("SYST:ERR?")
            if answer.startswith("+0") or answer.startswith("0,"):
                break
            errors.append(answer)
        if errors:
            raise DeviceFault(f"thermocouples: instrument reports {'; '.join(errors)}")

    def read(self) -> Scan:
        """One scan of the configured channels."""
        if not self.channels:
            raise ValueError("configure() the channels before reading")
        answer = self.channel.query("READ?")
        try:
            values = [float(v) for v in answer.split(",")]
        except ValueError:
            raise ProtocolError(f"thermocouples: READ? answered {answer!r}") from None
        if len(values) != len(self.channels):
            raise ProtocolError(f"thermocouples: {len(values)} values for {len(self.channels)} channels")
        scan = Scan({})
        for ch, v in zip(self.channels, values):
            if not math.isfinite(v) or abs(v) >= OPEN_TC_THRESHOLD:  # overload, either sign: not a temperature
                scan.temps_c[ch] = None
                scan.open_channels.append(ch)
            else:
                scan.temps_c[ch] = v
        return scan

    def monitor_columns(self) -> list[str]:
        """Configure the monitored channels (if not configured yet) and name one column per channel (degC)."""
        if not self.channels:
            self.configure(self.monitor_channels, self.tc_type)
        return [f"ch{c}" for c in self.channels]

    def monitor(self) -> dict[str, float]:
        """One scan, °C per channel column; an open thermocouple reads NaN."""
        scan = self.read()
        return {f"ch{c}": (math.nan if v is None else v) for c, v in scan.temps_c.items()}

    def reference_junction_c(self, channel: int) -> float:
        """Reference (cold) junction temperature in °C used for ``channel``."""
        answer = self.channel.query(f"SENS:TEMP:TRAN:TC:RJUN? (@{channel})")
        try:
            value = float(answer)
        except ValueError:
            raise ProtocolError(f"thermocouples: RJUN? answered {answer!r}") from None
        if not math.isfinite(value):
            raise ProtocolError(f"thermocouples: RJUN? answered {answer!r}, not a temperature")
        return value

    def safe_state(self) -> str:
        """A logger only measures: nothing to make safe."""
        return "nothing to make safe (measures only)"
