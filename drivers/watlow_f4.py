"""Modbus driver of a Watlow F4-class temperature controller (the TVAC chamber's controller).

The register map is data (:data:`REGISTERS`), shared with the simulator
``bench/sim/watlow_f4_server.py``. Register number = raw PDU address, no 40001 offset; values
are signed 16-bit integers, value = raw / scale (``../shared/protocols.md`` section 1 [V]).
Rows marked ``verified=False`` are our own choice [U] (see ``docs/tvac.md``).

Transports: Modbus TCP (the simulator, or a serial-to-Ethernet gateway) and Modbus RTU on a
serial line at 9600 baud 8N1, device address 1 (protocols.md section 1: 9600 [V], 8 data bits
no parity [V], 1 stop bit [U]); either framing also on any byte stream pyserial opens
(``modbus-tcp+stream://URL``, ``modbus-rtu+stream://URL``: :mod:`drivers.modbus_stream`, the
same bytes without the socket and serial clients' waits).

Error reactions: no answer -> :class:`InstrumentTimeout`; a Modbus exception response ->
:class:`ProtocolError` naming register and exception; connection refused or lost ->
:class:`InstrumentError`; the controller reporting an input error -> :class:`DeviceFault`.
Reads are retried at most :data:`READ_RETRIES` times, and only after a lost connection or a
"busy" exception (code 6), which come back at once; a timeout is never retried, so one call
waits at most ``timeout_s`` per attempt. Writes are never retried; they are verified by
reading the register back.
"""

from __future__ import annotations

import urllib.parse
from dataclasses import dataclass
from typing import Callable

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException
from pymodbus.framer import FramerType

from drivers.base import Driver, Transient, check_timeout
from drivers.errors import DeviceFault, InstrumentError, InstrumentTimeout, ProtocolError
from drivers.modbus_stream import ModbusStreamClient

UNIT_ID = 1  # F4 factory device address 1 (protocols.md section 1 [V])
DEFAULT_TCP_PORT = 502  # Modbus/TCP registered port (Modbus Messaging on TCP/IP guide)
RTU_BAUDRATE = 9600  # protocols.md section 1: TestEquity F4 since 2003 [V]
READ_RETRIES = 2  # our choice: extra attempts of a read after a lost link or "busy" (code 6)
BUSY_PAUSE_S = 0.05  # our choice: pause before retrying a read the controller called busy
NO_VALUE_RAW = -32768  # our choice [U]: what the simulator's PV register holds for a failed input
MAX_REGS_PER_READ = 125  # Modbus application protocol, FC 3 quantity limit

EXCEPTION_MEANINGS = {  # Modbus application protocol v1.1b section 7; F4 manual uses 1-3 [V]
    1: "illegal function",
    2: "illegal data address",
    3: "illegal data value",
    4: "server device failure",
    5: "acknowledge",
    6: "server device busy",
    8: "memory parity error",
    10: "gateway path unavailable",
    11: "gateway target device failed to respond",
}

INPUT_ERRORS = {  # F4T-family input error enum (Watlow D4T manual) [V]; its F4 register is [U]
    61: "none",
    65: "open sensor",
    127: "shorted sensor",
    140: "measurement error",
    139: "bad calibration",
    9: "ambient error",
    141: "RTD error",
    32: "fail",
}
INPUT_OK = 61

# alarm status register bits (our choice [U])
ALARM_HIGH_DEVIATION = 0x01  # PV input 1 above set point + band
ALARM_LOW_DEVIATION = 0x02  # PV input 1 below set point - band
ALARM_INPUT_1_ERROR = 0x04
ALARM_INPUT_2_ERROR = 0x08

TEMP_UNIT_C = 1  # register 901: 0 = °F, 1 = °C (protocols.md section 1 [V])
EXPECTED_DECIMALS = 1  # register 606 value this map's scales assume (tenths of °C)


