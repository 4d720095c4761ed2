"""Driver of a Rigol DP800-series programmable DC supply (DP832: three outputs), SCPI over RS-232,
or over its LAN socket (a ``socket://HOST:5555`` URL, pyserial's), one command per line.

The commands are those of RIGOL's *DP800 Programming Guide* (README.md of this package cites the
pages) in the forms two drivers written for the real DP800 send: select an output with
``:INST:NSEL n`` and set it with ``:VOLT`` / ``:CURR`` (sigrok's scpi-pps profile of the DP800),
name it in ``:OUTP CHn,ON``, ``:MEAS:VOLT? CHn``, ``:OUTP:OCP:QUES? CHn`` (gotmc/ivi's dp800).
Every setting is checked with ``:SYST:ERR?``; switching an output is confirmed by reading its
state back. Volts in V, amperes in A, times in s. Imports nothing of bench but its drivers layer.
"""

from __future__ import annotations

from dataclasses import dataclass

import serial

from drivers.base import Driver, check_timeout
from drivers.clock import WallClock
from drivers.errors import DeviceFault, ProtocolError
from drivers.transport import LineChannel, open_serial

from bench_dc_supply.dp832 import RANGES

ERROR_QUEUE_MAX = 10
"""Most errors drained from ``:SYST:ERR?`` in one check."""


@dataclass(frozen=True)
class OutputSetting:
    """How the lab sets an output to power its unit: ``voltage`` (V), ``current`` limit (A), the
    over-voltage and over-current protection levels (V, A; None: protection off), and how long the
    unit takes to come up after the output is switched on (``settle_s``)."""

    voltage: float
    current: float
    ovp: float | None = None
    ocp: float | None = None
    settle_s: float = 0.5


@dataclass
class OutputReading:
    """One output read back: ``on``, measured volts and amperes, regulation ``mode`` (CV, CC, UR), and
    whether its over-voltage / over-current protection tripped."""

    on: bool
    volts: float
    amps: float
    mode: str
    ovp_tripped: bool
    ocp_tripped: bool

    def describe(self) -> str:
        trips = " ".join(w for w, t in (("OVP tripped", self.ovp_tripped), ("OCP tripped", self.ocp_tripped)) if t)
        return (f"{'on' if self.on else 'off'}, {self.volts:.3f} V, {self.amps:.4f} A ({self.mode})" + (f", {trips}" if trips else ""))


