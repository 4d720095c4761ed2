"""Simulated thermocouple data logger: a Keysight 34970A with a 34901A multiplexer (SCPI over RS-232).

Subset served (``docs/thermocouples.md``; the command forms follow the 34970A User's Guide as
collected in ``../shared/protocols.md`` section 3a): ``*IDN?``, ``*RST``, ``*CLS``,
``CONF:TEMP TC,<K|T>,(@list)``, ``UNIT:TEMP C,(@list)``, ``SENS:TEMP:TRAN:TC:RJUN:TYPE INT,(@list)``,
``SENS:TEMP:TRAN:TC:CHEC ON|OFF,(@list)``, ``ROUT:SCAN (@list)``, ``READ?``, ``INIT`` +
``FETC?``, ``SENS:TEMP:TRAN:TC:RJUN? (@ch)`` (internal reference-junction temperature, °C [U]),
``SYST:ERR?``. Errors go to the SCPI error queue (-113 undefined header, -221 settings conflict,
-222 data out of range, -224 illegal parameter value, -230 ``FETC?`` without readings [U]), as on
the instrument. Answers end with CR LF on RS-232 (as a 34970A's do) and with LF on the 34972A's
LAN socket (:meth:`~bench.sim.line_device.LineDeviceSim.exchange`, ``bench.sim.scpi_socket``).

Measurement chain (``docs/thermocouples.md``, "Simulated physics"): per scan and channel the
true junction temperature (the mount by default, or the chamber air / sensor die per ``points``),
the thermo-EMF of the installed thermocouple (``installed_types``, NIST ITS-90 reference functions
in :mod:`bench.sim.thermocouple_emf`) relative to the logger's terminals at room temperature,
plus DMM voltage noise, quantised at the DMM resolution; the logger converts back with the
*configured* type and its internal reference-junction temperature as measured (with its own
offset), so a channel configured for the wrong type reads wrong, as on the instrument. The
instrument figures come from a :class:`LoggerSpec`; the default (``spec=None``) is an ideal logger
(no noise, no quantisation, no reference-junction error).

Fault hooks: :meth:`ThermocoupleReaderSim.inject` (``open``, ``stuck``, ``runaway``, ``noisy``) and
:meth:`ThermocoupleReaderSim.clear_faults`; the ``open_channels`` constructor argument (or
attribute) makes channels open thermocouples. An open, checked channel reads +9.9E+37 (overload
value [U-]); an open channel without the check reads a floating input (random EMF).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from bench import __version__
from bench.sim.line_device import LineDeviceSim
from bench.sim.scpi import header_matches, parse_channel_list
from bench.sim.thermocouple_emf import emf_to_temp_c, temp_to_emf_mv
from bench.sim.world import World

OVERLOAD = 9.9e37
CHANNELS = range(101, 121)  # 34901A: 20 channels
POINTS = ("mount", "air", "die")
FAULTS = ("open", "stuck", "runaway", "noisy")


@dataclass(frozen=True)
class LoggerSpec:
    """Instrument figures of the simulated logger (sources in ``docs/thermocouples.md``)."""

    noise_uv_rms: float = 0.0
    """Gaussian voltage noise at the DMM input, µV rms per reading."""
    resolution_uv: float = 0.0
    """DMM resolution on the 100 mV range, µV (0: no quantisation)."""
    rj_accuracy_c: float = 0.0
    """Reference-junction accuracy, °C: the measured junction is off by a fixed offset drawn once
    (seeded) uniformly in ±rj_accuracy_c."""
    tc_accuracy_c: float = 0.0
    """Stated thermocouple accuracy (°C), including the reference-junction error (for checks)."""
    open_float_uv_rms: float = 50.0
    """Open channel without the open-TC check: floating input, µV rms per reading [U]."""
    exact_conversion: bool = True
    """Convert EMF to °C exactly (inverse of the reference function); False: with the NIST inverse
    polynomials (±0.06 °C K, ±0.04 °C T), as instrument firmware does — and 10x cheaper."""


IDEAL = LoggerSpec()
"""No noise, no quantisation, no reference-junction error (the default)."""
KEYSIGHT_34970A = LoggerSpec(noise_uv_rms=1.0, resolution_uv=1.0, rj_accuracy_c=0.8, tc_accuracy_c=1.0, exact_conversion=False)
"""34970A + 34901A at its 1 PLC / 5½-digit setting (docs/thermocouples.md, "Simulated physics")."""


class ThermocoupleReaderSim(LineDeviceSim):
    def __init__(self, clock, world: World, serial_number: str = "SIM-0003", open_channels: tuple[int, ...] = (),
                 baudrate: int = 57600, *, points: dict[int, str] | None = None, spec: LoggerSpec | None = None,
                 installed_types: str | dict[int, str] = "K", seed: int = 0):
        """``points``: channel → "mount" | "air" | "die" (default "mount"); ``spec``: instrument
        figures (None: :data:`IDEAL`); ``installed_types``: the thermocouple wire actually
        connected, one type for all channels or channel → type (default "K"); ``seed``: RNG seed."""
        super().__init__(clock, baudrate)
        self.world = world
        self.serial_number = serial_number
        self.open_channels = set(open_channels)
        self.points = dict(points or {})
        for ch, point in self.points.items():
            if ch not in CHANNELS or point not in POINTS:
                raise ValueError(f"thermocouple point mapping: channel {ch} -> {point!r}; channels 101..120, points {POINTS}")
        self.spec = spec or IDEAL
        if isinstance(installed_types, str):
            self.installed_types = {c: installed_types.upper() for c in CHANNELS}
        else:
            self.installed_types = {c: str(installed_types.get(c, "K")).upper() for c in CHANNELS}
        for ch, kind in self.installed_types.items():
            if kind not in ("K", "T"):
                raise ValueError(f"installed thermocouple type on channel {ch} must be K or T, got {kind!r}")
        self.rng = np.random.default_rng(seed)
        self.rj_offset_c = float(self.rng.uniform(-1.0, 1.0)) * self.spec.rj_accuracy_c
        self.faults: dict[int, dict] = {}
        self._reset()

    # ---- fault hooks ------------------------------------------------------------------------
    def inject(self, fault: str, channel: int | None = None, **params) -> None:
        """Inject ``fault`` on ``channel`` (None: every channel) from now on.

        ``open``: an open thermocouple (+9.9E+37 with the open-TC check on, else a floating input);
        ``stuck``: frozen at the value it reads now; ``runaway``: the junction climbs at
        ``rate_c_per_min`` (°C/min) from now; ``noisy``: extra Gaussian noise ``sigma_c`` (°C rms).
        A later fault on a channel replaces the earlier one."""
        if fault not in FAULTS:
            raise ValueError(f"unknown thermocouple fault {fault!r}; one of {FAULTS}")
        required = {"open": set(), "stuck": set(), "runaway": {"rate_c_per_min"}, "noisy": {"sigma_c"}}[fault]
        if set(params) != required:
            raise ValueError(f"fault {fault!r} takes parameters {sorted(required)}, got {sorted(params)}")
        if any(not math.isfinite(float(v)) for v in params.values()) or float(params.get("sigma_c", 0.0)) < 0:
            raise ValueError(f"fault {fault!r}: bad parameters {params}")
        chans = list(CHANNELS) if channel is None else [channel]
        if any(c not in CHANNELS for c in chans):
            raise ValueError(f"no channel {channel} on a 34901A (101..120)")
        now = self.clock.now()
        for c in chans:
            entry = {"fault": fault, "t0": now, **{k: float(v) for k, v in params.items()}}
            if fault == "stuck":
                self.faults.pop(c, None)
                entry["value"] = self._reading(c, now)
            self.faults[c] = entry

    def clear_faults(self, channel: int | None = None) -> None:
        """Remove injected faults (all, or on ``channel``); ``open_channels`` stay as configured."""
        if channel is None:
            self.faults.clear()
        else:
            self.faults.pop(channel, None)

    # ---- physics ----------------------------------------------------------------------------
    def junction_temp_c(self, channel: int, t_s: float) -> float:
        """True temperature (°C) of the measuring junction on ``channel`` at run time ``t_s``."""
        point = self.points.get(channel, "mount")
        if point == "mount":
            temp = self.world.chamber.mount_temp_c(t_s)  # thermocouples sit on the mount (NPSAT1 IV.B)
        elif point == "air":
            temp = self.world.chamber.air_temp_c(t_s)
        else:
            temp = float(self.world.unit_temperature_c([t_s])[0])
        fault = self.faults.get(channel)
        if fault and fault["fault"] == "runaway":
            temp += fault["rate_c_per_min"] * (t_s - fault["t0"]) / 60.0
        return float(temp)

    @property
    def terminal_temp_c(self) -> float:
        """True temperature of the logger's terminals (reference junction): the room."""
        return float(self.world.p.ambient_temp_c)

    @property
    def measured_rj_c(self) -> float:
        """Reference-junction temperature as the logger measures it (°C)."""
        return self.terminal_temp_c + self.rj_offset_c

    def _is_open(self, channel: int) -> bool:
        f = self.faults.get(channel)
        return channel in self.open_channels or (f is not None and f["fault"] == "open")

    def _reading(self, channel: int, t_s: float) -> float:
        """One reading (°C, or the overload value) of ``channel`` as the logger reports it."""
        fault = self.faults.get(channel)
        if fault and fault["fault"] == "stuck":
            return fault["value"]
        spec = self.spec
        if self._is_open(channel):
            if channel in self.check:
                return OVERLOAD
            volts_mv = float(self.rng.normal(0.0, spec.open_float_uv_rms)) / 1000.0
        else:
            wire = self.installed_types[channel]
            t_ref = self.terminal_temp_c
            tj = self.junction_temp_c(channel, t_s)
            try:
                volts_mv = temp_to_emf_mv(tj, wire) - _emf_of_fixed_temp(t_ref, wire)
            except ValueError:
                return OVERLOAD
            if spec.noise_uv_rms > 0:
                volts_mv += float(self.rng.normal(0.0, spec.noise_uv_rms)) / 1000.0
        if spec.resolution_uv > 0:
            step = spec.resolution_uv / 1000.0
            volts_mv = round(volts_mv / step) * step
        kind = self.tc_type.get(channel, "K")
        try:
            value = emf_to_temp_c(volts_mv + _emf_of_fixed_temp(self.measured_rj_c, kind), kind, exact=spec.exact_conversion)
        except ValueError:
            return OVERLOAD  # outside the configured type's range: the logger reports overload
        if fault and fault["fault"] == "noisy":
            value += float(self.rng.normal(0.0, fault["sigma_c"]))
        return value

    def _reset(self) -> None:
        self.tc_type: dict[int, str] = {}
        self.check: set[int] = set()
        self.scan: list[int] = []
        self.errors: list[str] = []
        self.memory: list[float] | None = None  # readings of the last INIT

    # ---- SCPI -------------------------------------------------------------------------------
    def _error(self, code: int, text: str) -> None:
        if len(self.errors) < 10:
            self.errors.append(f'{code:+d},"{text}"')

    def _answer(self, text: str) -> None:
        """One answer line: ends with CR LF on RS-232, LF on the LAN socket (:attr:`eol`)."""
        self.reply(text)

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
            # the logger stands outside the chamber: its reference junction is at room temperature,
            # as measured by its thermistor (with the spec's reference-junction offset)
            self._answer(f"{self.measured_rj_c:+.8E}")
        elif header_matches("READ?", header):
            if not self.scan:
                self._error(-221, "Settings conflict")
                self._answer("")
                return
            self._answer(_readings(self.read_values()))
        elif header_matches("INITiate", header):
            if not self.scan:
                self._error(-221, "Settings conflict")
                return
            self.memory = self.read_values()  # one scan into reading memory
        elif header_matches("FETCh?", header):
            if self.memory is None:
                self._error(-230, "Data corrupt or stale")  # SCPI code for "no valid data" [U]
                self._answer("")
                return
            self._answer(_readings(self.memory))
        else:
            self._error(-113, "Undefined header")

    def read_values(self) -> list[float]:
        """One scan: °C per channel in scan order (overload value for open, checked channels)."""
        now = self.clock.now()
        return [self._reading(c, now) for c in self.scan]


@functools.lru_cache(maxsize=64)
def _emf_of_fixed_temp(temp_c: float, tc_type: str) -> float:
    """:func:`temp_to_emf_mv` of the few temperatures every reading uses again (the terminals, the
    measured reference junction), computed once."""
    return temp_to_emf_mv(temp_c, tc_type)


def _readings(values: list[float]) -> str:
    """Readings as the 34970A sends them: ``±d.ddddddddE±dd`` comma-separated in scan order
    (protocols.md 3a, 34970A/34972A UG p. 104)."""
    return ",".join(f"{v:+.8E}" for v in values)


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