@dataclass(frozen=True)
class Register:
    """One holding register: PDU address, name, access ("R" or "RW"), value = raw / scale, unit."""

    address: int
    name: str
    access: str
    scale: int
    unit: str
    verified: bool
    source: str
    signed: bool = True

    def decode(self, raw: int) -> float:
        """Lab value (in :attr:`unit`) of a raw 16-bit register value (0..65535)."""
        if not 0 <= raw <= 0xFFFF:
            raise ValueError(f"register {self.address} raw value {raw} is not 16-bit")
        if self.signed and raw >= 0x8000:
            raw -= 0x10000
        return raw / self.scale

    def encode(self, value: float) -> int:
        """Raw 16-bit register value (0..65535) of a lab value; ``ValueError`` if out of range."""
        raw = round(value * self.scale)
        lo, hi = (-0x8000, 0x7FFF) if self.signed else (0, 0xFFFF)
        if not lo <= raw <= hi:
            raise ValueError(f"{self.name}: {value} {self.unit} does not fit register {self.address}")
        return raw & 0xFFFF


_E = "ESPEC ChamberConnectLibrary watlowf4.py, protocols.md s1"
REGISTERS: tuple[Register, ...] = (
    Register(100, "pv_input_1", "R", 10, "°C", True, _E + " (chamber air)"),
    Register(103, "output_a", "R", 100, "%", True, _E + " (heat)"),
    Register(104, "pv_input_2", "R", 10, "°C", True, _E + " (mount plate)"),
    Register(107, "output_b", "R", 100, "%", True, _E + " (cool)"),
    Register(200, "run_state", "R", 1, "", True, _E + ": 0,1 constant, 2 profile, 3 hold"),
    Register(300, "set_point_1", "RW", 10, "°C", True, _E),
    Register(340, "ramp_rate_1", "RW", 10, "°C/min", False, "our choice; 0 = ramp off"),
    Register(341, "alarm_band_1", "RW", 10, "°C", False, "our choice; deviation alarm band"),
    Register(600, "sensor_type_1", "R", 1, "", True, _E + ": 0 thermocouple, 1 RTD, 2 process, 3 wet/dry, 4 off", signed=False),
    Register(602, "sp_low_limit_1", "R", 10, "°C", True, _E + " (R/W on the F4; read-only here)"),
    Register(603, "sp_high_limit_1", "R", 10, "°C", True, _E + " (R/W on the F4; read-only here)"),
    Register(606, "decimals_1", "R", 1, "", True, _E),
    Register(608, "units_1", "R", 1, "", True, _E + ": 0 temperature, 1 %RH, 2 PSI, 3 none", signed=False),
    Register(610, "sensor_type_2", "R", 1, "", True, "ESPEC watlowf4.py (__get_analog_input_setup reads 600, 610, 620)", signed=False),
    Register(616, "decimals_2", "R", 1, "", True, _E + " (decimals of inputs 1-3 at 606/616/626)"),
    Register(618, "units_2", "R", 1, "", True, "ESPEC watlowf4.py (get_loop_units reads 608, 618, 628)", signed=False),
    Register(901, "temp_unit", "R", 1, "", True, _E + ": 0 °F, 1 °C"),
    Register(1400, "alarm_status", "R", 1, "bits", False, "our choice; bits 0 high dev, 1 low dev, 2/3 input 1/2 error", signed=False),
    Register(1401, "input_1_error", "R", 1, "code", False, "our choice; codes of the D4T manual", signed=False),
    Register(1402, "input_2_error", "R", 1, "code", False, "our choice; codes of the D4T manual", signed=False),
    Register(2000, "event_1", "RW", 1, "", True, _E + ": event output 1 = pumps", signed=False),
    Register(2010, "event_2", "RW", 1, "", True, _E + ": event output 2 = vent valve", signed=False),
)
BY_ADDRESS: dict[int, Register] = {r.address: r for r in REGISTERS}
BY_NAME: dict[str, Register] = {r.name: r for r in REGISTERS}
EVENT_REGISTERS = {1: "event_1", 2: "event_2"}  # event output n at 2000 + 10 (n - 1) [V]


def exception_text(code: int) -> str:
    """``"3 (illegal data value)"`` for a Modbus exception code."""
    return f"{code} ({EXCEPTION_MEANINGS.get(code, 'unknown exception')})"


