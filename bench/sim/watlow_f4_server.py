"""Simulated Watlow F4 controller: :class:`WatlowF4Sim` (registers and fault hooks over a
:class:`Chamber`) and :class:`WatlowF4Server`, a real pymodbus Modbus/TCP server in front of it.
Modbus RTU on a serial line: :mod:`bench.sim.watlow_f4_rtu` (same registers, same faults).

Register map: :data:`drivers.watlow_f4.REGISTERS` (no numbers are repeated here). Addresses are
raw PDU addresses: our own device context maps them straight onto the chamber, avoiding
``ModbusDeviceContext``'s +1 address shift (``../shared/style-models.md`` section 6). Unit id 1;
another unit id gets no answer, as on an RTU line. FC 3 (read holding registers), 6 (write
single) and 16 (write multiple) are served; any other function -> exception 1, an unmapped
address or a write to a read-only register -> exception 2, a bad value (set point outside the
limits, event not 0/1) -> exception 3 (protocols.md section 1 [V]; read-only writes: Watlow
Controls Communications Guide p. 15, see ``docs/golden/watlow-f4.md``).

Usage from synchronous code::

    server = WatlowF4Server(clock, chamber)
    port = server.start()            # 127.0.0.1, a free port
    ...                              # modbus-tcp://127.0.0.1:<port>
    server.stop()

Fault hooks (``inject(fault, **params)``, ``clear_faults()``; several may be active at once):

* ``exception``, ``code=N`` (default 4): every request is answered with exception N.
* ``timeout``: requests are read but never answered.
* ``runaway``, ``rate_c_per_min=R`` (default 5): PV input 1 climbs at R °C/min from the value at
  injection, whatever the control does (the loop output still follows the real chamber).
* ``stuck``: PV inputs 1 and 2 stay at their value at injection.
* ``open_sensor``, ``input=1|2`` (default 1): the PV register reads -32768 [U], the input error
  register 65 ("open", D4T enum) and the alarm status has the input error bit.
* ``disconnect``: open connections are closed and new ones refused (the listening socket is
  closed) until ``clear_faults()``, which listens again on the same port. (On RTU: the line
  goes silent, as with a pulled RS-232/485 cable.)
"""

from __future__ import annotations

import asyncio
import threading
from typing import Callable

from pymodbus.constants import ExcCodes
from pymodbus.datastore import ModbusBaseDeviceContext, ModbusServerContext
from pymodbus.exceptions import NoSuchIdException
from pymodbus.server import ModbusTcpServer

from drivers.watlow_f4 import (ALARM_HIGH_DEVIATION, ALARM_INPUT_1_ERROR, ALARM_INPUT_2_ERROR,
                               ALARM_LOW_DEVIATION, BY_ADDRESS, BY_NAME, EXPECTED_DECIMALS, INPUT_OK,
                               NO_VALUE_RAW, TEMP_UNIT_C, UNIT_ID, Register)

START_TIMEOUT_S = 5.0  # longest wait for the server thread to listen (our choice)
OPEN_SENSOR_CODE = 65  # "Open" in the F4T/D4T input error enum (protocols.md section 1 [V])
DEFAULT_ALARM_BAND_C = 5.0  # our choice [U]: deviation alarm when |PV - SP| > 5 °C
SENSOR_THERMOCOUPLE = 0  # registers 600/610: 0 thermocouple (protocols.md section 1, ESPEC [V]): both inputs are TCs
UNITS_TEMPERATURE = 0  # registers 608/618: 0 temperature, the unit then in register 901 (ESPEC get_loop_units [V])
RUN_STATE_CONSTANT = 1  # register 200: 0,1 = constant set point (protocols.md section 1 [V])
FAULTS = ("exception", "timeout", "runaway", "stuck", "open_sensor", "disconnect")
_LIMITS = {r.address: (r.decode(0x8000 if r.signed else 0), r.decode(0x7FFF if r.signed else 0xFFFF)) for r in BY_ADDRESS.values()}
"""Register address -> (lowest, highest) lab value its raw 16 bits hold."""
_WRITE_FCS = (6, 16)
_READ_FCS = (3,)