class DcSupply(Driver):
    """A DP800-class supply. ``outputs``: output number (``"1"``..) -> :class:`OutputSetting` of the
    outputs this lab uses (the others are left alone)."""

    kind = "dc_supply"
    streams = False
    read_attempts = 1

    def __init__(self, port: serial.SerialBase, *, timeout_s: float = 1.0, on_traffic=None,
                 outputs: dict[str, OutputSetting] | None = None, clock=None, name: str = "dc_supply"):
        self.port = port
        self.name = name
        self.timeout_s = check_timeout(timeout_s)
        self.channel = LineChannel(port, self.timeout_s, self.name, on_traffic)
        self.outputs = dict(outputs or {})
        self.clock = clock or WallClock()

    @classmethod
    def open(cls, url: str, *, baudrate: int = 9600, timeout_s: float = 1.0, **kwargs) -> "DcSupply":
        """``url``: a serial port (``/dev/ttyUSB3``, RS-232 at the supply's rate, default 9600) or its
        LAN socket (``socket://192.168.1.40:5555``)."""
        return cls(open_serial(url, baudrate, timeout_s), timeout_s=timeout_s, **kwargs)

    def close(self) -> None:
        self.port.close()

    # ---- identity and errors ----------------------------------------------------------------
    def identify(self) -> dict[str, str]:
        """``*IDN?``: ``RIGOL TECHNOLOGIES,DP832,<serial>,<firmware>``."""
        return self.channel.identify()

    def check_errors(self, doing: str) -> None:
        """Drain ``:SYST:ERR?``; :class:`DeviceFault` naming what was being done if any error was queued."""
        errors = []
        for _ in range(ERROR_QUEUE_MAX):
            answer = self.channel.query(":SYST:ERR?")
            if answer.startswith(("0,", "+0,")):
                break
            errors.append(answer)
        if errors:
            raise DeviceFault(f"{self.name}: {doing}: the supply reports {'; '.join(errors)}")

    # ---- settings ---------------------------------------------------------------------------
    def _check_output(self, output: str) -> int:
        if not str(output).isdigit() or int(output) not in RANGES:
            raise ValueError(f"{self.name}: output {output!r}: the DP832 has outputs {', '.join(map(str, RANGES))}")
        return int(output)

    def set_output(self, output: str, volts: float | None = None, amps: float | None = None) -> None:
        """Program output ``output``'s voltage (V) and current limit (A) (``None``: left as it is)."""
        n = self._check_output(output)
        self.channel.send(f":INST:NSEL {n}")
        if volts is not None:
            self.channel.send(f":VOLT {volts:.3f}")
        if amps is not None:
            self.channel.send(f":CURR {amps:.4f}")
        self.check_errors(f"setting output {n} to {volts} V, {amps} A")

    def set_protection(self, output: str, ovp: float | None, ocp: float | None) -> None:
        """Over-voltage (V) and over-current (A) protection of ``output``: on at that level, off for None."""
        n = self._check_output(output)
        for what, level in (("OVP", ovp), ("OCP", ocp)):
            if level is not None:
                self.channel.send(f":OUTP:{what}:VAL CH{n},{level:.4f}")
            self.channel.send(f":OUTP:{what} CH{n},{'ON' if level is not None else 'OFF'}")
        self.check_errors(f"setting output {n}'s protection (OVP {ovp} V, OCP {ocp} A)")

    def clear_trips(self, output: str) -> None:
        """Clear a tripped over-voltage or over-current protection of ``output`` (the output stays off)."""
        n = self._check_output(output)
        self.channel.send(f":OUTP:OVP:CLEAR CH{n}")
        self.channel.send(f":OUTP:OCP:CLEAR CH{n}")
        self.check_errors(f"clearing output {n}'s protection")

    def switch(self, output: str, on: bool) -> bool:
        """Switch ``output`` on or off and read its state back; :class:`DeviceFault` if it is not as told
        (a tripped protection keeps it off). Returns the state read back."""
        n = self._check_output(output)
        self.channel.send(f":OUTP CH{n},{'ON' if on else 'OFF'}")
        self.check_errors(f"switching output {n} {'on' if on else 'off'}")
        state = self._on_off(self.channel.query(f":OUTP? CH{n}"), f":OUTP? CH{n}")
        if state != on:
            r = self.read(output)
            raise DeviceFault(f"{self.name}: output {n} told {'on' if on else 'off'} reads {'on' if state else 'off'} ({r.describe()})")
        return state

    # ---- readings ---------------------------------------------------------------------------
    def read(self, output: str) -> OutputReading:
        """Output ``output`` as it is: state, measured V and A, mode, protection trips (changes nothing)."""
        n = self._check_output(output)
        on = self._on_off(self.channel.query(f":OUTP? CH{n}"), f":OUTP? CH{n}")
        volts = self._number(self.channel.query(f":MEAS:VOLT? CH{n}"), f":MEAS:VOLT? CH{n}")
        amps = self._number(self.channel.query(f":MEAS:CURR? CH{n}"), f":MEAS:CURR? CH{n}")
        mode = self.channel.query(f":OUTP:CVCC? CH{n}").strip().upper()
        ovp = self._yes_no(self.channel.query(f":OUTP:OVP:QUES? CH{n}"), f":OUTP:OVP:QUES? CH{n}")
        ocp = self._yes_no(self.channel.query(f":OUTP:OCP:QUES? CH{n}"), f":OUTP:OCP:QUES? CH{n}")
        return OutputReading(on, volts, amps, mode, ovp, ocp)

    def monitor_columns(self) -> list[str]:
        """``voltageN`` (V) and ``currentN`` (A) of each output the lab uses (units: the kind's)."""
        return [c for n in sorted(self.outputs) for c in (f"voltage{n}", f"current{n}")]

    def monitor(self) -> dict[str, float]:
        """Measured voltage (V) and current (A) of each output the lab uses."""
        out: dict[str, float] = {}
        for n in sorted(self.outputs):
            out[f"voltage{n}"] = self._number(self.channel.query(f":MEAS:VOLT? CH{n}"), f":MEAS:VOLT? CH{n}")
            out[f"current{n}"] = self._number(self.channel.query(f":MEAS:CURR? CH{n}"), f":MEAS:CURR? CH{n}")
        return out

    # ---- powering the unit ------------------------------------------------------------------
    def power_up(self, output: str) -> str:
        """Power what ``output`` feeds as the lab set it: protection, voltage, current limit, a
        tripped protection cleared, output on; wait its settle time on the lab's clock, then read it
        back. :class:`DeviceFault` when a protection tripped (the unit drew too much, or its voltage
        was above the OVP level). Returns what it reads."""
        s = self.outputs.get(str(output))
        if s is None:
            raise ValueError(f"{self.name}: output {output!r} is not set up in the lab config (outputs: {', '.join(self.outputs) or 'none'})")
        self.set_protection(output, s.ovp, s.ocp)
        self.set_output(output, s.voltage, s.current)
        self.clear_trips(output)
        self.switch(output, True)
        self.clock.sleep(s.settle_s)
        r = self.read(output)
        if r.ovp_tripped or r.ocp_tripped or not r.on:
            raise DeviceFault(f"{self.name}: output {output} after power-up: {r.describe()}")
        return r.describe()

    def safe_state(self) -> str:
        """Every output the lab uses switched off, each confirmed by reading ``:OUTP?`` back as OFF."""
        told = []
        for n in sorted(self.outputs):
            self.switch(n, False)
            told.append(f"output {n} off (read back OFF)")
        return "; ".join(told) if told else "no output set up in the lab config: nothing switched"

    # ---- answers ----------------------------------------------------------------------------
    def _number(self, answer: str, what: str) -> float:
        try:
            return float(answer)
        except ValueError:
            raise ProtocolError(f"{self.name}: {what} answered {answer!r}, not a number") from None

    def _on_off(self, answer: str, what: str) -> bool:
        a = answer.strip().upper()
        if a not in ("ON", "OFF", "1", "0"):
            raise ProtocolError(f"{self.name}: {what} answered {answer!r}, not ON or OFF")
        return a in ("ON", "1")

    def _yes_no(self, answer: str, what: str) -> bool:
        a = answer.strip().upper()
        if a not in ("YES", "NO", "1", "0"):
            raise ProtocolError(f"{self.name}: {what} answered {answer!r}, not YES or NO")
        return a in ("YES", "1")