def parse_modbus_url(url: str) -> tuple[str, str, int, int]:
    """Split ``modbus-tcp://HOST[:PORT][?unit=N]`` or ``modbus-rtu://PORTNAME[?unit=N]``
    (``modbus-rtu:///dev/ttyUSB0``, ``modbus-rtu://COM3``) into (kind, host_or_port, tcp_port, unit);
    ``modbus-tcp+stream://URL`` and ``modbus-rtu+stream://URL`` (kinds ``tcp-stream``,
    ``rtu-stream``) give the pyserial URL of the stream (``sim://tvac``, ``socket://HOST:PORT``).

    Raises ``ValueError`` on another scheme.
    """
    parts = urllib.parse.urlsplit(url)
    query = urllib.parse.parse_qs(parts.query)
    unit = int(query.get("unit", [UNIT_ID])[0])
    if parts.scheme == "modbus-tcp":
        if not parts.hostname:
            raise ValueError(f"modbus-tcp URL needs a host: {url!r}")
        return "tcp", parts.hostname, parts.port or DEFAULT_TCP_PORT, unit
    if parts.scheme in ("modbus-rtu", "modbus-tcp+stream", "modbus-rtu+stream"):
        port = parts.netloc + parts.path
        if not port:
            raise ValueError(f"{parts.scheme} URL needs a serial port or stream URL: {url!r}")
        kind = {"modbus-rtu": "rtu", "modbus-tcp+stream": "tcp-stream", "modbus-rtu+stream": "rtu-stream"}[parts.scheme]
        return kind, port, 0, unit
    raise ValueError(f"expected modbus-tcp://HOST:PORT, modbus-rtu://PORT or modbus-tcp+stream:// / modbus-rtu+stream://URL, "
                     f"got {url!r}")