class F4DeviceContext(ModbusBaseDeviceContext):
    """Holding registers at raw PDU addresses, read from and written to the simulated F4."""

    def __init__(self, sim: "WatlowF4Sim"):
        self.sim = sim

    def reset(self) -> None:
        """Nothing to reset: the state lives in the chamber."""

    def getValues(self, func_code: int, address: int, count: int = 1):
        return self.sim.read_registers(func_code, address, count)

    def setValues(self, func_code: int, address: int, values):
        return self.sim.write_registers(func_code, address, values)


class F4ServerContext(ModbusServerContext):
    """One device at unit id 1; another unit id, or the ``timeout`` fault, gets no answer."""

    def __init__(self, sim: "WatlowF4Sim"):
        super().__init__(devices={UNIT_ID: F4DeviceContext(sim)}, single=False)
        self.sim = sim

    def __getitem__(self, device_id):
        if not self.sim.answering:
            raise NoSuchIdException("timeout fault: no answer")
        return super().__getitem__(device_id)


class WatlowF4Sim:
    """The simulated F4 without a transport: its registers over a :class:`Chamber` and its fault
    hooks. :class:`WatlowF4Server` puts it on Modbus/TCP, :class:`bench.sim.watlow_f4_rtu.WatlowF4RtuSim`
    on a serial line (Modbus RTU)."""

    def __init__(self, clock, chamber, *, alarm_band_c: float = DEFAULT_ALARM_BAND_C):
        self.clock = clock
        self.chamber = chamber
        self.alarm_band_c = alarm_band_c
        self.faults: dict[str, dict] = {}
        self._values: dict[str, tuple[Callable[[], float], Callable[[float], None] | None]] = {
            "pv_input_1": (self._pv1, None),
            "pv_input_2": (self._pv2, None),
            "output_a": (lambda: max(0.0, self.chamber.output_pct(self.clock.now())), None),
            "output_b": (lambda: max(0.0, -self.chamber.output_pct(self.clock.now())), None),
            "run_state": (lambda: RUN_STATE_CONSTANT, None),
            "set_point_1": (lambda: self.chamber.set_point_c,
                            lambda v: self.chamber.command_set_point(self.clock.now(), v)),
            "ramp_rate_1": (lambda: self.chamber.ramp_rate_c_per_min,
                            lambda v: self.chamber.command_ramp_rate(self.clock.now(), v)),
            "alarm_band_1": (lambda: self.alarm_band_c, self._set_band),
            "sp_low_limit_1": (lambda: self.chamber.set_point_limits_c[0], None),
            "sp_high_limit_1": (lambda: self.chamber.set_point_limits_c[1], None),
            "decimals_1": (lambda: EXPECTED_DECIMALS, None),
            "decimals_2": (lambda: EXPECTED_DECIMALS, None),
            "sensor_type_1": (lambda: SENSOR_THERMOCOUPLE, None),
            "sensor_type_2": (lambda: SENSOR_THERMOCOUPLE, None),
            "units_1": (lambda: UNITS_TEMPERATURE, None),
            "units_2": (lambda: UNITS_TEMPERATURE, None),
            "temp_unit": (lambda: TEMP_UNIT_C, None),
            "alarm_status": (self._alarm_bits, None),
            "input_1_error": (lambda: self._input_error(1), None),
            "input_2_error": (lambda: self._input_error(2), None),
            "event_1": (lambda: int(self.chamber.pump_on), lambda v: self._set_event(self.chamber.set_pump, v)),
            "event_2": (lambda: int(self.chamber.vent_open), lambda v: self._set_event(self.chamber.set_vent, v)),
        }
        missing = set(BY_NAME) ^ set(self._values)
        if missing:
            raise RuntimeError(f"register map and simulator disagree on {sorted(missing)}")

    @property
    def answering(self) -> bool:
        """False while the ``timeout`` fault holds: requests are taken in but never answered."""
        return "timeout" not in self.faults

    # ---- requests (function code, PDU address, values) -> registers or exception -------------
    def refusal(self, func_code: int, served: tuple[int, ...] = _READ_FCS + _WRITE_FCS) -> ExcCodes | None:
        """The exception that refuses ``func_code`` before any address is looked at: the
        ``exception`` fault's code, 1 (illegal function) for a function not in ``served``, else None."""
        if self.faults.get("exception"):
            return ExcCodes(self.faults["exception"]["code"])
        if func_code not in served:
            return ExcCodes.ILLEGAL_FUNCTION
        return None

    def read_registers(self, func_code: int, address: int, count: int = 1) -> list[int] | ExcCodes:
        """Raw values (0..65535) of ``count`` registers from PDU ``address``, or the exception:
        2 (illegal data address) if any of them is not in the register map."""
        if (exc := self.refusal(func_code)) is not None:
            return exc
        regs = [BY_ADDRESS.get(a) for a in range(address, address + count)]
        if any(r is None for r in regs):
            return ExcCodes.ILLEGAL_ADDRESS
        return [self.read_raw(r) for r in regs]

    def write_registers(self, func_code: int, address: int, values) -> ExcCodes | None:
        """Write raw ``values`` from PDU ``address`` (FC 6 or 16); None on success, else the
        exception: 2 (illegal data address) for an address not in the map or a read-only register
        (Watlow Controls Communications Guide p. 15: "An attempt to write to a read-only parameter
        returns an illegal data address error (0x02)"), 3 (illegal data value) for a refused value."""
        if (exc := self.refusal(func_code, _WRITE_FCS)) is not None:
            return exc
        regs = [BY_ADDRESS.get(a) for a in range(address, address + len(values))]
        if any(r is None or r.access != "RW" for r in regs):
            return ExcCodes.ILLEGAL_ADDRESS
        for reg, raw in zip(regs, values):
            if not self.write_raw(reg, int(raw)):
                return ExcCodes.ILLEGAL_VALUE
        return None

    # ---- register values --------------------------------------------------------------------
    def read_raw(self, reg: Register) -> int:
        """Raw 16-bit value of ``reg`` now."""
        if reg.name in ("pv_input_1", "pv_input_2") and self._open(int(reg.name[-1])):
            return NO_VALUE_RAW & 0xFFFF
        value = self._values[reg.name][0]()
        lo, hi = _LIMITS[reg.address]
        return reg.encode(min(hi, max(lo, value)))

    def write_raw(self, reg: Register, raw: int) -> bool:
        """Apply a written raw value; False if the value is refused (exception 3)."""
        setter = self._values[reg.name][1]
        if setter is None:
            return False
        try:
            setter(reg.decode(raw))
        except ValueError:
            return False
        return True

    def _pv1(self) -> float:
        t = self.clock.now()
        if "stuck" in self.faults:
            return self.faults["stuck"]["pv1"]
        if "runaway" in self.faults:
            f = self.faults["runaway"]
            return f["pv1"] + f["rate_c_per_min"] * (t - f["t0"]) / 60.0
        return self.chamber.air_temp_c(t)

    def _pv2(self) -> float:
        if "stuck" in self.faults:
            return self.faults["stuck"]["pv2"]
        return self.chamber.mount_temp_c(self.clock.now())

    def _open(self, n: int) -> bool:
        return "open_sensor" in self.faults and self.faults["open_sensor"]["input"] == n

    def _input_error(self, n: int) -> int:
        return OPEN_SENSOR_CODE if self._open(n) else INPUT_OK

    def _alarm_bits(self) -> int:
        bits = 0
        if self._open(1):
            bits |= ALARM_INPUT_1_ERROR
        else:
            dev = self._pv1() - self.chamber.set_point_c
            if dev > self.alarm_band_c:
                bits |= ALARM_HIGH_DEVIATION
            elif dev < -self.alarm_band_c:
                bits |= ALARM_LOW_DEVIATION
        if self._open(2):
            bits |= ALARM_INPUT_2_ERROR
        return bits

    def _set_band(self, v: float) -> None:
        if v <= 0:
            raise ValueError("alarm band must be > 0")
        self.alarm_band_c = v

    def _set_event(self, command, v: float) -> None:
        if v not in (0, 1):
            raise ValueError("event output takes 0 or 1")
        command(self.clock.now(), bool(v))

    # ---- faults -----------------------------------------------------------------------------
    def inject(self, fault: str, **params) -> None:
        """Start fault ``fault`` (one of :data:`FAULTS`; parameters in the module docstring)."""
        t = self.clock.now()
        if fault == "exception":
            self.faults["exception"] = {"code": int(ExcCodes(params.get("code", 4)))}
        elif fault == "timeout":
            self.faults["timeout"] = {}
        elif fault == "runaway":
            self.faults["runaway"] = {"rate_c_per_min": float(params.get("rate_c_per_min", 5.0)), "t0": t,
                                      "pv1": self._pv1()}
        elif fault == "stuck":
            self.faults["stuck"] = {"pv1": self._pv1(), "pv2": self._pv2()}
        elif fault == "open_sensor":
            n = int(params.get("input", 1))
            if n not in (1, 2):
                raise ValueError("open_sensor input must be 1 or 2")
            self.faults["open_sensor"] = {"input": n}
        elif fault == "disconnect":
            self.faults["disconnect"] = {}
            self._disconnect()
        else:
            raise ValueError(f"unknown fault {fault!r}; known: {', '.join(FAULTS)}")

    def clear_faults(self) -> None:
        """End every fault (after ``disconnect`` the transport is back)."""
        reconnect = "disconnect" in self.faults
        self.faults.clear()
        if reconnect:
            self._reconnect()

    def _disconnect(self) -> None:
        """Transport side of the ``disconnect`` fault."""

    def _reconnect(self) -> None:
        """Transport side of the end of the ``disconnect`` fault."""


