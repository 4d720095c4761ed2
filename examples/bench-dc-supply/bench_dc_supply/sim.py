"""A simulated Rigol DP832: three outputs, the SCPI of the DP800 Programming Guide, on its RS-232
line (``sim://NAME``, a pty under ``bench sim serve``) and its LAN socket (port 5555 under ``bench
sim serve``), each output a power source another simulated instrument can draw from
(bench/sim/power.py: a unit under test).

Each output is a constant-voltage source up to its current limit:

* on, not tripped: ``voltage`` at the terminals while the load draws at most ``current`` (CV);
  a load demanding more (after its inrush, ``CC_AFTER_S``) holds the output at the limit (CC), the
  voltage falls as across the load's resistance at the set voltage, and a unit below its range
  stays off (it browns out);
* OVP on and a set voltage above its level: the output trips off when switched on or raised;
  OCP on and the load's current above its level at any change (the switch-on inrush included):
  it trips off. A trip reads back ``YES`` on ``:OUTP:OVP:QUES?`` / ``:OUTP:OCP:QUES?`` until
  ``:OUTP:OVP:CLEAR`` / ``:OUTP:OCP:CLEAR``, and the output stays off until switched on again.
* ``:MEAS:VOLT?`` / ``:MEAS:CURR?`` read the terminals (V to 1 mV, A to 0.1 mA: the digits of the
  guide's examples); off or tripped: 0.

Ranges are the DP832's (Programming Guide, ``:APPLy`` table: CH1 and CH2 0–32 V / 0–3.2 A, CH3
0–5.3 V / 0–3.2 A); a value outside answers error -222 "Data out of range", an unknown header
-113 "Undefined header" (SCPI's standard error numbers, as ``:SYST:ERR?`` reads them). *RST and
power-up: every output off at 0 V, the current limit at the range's default, protection off.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import functools

from bench.sim.line_device import LineDeviceSim
from bench_dc_supply.dp832 import DEFAULT_CURRENT_A, MODEL, RANGES, VENDOR

CC_AFTER_S = 0.01
"""[U] The supply regulates the steady state: a load's demand is compared with the current limit this
long after a change (its inrush is over), and with the OCP level at the change."""


@dataclass
class Output:
    """One output of the supply, a power source (bench/sim/power.py)."""

    n: int
    clock: object
    voltage: float = 0.0
    current: float = 3.0
    on: bool = False
    ovp_on: bool = False
    ovp: float = 33.0
    ocp_on: bool = False
    ocp: float = 3.3
    ovp_tripped: bool = False
    ocp_tripped: bool = False
    browned_out: bool = False
    load: object = None
    t_on: float = 0.0
    injected: list[str] = field(default_factory=list)

    # ---- PowerSource ------------------------------------------------------------------------
    def attach(self, load) -> None:  # noqa: ANN001 - a bench.sim.power.PowerLoad
        self.load = load

    def volts_at(self, t: float) -> float:
        if not self.on or self.ovp_tripped or self.ocp_tripped:
            return 0.0
        if self.browned_out and self.load is not None:
            demand = self._demand(t)
            return self.voltage * self.current / demand if demand > self.current else self.voltage
        return self.voltage

    def load_changed(self, t: float) -> None:
        self._check(t)

    # ---- the supply's side ------------------------------------------------------------------
    def amps_at(self, t: float) -> float:
        if self.volts_at(t) == 0.0 or self.load is None:
            return 0.0
        if self.browned_out:
            return self.current
        return float(self.load.current_a(t, self.voltage))

    def mode(self, t: float) -> str:
        if not self.on:
            return "UR"
        return "CC" if self.browned_out else "CV"

    def _demand(self, t: float) -> float:
        """What the load draws at the set voltage once its inrush is over (A)."""
        return float(self.load.current_a(t + CC_AFTER_S, self.voltage)) if self.load is not None else 0.0

    def _tell(self, t: float) -> None:
        if self.load is not None:
            self.load.supply_changed(t, self.volts_at(t))

    def _trip(self, t: float, which: str) -> None:
        setattr(self, f"{which}_tripped", True)
        self.on = False
        self.browned_out = False
        self._tell(t)

    def _check(self, t: float) -> None:
        """Protection and current limit at run time ``t`` (a change of the output or of its load)."""
        if not self.on or self.ovp_tripped or self.ocp_tripped:
            return
        if self.ovp_on and self.voltage > self.ovp:
            self._trip(t, "ovp")
            return
        if self.load is None:
            return
        if self.ocp_on and self.load.current_a(t, self.voltage) > self.ocp:
            self._trip(t, "ocp")
            return
        was = self.browned_out
        self.browned_out = self._demand(t) > self.current
        if self.browned_out != was:
            self._tell(t)

    def switch(self, t: float, on: bool) -> None:
        if on == self.on:
            return
        self.on = on
        self.browned_out = False
        self.t_on = t
        if on and (self.ovp_tripped or self.ocp_tripped):
            self.on = False  # a tripped output stays off until its protection is cleared
            return
        if on and self.ovp_on and self.voltage > self.ovp:
            self._trip(t, "ovp")
            return
        self._tell(t)
        self._check(t)

    def set_voltage(self, t: float, volts: float) -> None:
        self.voltage = volts
        if self.on:
            self._tell(t)
            self._check(t)

    def set_current(self, t: float, amps: float) -> None:
        self.current = amps
        if self.on:
            self._check(t)


class Dp800Sim(LineDeviceSim):
    """The DP832 (see the module docstring). ``serial``: what ``*IDN?`` reports as its serial."""

    def __init__(self, clock, serial: str = "DP8C000000001", baudrate: int = 9600, firmware: str = "00.01.14"):
        super().__init__(clock, baudrate)
        self.eol = b"\n"  # the DP800 ends its answers with LF
        self.serial = serial
        self.firmware = firmware
        self.outputs = {n: Output(n, clock) for n in RANGES}
        self.errors: list[str] = []
        self.selected = 1
        self.faults: set[str] = set()
        self._reset()

    def _reset(self) -> None:
        t = self.clock.now()
        for n, out in self.outputs.items():
            out.switch(t, False)
            out.voltage, out.current = 0.0, DEFAULT_CURRENT_A[n]
            out.ovp_on = out.ocp_on = False
            out.ovp, out.ocp = RANGES[n][0] * 1.1, RANGES[n][1] * 1.1
        self.selected = 1

    # ---- faults (bench/faults.py) -----------------------------------------------------------
    def inject(self, fault: str, **params) -> None:
        """``trip``: output ``output`` (default 1) trips its over-current protection now, as when the
        unit's draw jumps above the OCP level."""
        if fault != "trip":
            raise ValueError(f"the simulated DP832 cannot do fault {fault!r}")
        out = self.outputs[int(params.get("output", 1))]
        if out.on:
            out._trip(self.clock.now(), "ocp")  # noqa: SLF001 - the supply's own output

    def clear_faults(self) -> None:
        """A trip stays until cleared over SCPI, as on the real supply."""

    # ---- SCPI -------------------------------------------------------------------------------
    def _error(self, code: int, text: str) -> None:
        if len(self.errors) < 20:
            self.errors.append(f'{code},"{text}"')

    def on_line(self, line: str) -> None:
        for command in line.split(";"):
            command = command.strip()
            if command:
                header, _, args = command.partition(" ")
                try:
                    self._command(header.lstrip(":"), [a.strip() for a in args.split(",")] if args.strip() else [])
                except _Bad as bad:
                    self._error(*bad.args)

    def _channel(self, text: str | None) -> int:
        """``CH1``..``CH3`` (or a bare number); the selected output when omitted."""
        if text is None or text == "":
            return self.selected
        m = re.fullmatch(r"(?:CH)?([1-3])", text.strip().upper())
        if m is None:
            raise _Bad(-224, "Illegal parameter value")
        return int(m.group(1))

    def _number(self, text: str, lo: float, hi: float) -> float:
        t = text.strip().upper()
        if t in ("MIN", "MINIMUM"):
            return lo
        if t in ("MAX", "MAXIMUM"):
            return hi
        try:
            v = float(t)
        except ValueError:
            raise _Bad(-104, "Data type error") from None
        if not lo <= v <= hi:
            raise _Bad(-222, "Data out of range")
        return v

    def _bool(self, text: str) -> bool:
        t = text.strip().upper()
        if t not in ("ON", "OFF", "1", "0"):
            raise _Bad(-224, "Illegal parameter value")
        return t in ("ON", "1")

    def _source(self, header: str) -> tuple[int, str]:
        """``SOUR2:VOLT`` -> (2, ``VOLT``); ``VOLT`` -> (selected, ``VOLT``)."""
        m = re.match(r"(?i)SOUR(?:CE)?([1-3])?:(.*)", header)
        if m is None:
            return self.selected, header
        return (int(m.group(1)) if m.group(1) else self.selected), m.group(2)

    def _command(self, header: str, args: list[str]) -> None:
        t = self.clock.now()
        h = header.upper()
        if h == "*IDN?":
            self.reply(f"{VENDOR},{MODEL},{self.serial},{self.firmware}")
        elif h == "*RST":
            self._reset()
        elif h == "*CLS":
            self.errors.clear()
        elif header_matches("SYSTem:ERRor?", header):
            self.reply(self.errors.pop(0) if self.errors else '0,"No error"')
        elif header_matches("SYSTem:REMote", header) or header_matches("SYSTem:LOCal", header):
            pass
        elif header_matches("INSTrument:NSELect", header):
            self.selected = self._channel(args[0] if args else "")
        elif header_matches("INSTrument:NSELect?", header):
            self.reply(str(self.selected))
        elif header_matches("INSTrument[:SELect]", header):
            self.selected = self._channel(args[0] if args else "")
        elif header_matches("INSTrument[:SELect]?", header):
            self.reply(f"CH{self.selected}")
        elif header_matches("APPLy", header):
            n = self._channel(args[0] if args else "")
            self.selected = n
            vmax, imax = RANGES[n]
            out = self.outputs[n]
            if len(args) > 1:
                out.set_voltage(t, self._number(args[1], 0.0, vmax))
            if len(args) > 2:
                out.set_current(t, self._number(args[2], 0.0, imax))
        elif header_matches("APPLy?", header):
            n = self._channel(args[0] if args else "")
            vmax, imax = RANGES[n]
            out = self.outputs[n]
            self.reply(f"CH{n}:{vmax:g}V/{imax:g}A,{out.voltage:.3f},{out.current:.4f}")
        elif header_matches("MEASure[:VOLTage][:DC]?", header):
            self.reply(f"{self.outputs[self._channel(args[0] if args else '')].volts_at(t):.3f}")
        elif header_matches("MEASure:CURRent[:DC]?", header):
            self.reply(f"{self.outputs[self._channel(args[0] if args else '')].amps_at(t):.4f}")
        elif header_matches("MEASure:ALL[:DC]?", header):
            out = self.outputs[self._channel(args[0] if args else "")]
            v, i = out.volts_at(t), out.amps_at(t)
            self.reply(f"{v:.3f},{i:.4f},{v * i:.3f}")
        elif header_matches("OUTPut[:STATe]", header):
            n, state = self._channel_and_value(args)
            self.outputs[n].switch(t, self._bool(state))
        elif header_matches("OUTPut[:STATe]?", header):
            self.reply("ON" if self.outputs[self._channel(args[0] if args else "")].on else "OFF")
        elif header_matches("OUTPut:CVCC?", header) or header_matches("OUTPut:MODE?", header):
            self.reply(self.outputs[self._channel(args[0] if args else "")].mode(t))
        elif (m := re.fullmatch(r"(?i)OUTP(?:ut)?:(OVP|OCP)(:STAT(?:e)?|:VAL(?:ue)?|:QUES(?:tion)?|:CLE(?:AR)?)?(\?)?", header)):
            self._protection(m.group(1).lower(), (m.group(2) or ":STAT").upper(), bool(m.group(3)), args, t)
        else:
            n, sub = self._source(header)
            self._source_command(n, sub.upper(), args, t)

    def _channel_and_value(self, args: list[str]) -> tuple[int, str]:
        if len(args) == 2:
            return self._channel(args[0]), args[1]
        if len(args) == 1:
            return self.selected, args[0]
        raise _Bad(-109, "Missing parameter")

    def _protection(self, which: str, what: str, query: bool, args: list[str], t: float) -> None:
        if what.startswith(":STAT"):
            if query:
                n = self._channel(args[0] if args else "")
                self.reply("ON" if getattr(self.outputs[n], f"{which}_on") else "OFF")
            else:
                n, state = self._channel_and_value(args)
                setattr(self.outputs[n], f"{which}_on", self._bool(state))
                self.outputs[n].load_changed(t)
        elif what.startswith(":VAL"):
            if query:
                n = self._channel(args[0] if args else "")
                self.reply(f"{getattr(self.outputs[n], which):.4f}")
            else:
                n, value = self._channel_and_value(args)
                hi = RANGES[n][0] * 1.1 if which == "ovp" else RANGES[n][1] * 1.1
                setattr(self.outputs[n], which, self._number(value, 0.01, hi))
                self.outputs[n].load_changed(t)
        elif what.startswith(":QUES"):
            if not query:
                raise _Bad(-113, "Undefined header")
            n = self._channel(args[0] if args else "")
            self.reply("YES" if getattr(self.outputs[n], f"{which}_tripped") else "NO")
        elif what.startswith(":CLE"):
            n = self._channel(args[0] if args else "")
            setattr(self.outputs[n], f"{which}_tripped", False)

    def _source_command(self, n: int, sub: str, args: list[str], t: float) -> None:
        vmax, imax = RANGES[n]
        out = self.outputs[n]
        if re.fullmatch(r"VOLT(AGE)?(:LEV(EL)?)?(:IMM(EDIATE)?)?(:AMPL(ITUDE)?)?", sub):
            out.set_voltage(t, self._number(args[0] if args else "", 0.0, vmax))
        elif re.fullmatch(r"VOLT(AGE)?(:LEV(EL)?)?(:IMM(EDIATE)?)?(:AMPL(ITUDE)?)?\?", sub):
            self.reply(f"{out.voltage:.3f}")
        elif re.fullmatch(r"CURR(ENT)?(:LEV(EL)?)?(:IMM(EDIATE)?)?(:AMPL(ITUDE)?)?", sub):
            out.set_current(t, self._number(args[0] if args else "", 0.0, imax))
        elif re.fullmatch(r"CURR(ENT)?(:LEV(EL)?)?(:IMM(EDIATE)?)?(:AMPL(ITUDE)?)?\?", sub):
            self.reply(f"{out.current:.4f}")
        else:
            raise _Bad(-113, "Undefined header")


class _Bad(Exception):
    """An SCPI error (code, text) for the error queue."""


@functools.lru_cache(maxsize=256)
def _pattern(pattern: str) -> re.Pattern[str]:
    """A SCPI header pattern in mixed case with optional nodes anywhere (``OUTPut[:STATe]?``,
    ``MEASure[:VOLTage][:DC]?``) as a regex: each node its short form (the upper-case letters) or
    long form, case-insensitively (SCPI-99 section 6)."""
    out = ""
    for optional, node in re.findall(r"(\[?):?([A-Za-z*]+)\]?", pattern.replace("?", "")):
        short = "".join(c for c in node if c.isupper() or c == "*")
        alt = f"(?:{re.escape(node.upper())}|{re.escape(short)})"
        sep = ":" if out else ":?"
        out += f"(?:{sep}{alt})?" if optional else f"{sep}{alt}"
    return re.compile(out + (r"\?" if pattern.endswith("?") else ""), re.IGNORECASE)


def header_matches(pattern: str, header: str) -> bool:
    """Does ``header`` (as received) match ``pattern`` (:func:`_pattern`)?"""
    return _pattern(pattern).fullmatch(header.lstrip(":")) is not None