class WatlowF4(Driver):
    """Watlow F4 loop 1 over Modbus. Temperatures in °C, rates in °C/min, power in %."""

    kind = "watlow_f4"
    streams = False

    def __init__(self, client, *, timeout_s: float = 0.5, unit: int = UNIT_ID, name: str = "tvac controller",
                 on_traffic: Callable[[str, str, bytes], None] | None = None, read_retries: int = READ_RETRIES):
        self.client = client
        self.timeout_s = check_timeout(timeout_s)
        self.unit = unit
        self.name = name
        self.on_traffic = on_traffic
        self.read_retries = read_retries
        self._op = ""
        if getattr(client, "transaction", None) is not None:  # pymodbus calls it with every ADU
            client.transaction.trace_packet = self._trace

    @classmethod
    def open(cls, url: str, *, baudrate: int = RTU_BAUDRATE, timeout_s: float = 0.5,
             on_traffic: Callable[[str, str, bytes], None] | None = None, check: bool = True) -> "WatlowF4":
        """Connect to ``url`` (see :func:`parse_modbus_url`) and, with ``check``, verify that the
        controller reports °C with one decimal (registers 901 and 606)."""
        kind, where, port, unit = parse_modbus_url(url)
        if kind == "tcp":
            client = ModbusTcpClient(where, port=port, timeout=timeout_s, retries=0, reconnect_delay=0)
        elif kind in ("tcp-stream", "rtu-stream"):
            client = ModbusStreamClient(where, framer=FramerType.SOCKET if kind == "tcp-stream" else FramerType.RTU,
                                        baudrate=baudrate, timeout=timeout_s)
        else:  # 9600 8N1 (protocols.md section 1)
            client = ModbusSerialClient(where, framer=FramerType.RTU, baudrate=baudrate, bytesize=8, parity="N",
                                        stopbits=1, timeout=timeout_s, retries=0, reconnect_delay=0)
        driver = cls(client, timeout_s=timeout_s, unit=unit, on_traffic=on_traffic, name=f"tvac controller {url}")
        if not client.connect():
            client.close()
            raise InstrumentError(f"{driver.name}: cannot connect (refused or no such port)")
        if check:
            try:
                driver.check_configuration()
            except BaseException:
                driver.close()
                raise
        return driver

    def close(self) -> None:
        self.client.close()

    def _trace(self, sending: bool, data: bytes) -> bytes:
        if self.on_traffic is not None and data:
            self.on_traffic("command" if sending else "reply", self._op, bytes(data))
        return data

    # ---- raw access -------------------------------------------------------------------------
    def read_raw(self, address: int, count: int = 1) -> list[int]:
        """FC 3 read of ``count`` raw registers from ``address`` (retried as documented)."""
        if not 1 <= count <= MAX_REGS_PER_READ:
            raise ValueError(f"count must be 1..{MAX_REGS_PER_READ}")
        self._op = f"read {address}" if count == 1 else f"read {address}+{count}"

        def attempt(_: int) -> list[int]:
            try:
                rr = self._call(lambda: self.client.read_holding_registers(address, count=count, device_id=self.unit))
            except _LinkLost:
                raise Transient(InstrumentError(f"{self.name}: connection lost reading register {address}")) from None
            if rr.isError() and getattr(rr, "exception_code", None) == 6:  # busy: ask again after a pause
                raise Transient(self._exception(rr, address, "reading"), pause_s=BUSY_PAUSE_S)
            self._check(rr, address, "reading")
            if len(rr.registers) != count:
                raise ProtocolError(f"{self.name}: {len(rr.registers)} registers for {count} read at {address}")
            return list(rr.registers)

        return self.read_retrying(attempt, attempts=1 + self.read_retries)

    def write_raw(self, address: int, raw: int) -> None:
        """FC 6 write of one raw register. Never retried: a timeout leaves the outcome unknown."""
        self._op = f"write {address}"
        try:
            rr = self._call(lambda: self.client.write_register(address, raw, device_id=self.unit),
                            what=f"writing register {address} (not retried: the write may have taken effect)")
        except _LinkLost:
            raise InstrumentError(f"{self.name}: connection lost writing register {address}; not retried") from None
        self._check(rr, address, f"writing {raw} to")

    def _call(self, request, what: str = "the request"):
        try:
            return request()
        except ModbusIOException:
            self.client.close()  # a late answer must not be taken as the answer to the next request
            raise InstrumentTimeout(f"{self.name}: no answer to {what} within {self.timeout_s:g} s") from None
        except ConnectionException as exc:
            self.client.close()
            if "Failed to connect" in str(exc) or "cannot connect" in str(exc):
                raise InstrumentError(f"{self.name}: cannot connect (refused or no such port)") from None
            raise _LinkLost() from None
        except ModbusException as exc:
            self.client.close()
            raise ProtocolError(f"{self.name}: bad Modbus frame: {exc}") from None
        except OSError as exc:
            self.client.close()
            raise InstrumentError(f"{self.name}: link error: {exc}") from None

    def _exception(self, rr, address: int, action: str) -> ProtocolError:
        """The :class:`ProtocolError` naming the register and the exception of response ``rr``."""
        code = getattr(rr, "exception_code", 0)
        reg = BY_ADDRESS.get(address)
        label = f" ({reg.name})" if reg is not None else ""
        return ProtocolError(f"{self.name}: exception {exception_text(code)} {action} register {address}{label}")

    def _check(self, rr, address: int, action: str) -> None:
        """Raise :meth:`_exception` if ``rr`` is an exception response."""
        if rr.isError():
            raise self._exception(rr, address, action)

    # ---- scaled access ----------------------------------------------------------------------
    def read(self, name: str) -> float:
        """Lab value of the register called ``name`` in :data:`REGISTERS`."""
        reg = BY_NAME[name]
        return reg.decode(self.read_raw(reg.address)[0])

    def write(self, name: str, value: float, verify: bool = True) -> None:
        """Write a lab value to register ``name``; with ``verify`` read it back (``DeviceFault`` if it differs)."""
        reg = BY_NAME[name]
        if reg.access != "RW":
            raise ValueError(f"register {reg.address} ({name}) is read-only")
        raw = reg.encode(value)
        self.write_raw(reg.address, raw)
        if verify:
            back = self.read_raw(reg.address)[0]
            if back != raw:
                raise DeviceFault(f"{self.name}: register {reg.address} ({name}) reads {reg.decode(back)} "
                                  f"after writing {reg.decode(raw)}")

    # ---- lab API ----------------------------------------------------------------------------
    def check_configuration(self) -> dict[str, int]:
        """Read units (901) and input-1 decimals (606); ``DeviceFault`` unless °C with one decimal."""
        unit = int(self.read("temp_unit"))
        decimals = int(self.read("decimals_1"))
        if unit != TEMP_UNIT_C or decimals != EXPECTED_DECIMALS:
            raise DeviceFault(f"{self.name}: controller set to units={unit} (1 = °C) and decimals={decimals}; "
                              f"this driver needs °C with 1 decimal (registers 901 = 1, 606 = 1)")
        return {"temp_unit": unit, "decimals": decimals}

    def _read_temp(self, name: str, error_name: str, label: str) -> float:
        reg = BY_NAME[name]
        raw = self.read_raw(reg.address)[0]
        value = reg.decode(raw)
        if round(value * reg.scale) == NO_VALUE_RAW:
            code = int(self.read(error_name))
            raise DeviceFault(f"{self.name}: {label} input error {code} ({INPUT_ERRORS.get(code, 'unknown')})")
        return value

    def read_air_temp_c(self) -> float:
        """Chamber air temperature, PV input 1 (°C)."""
        return self._read_temp("pv_input_1", "input_1_error", "air temperature")

    def read_mount_temp_c(self) -> float:
        """Mounting plate temperature, PV input 2 (°C)."""
        return self._read_temp("pv_input_2", "input_2_error", "mount temperature")

    def read_set_point_c(self) -> float:
        """Loop-1 static set point (°C)."""
        return self.read("set_point_1")

    def set_set_point_c(self, value_c: float) -> None:
        """Write the loop-1 set point (°C), verified by read-back. Outside the controller's limits
        the controller answers exception 3 (:class:`ProtocolError`)."""
        self.write("set_point_1", value_c)

    def read_set_point_limits_c(self) -> tuple[float, float]:
        """(low, high) set point limits of input 1 (°C)."""
        return self.read("sp_low_limit_1"), self.read("sp_high_limit_1")

    def set_ramp_rate_c_per_min(self, rate: float) -> None:
        """Set-point ramp rate (°C/min, 0 = off: step changes) [U register]."""
        if rate < 0:
            raise ValueError("ramp rate must be >= 0 °C/min")
        self.write("ramp_rate_1", rate)

    def read_ramp_rate_c_per_min(self) -> float:
        return self.read("ramp_rate_1")

    def read_alarms(self) -> dict[str, object]:
        """Alarm status [U registers]: ``high_deviation``, ``low_deviation``, ``input_1_error``,
        ``input_2_error`` (bools) and ``input_1_code`` / ``input_2_code`` texts (``"none"`` when fine)."""
        bits = int(self.read("alarm_status"))
        e1, e2 = int(self.read("input_1_error")), int(self.read("input_2_error"))
        return {
            "high_deviation": bool(bits & ALARM_HIGH_DEVIATION),
            "low_deviation": bool(bits & ALARM_LOW_DEVIATION),
            "input_1_error": bool(bits & ALARM_INPUT_1_ERROR),
            "input_2_error": bool(bits & ALARM_INPUT_2_ERROR),
            "input_1_code": INPUT_ERRORS.get(e1, f"code {e1}"),
            "input_2_code": INPUT_ERRORS.get(e2, f"code {e2}"),
        }

    def set_event(self, n: int, on: bool) -> None:
        """Switch event output ``n`` (1 = pumps, 2 = vent valve), verified by read-back."""
        self.write(_event_name(n), 1 if on else 0)

    def read_event(self, n: int) -> bool:
        return bool(self.read(_event_name(n)))

    def read_output_pct(self) -> float:
        """Loop-1 output: heat power (output A) minus cool power (output B), -100..100 %."""
        return self.read("output_a") - self.read("output_b")

    def read_run_state(self) -> int:
        return int(self.read("run_state"))


class _LinkLost(Exception):
    """Internal: the TCP connection or serial port dropped during a request."""


def _event_name(n: int) -> str:
    try:
        return EVENT_REGISTERS[n]
    except KeyError:
        raise ValueError(f"event output must be one of {sorted(EVENT_REGISTERS)}, got {n}") from None