class WatlowF4Server(WatlowF4Sim):
    """A Watlow F4 on Modbus/TCP, in a daemon thread with its own event loop."""

    def __init__(self, clock, chamber, *, alarm_band_c: float = DEFAULT_ALARM_BAND_C):
        super().__init__(clock, chamber, alarm_band_c=alarm_band_c)
        self.host = "127.0.0.1"
        self.port = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._server: ModbusTcpServer | None = None
        self._context = F4ServerContext(self)

    def _disconnect(self) -> None:
        if self._loop is not None:
            self._run(self._close_server())

    def _reconnect(self) -> None:
        """Listen again on the same port."""
        if self._loop is not None:
            self._run(self._listen(self.host, self.port))

    # ---- server thread ----------------------------------------------------------------------
    def start(self, host: str = "127.0.0.1", port: int = 0) -> int:
        """Listen on ``host``:``port`` (0 = a free port) and return the bound port once the server
        accepts connections (``RuntimeError`` after :data:`START_TIMEOUT_S` s)."""
        if self._thread is not None:
            raise RuntimeError("server already started")
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="watlow-f4-sim", daemon=True)
        self._thread.start()
        try:
            self.port = self._run(self._listen(host, port))
        except BaseException:
            self.stop()
            raise
        self.host = host
        return self.port

    def stop(self) -> None:
        """Close every connection and the listener, end the thread."""
        if self._loop is None:
            return
        try:
            self._run(self._close_server())
        finally:
            self._loop.call_soon_threadsafe(self._loop.stop)
            if self._thread is not None:
                self._thread.join(START_TIMEOUT_S)
            if not self._loop.is_running():
                self._loop.close()
            self._loop = None
            self._thread = None

    def _run(self, coro):
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(START_TIMEOUT_S)

    async def _listen(self, host: str, port: int) -> int:
        server = ModbusTcpServer(self._context, address=(host, port), ignore_missing_devices=True)
        await server.serve_forever(background=True)
        self._server = server
        return server.transport.sockets[0].getsockname()[1]

    async def _close_server(self) -> None:
        if self._server is not None:
            await self._server.shutdown()
            self._server = None

    def __enter__(self) -> "WatlowF4Server":
        if self._thread is None:
            self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()
