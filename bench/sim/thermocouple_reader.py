"""Simulated thermocouple data logger: a Keysight 34970A with a 34901A multiplexer (SCPI over RS-232).

Subset served (``docs/thermocouples.md``; the command forms follow the 34970A User's Guide as
collected in ``../shared/protocols.md`` section 3a): ``*IDN?``, ``*RST``, ``*CLS``,
``CONF:TEMP TC,<K|T>,(@list)``, ``UNIT:TEMP C,(@list)``, ``SENS:TEMP:TRAN:TC:RJUN:TYPE INT,(@list)``,
``SENS:TEMP:TRAN:TC:CHEC ON|OFF,(@list)``, ``ROUT:SCAN (@list)``, ``READ?``,
``SENS:TEMP:TRAN:TC:RJUN? (@ch)`` (internal reference-junction temperature, °C [U]),
``SYST:ERR?``. Errors go to the SCPI error queue (-113 undefined header, -222 data out of range,
-224 illegal parameter value), as on the instrument.

Temperatures come from the world: every channel reads the unit's temperature (°C) plus its
an open thermocouple (fault hook ``open_channels``) reads +9.9E+37 when the open-TC check is on
(overload value [U-]) and, without the check, the reference-junction temperature (no thermo-EMF).
"""

from __future__ import annotations

from bench import __version__
from bench.sim.line_device import LineDeviceSim
from bench.sim.scpi import header_matches, parse_channel_list
from bench.sim.world import World

OVERLOAD = 9.9e37
CHANNELS = range(101, 121)  # 34901A: 20 channels


class ThermocoupleReaderSim(LineDeviceSim):
    def __init__(self, clock, world: World, serial_number: str = "SIM-0003", open_channels: tuple[int, ...] = (),
                 baudrate: int = 57600):
        super().__init__(clock, baudrate)
        self.world = world
        self.serial_number = serial_number
        self.open_channels = set(open_channels)
        self._reset()

    def _reset(self) -> None:
        self.tc_type: dict[int, str] = {}
        self.check: set[int] = set()
        self.scan: list[int] = []
        self.errors: list[str] = []

    # ---- SCPI -------------------------------------------------------------------------------
    def _error(self, code: int, text: str) -> None:
        if len(self.errors) < 10:
            self.errors.append(f'{code:+d},"{text}"')

    def _answer(self, text: str) -> None:
        self.reply(text, b"\n")

    def on_line(self, line: str) -> None:
        for command in line.split(";"):
            command = command.strip()
            if command:
                header, _, args = command.partition(" ")
                self._command(header, args.strip())

    def _channels(self, text: str) -> list[int] | None:
        try:
            chans = parse_channel_list(text)
        except ValueError:
            self._error(-224, "Illegal parameter value")
            return None
        if any(c not in CHANNELS for c in chans):
            self._error(-222, "Data out of range")
            return None
        return chans

    def _command(self, header: str, args: str) -> None:
        parts = [p.strip() for p in _split_args(args)]
        if header.upper() == "*IDN?":
            self._answer(f"bench-sim,34970A,{self.serial_number},sim-{__version__}")
        elif header.upper() == "*RST":
            self._reset()
        elif header.upper() == "*CLS":
            self.errors.clear()
        elif header_matches("SYSTem:ERRor?", header):
            self._answer(self.errors.pop(0) if self.errors else '+0,"No error"')
        elif header_matches("CONFigure:TEMPerature", header):
            if len(parts) != 3 or parts[0].upper() != "TC" or parts[1].upper() not in ("K", "T", "J", "E", "N", "R", "S", "B"):
                self._error(-224, "Illegal parameter value")
                return
            chans = self._channels(parts[2])
            if chans is not None:
                for c in chans:
                    self.tc_type[c] = parts[1].upper()
                self.scan = chans
        elif header_matches("UNIT:TEMPerature", header):
            if len(parts) != 2 or parts[0].upper() not in ("C", "CEL"):
                self._error(-224, "Illegal parameter value")  # the simulator reports in C only
                return
            self._channels(parts[1])
        elif header_matches("[SENSe:]TEMPerature:TRANsducer:TCouple:RJUNction:TYPE", header):
            if len(parts) != 2 or parts[0].upper() not in ("INT", "INTERNAL"):
                self._error(-224, "Illegal parameter value")
                return
            self._channels(parts[1])
        elif header_matches("[SENSe:]TEMPerature:TRANsducer:TCouple:CHECk", header):
            if len(parts) != 2 or parts[0].upper() not in ("ON", "OFF", "1", "0"):
                self._error(-224, "Illegal parameter value")
                return
            chans = self._channels(parts[1])
            if chans is not None:
                if parts[0].upper() in ("ON", "1"):
                    self.check.update(chans)
                else:
                    self.check.difference_update(chans)
        elif header_matches("ROUTe:SCAN", header):
            chans = self._channels(args)
            if chans is not None:
                self.scan = chans
        elif header_matches("[SENSe:]TEMPerature:TRANsducer:TCouple:RJUNction?", header):
            # the logger stands outside the chamber: its reference junction is at room temperature
            self._answer(f"{self.world.p.ambient_temp_c:+.8E}")
        elif header_matches("READ?", header):
            if not self.scan:
                self._error(-221, "Settings conflict")
                self._answer("")
                return
            self._answer(",".join(f"{v:+.8E}" for v in self.read_values()))
        else:
            self._error(-113, "Undefined header")

    def read_values(self) -> list[float]:
        """One scan: °C per channel in scan order (overload value for open, checked channels)."""
        t = self.world.chamber.mount_temp_c(self.clock.now())  # thermocouples sit on the mount (NPSAT1 IV.B)
        out = []
        for c in self.scan:
            if c in self.open_channels:
                out.append(OVERLOAD if c in self.check else self.world.p.ambient_temp_c)
            else:
                out.append(t)
        return out


def _split_args(args: str) -> list[str]:
    """Split SCPI parameters on commas outside parentheses."""
    out, depth, cur = [], 0, ""
    for ch in args:
        if ch == "(":
            depth += 1
        elif ch == ")":
            depth -= 1
        if ch == "," and depth == 0:
            out.append(cur)
            cur = ""
        else:
            cur += ch
    if cur.strip():
        out.append(cur)
    return out
