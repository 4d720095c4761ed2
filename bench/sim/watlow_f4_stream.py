"""Simulated Watlow F4 on Modbus TCP framing over an in-process byte stream (the dry-run default).

The registers and faults of :class:`bench.sim.watlow_f4_server.WatlowF4Sim`, reached as a
:class:`bench.sim.registry.SerialDevice` (``sim://NAME``) by the driver's
:class:`drivers.modbus_stream.ModbusStreamClient` (``modbus-tcp+stream://sim://NAME``). Each request
is answered in the caller's thread by pymodbus's own server-side request handling: its framer and
decoder of :class:`pymodbus.server.ModbusTcpServer`, the requests' ``update_datastore`` on the
same :class:`~bench.sim.watlow_f4_server.F4ServerContext`, and the same error rules as its request
handler (another unit id or the ``timeout`` fault: no answer; a failing datastore: exception 4; an
undecodable request: exception 1). So the bytes are those of :class:`WatlowF4Server`, without its
event loop, thread and socket (``tests/test_inprocess_transports.py`` compares the two).

``disconnect``: while it holds, the stream fails (``SerialException``: the driver sees a lost
connection) and opening it again fails (refused), until ``clear_faults()``.
"""

from __future__ import annotations

import threading

from pymodbus.constants import ExcCodes
from pymodbus.exceptions import ModbusIOException, NoSuchIdException
from pymodbus.framer import FramerSocket
from pymodbus.pdu import DecodePDU, ExceptionResponse
from serial import SerialException

from bench.sim.registry import ReplyBuffer
from bench.sim.watlow_f4_server import DEFAULT_ALARM_BAND_C, F4ServerContext, WatlowF4Sim

UNDECODABLE_FC = 40
"""Function code pymodbus's server answers an undecodable request with (exception 1)."""


def run_now(coro):
    """Result of a coroutine that never suspends (pymodbus's ``update_datastore`` on a synchronous
    datastore), without an event loop. ``RuntimeError`` if it does suspend."""
    try:
        coro.send(None)
    except StopIteration as done:
        return done.value
    coro.close()
    raise RuntimeError("request handling waited on something; it cannot run in-process")


class WatlowF4StreamSim(ReplyBuffer, WatlowF4Sim):
    """A Watlow F4 answering Modbus TCP ADUs written to it, in the writer's thread."""

    def __init__(self, clock, chamber, *, alarm_band_c: float = DEFAULT_ALARM_BAND_C, baudrate: int = 0):
        super().__init__(clock, chamber, alarm_band_c=alarm_band_c)
        self.baudrate = baudrate
        self._in = bytearray()
        self._out = bytearray()
        self._lock = threading.RLock()
        self._framer = FramerSocket(DecodePDU(True))
        self._context = F4ServerContext(self)

    # ---- SerialDevice -----------------------------------------------------------------------
    def receive(self, data: bytes) -> None:
        """Request bytes from the client; every complete ADU is answered at once."""
        with self._lock:
            self._check_link()
            self._in += data
            while self._in:
                try:
                    used, pdu = self._framer.handleFrame(bytes(self._in), 0, 0)
                except ModbusIOException:  # as pymodbus's ServerRequestHandler.callback_data
                    self._in.clear()
                    self._send(ExceptionResponse(UNDECODABLE_FC, exception_code=ExcCodes.ILLEGAL_FUNCTION))
                    break
                del self._in[:used]
                if pdu is None:
                    break
                self._handle(pdu)

    def take_output(self, t_s: float, max_bytes: int | None = None) -> bytes:
        self._check_link()
        return super().take_output(t_s, max_bytes)

    def pending_bytes(self, t_s: float) -> int:
        self._check_link()
        return super().pending_bytes(t_s)

    def discard_input(self) -> None:
        with self._lock:
            self._in.clear()

    # ---- requests ---------------------------------------------------------------------------
    def _handle(self, pdu) -> None:
        """As ``ServerRequestHandler.handle_request`` with ``ignore_missing_devices=True`` and no broadcast."""
        try:
            response = run_now(pdu.update_datastore(self._context[pdu.dev_id]))
        except NoSuchIdException:
            return  # another unit id, or the timeout fault: the client waits in vain
        except Exception:  # noqa: BLE001 - pymodbus answers a failing datastore with exception 4
            response = ExceptionResponse(pdu.function_code, ExcCodes.DEVICE_FAILURE)
        response.transaction_id = pdu.transaction_id
        response.dev_id = pdu.dev_id
        self._send(response)

    def _send(self, response) -> None:
        self._out += self._framer.buildFrame(response)

    # ---- the disconnect fault ---------------------------------------------------------------
    def _check_link(self) -> None:
        if "disconnect" in self.faults:
            self._out.clear()
            raise SerialException("connection closed by the controller (simulated disconnect)")

    def _disconnect(self) -> None:
        with self._lock:
            self._in.clear()
            self._out.clear()
