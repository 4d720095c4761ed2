"""Simulated Watlow F4 on Modbus RTU: the registers and faults of
:class:`bench.sim.watlow_f4_server.WatlowF4Sim` behind a serial line.

It is a :class:`bench.sim.registry.SerialDevice`, so it is reached like every serial simulator:
as ``sim://NAME`` in a dry-run (the driver opens ``modbus-rtu://sim://NAME``; pymodbus's
``ModbusSerialClient`` opens its port with ``serial.serial_for_url``, which takes ``sim://``) and
on a pseudo-terminal under ``bench sim serve`` (``mbpoll -m rtu ... /dev/pts/N``). Like the other
serial simulators it owns no thread and its answers have no modelled latency.

Framing (Modbus over Serial Line V1.02, section 2.5.1): a frame is slave address, PDU, CRC-16
(low byte first, section 2.5.1.2 and 6.2.2). Frames are delimited by their length, known from the
function code (requests of FC 1..6: 8 bytes; FC 15/16: 9 + byte count), and by line silence
longer than 3.5 characters (section 2.5.1.1; 1.75 ms above 19200 bit/s): bytes that arrive after
such a gap start a new frame. A frame of another function is taken whole once its CRC holds.

* a frame with a wrong CRC is ignored (section 2.5.1.2; Watlow Controls Communications Guide p. 17:
  "Messages with the wrong format, timing or CRC are ignored"), as is a frame for another address;
* address 0 is a broadcast: a write is carried out and nothing is answered (section 2.1);
* FC 3 / 6 / 16 as the TCP server (same register map, same exceptions); FC 6 answers with an
  echo of the request (Modbus Application Protocol V1.1b3 section 6.6); a quantity outside
  1..125 (FC 3) or 1..123 with a matching byte count (FC 16) is exception 3 (sections 6.3, 6.12);
* faults: ``timeout`` and ``disconnect`` silence the line (a pulled RS-232/485 cable looks the
  same as a controller that does not answer); the others act on the registers as on TCP.
"""

from __future__ import annotations

import struct
import threading

from pymodbus.constants import ExcCodes

from bench.sim.registry import ReplyBuffer
from bench.sim.watlow_f4_server import DEFAULT_ALARM_BAND_C, WatlowF4Sim
from drivers.watlow_f4 import MAX_REGS_PER_READ, RTU_BAUDRATE, UNIT_ID

BROADCAST = 0  # Modbus over Serial Line V1.02 section 2.1
MAX_ADU = 256  # serial line ADU limit (section 2.5.1)
MAX_REGS_PER_WRITE = 123  # application protocol section 6.12: FC 16 quantity 1..123
BITS_PER_CHAR = 11  # section 2.5.1: 1 start, 8 data, parity or second stop bit, 1 stop
FIXED_GAP_S = 1.75e-3  # section 2.5.1.1: t3.5 above 19200 bit/s
_FIXED_REQUEST_LENGTH = {1: 8, 2: 8, 3: 8, 4: 8, 5: 8, 6: 8}  # address, FC, 4 data bytes, CRC
_BYTE_COUNT_REQUESTS = (15, 16)  # address, FC, start, quantity, byte count, data, CRC


def crc16_modbus(data: bytes) -> bytes:
    """CRC-16/MODBUS of ``data`` as it goes on the line, low byte first (Modbus over Serial Line
    V1.02 section 6.2.2: preset 0xFFFF, reflected polynomial 0xA001)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return bytes((crc & 0xFF, crc >> 8))


def silent_interval_s(baudrate: int) -> float:
    """t3.5, the line silence that ends a frame (s), at ``baudrate`` bit/s (section 2.5.1.1)."""
    return FIXED_GAP_S if baudrate > 19200 else 3.5 * BITS_PER_CHAR / baudrate


class WatlowF4RtuSim(ReplyBuffer, WatlowF4Sim):
    """A Watlow F4 answering Modbus RTU on a serial line at ``baudrate`` bit/s, address ``unit``."""

    def __init__(self, clock, chamber, *, baudrate: int = RTU_BAUDRATE, unit: int = UNIT_ID,
                 alarm_band_c: float = DEFAULT_ALARM_BAND_C):
        super().__init__(clock, chamber, alarm_band_c=alarm_band_c)
        self.baudrate = baudrate
        self.unit = unit
        self.crc_errors = 0
        self._in = bytearray()
        self._out = bytearray()
        self._last_rx_s: float | None = None
        self._lock = threading.RLock()

    @property
    def answering(self) -> bool:
        return super().answering and "disconnect" not in self.faults

    # ---- SerialDevice -----------------------------------------------------------------------
    def discard_input(self) -> None:
        with self._lock:
            self._in.clear()

    def receive(self, data: bytes) -> None:
        """Bytes from the master at the clock's current time."""
        with self._lock:
            now = self.clock.now()
            if self._last_rx_s is not None and now - self._last_rx_s > silent_interval_s(self.baudrate):
                self._in.clear()  # a partial frame followed by silence: discarded
            self._last_rx_s = now
            self._in += data
            while (n := self._frame_length()) is not None:
                frame = bytes(self._in[:n])
                del self._in[:n]
                if crc16_modbus(frame[:-2]) != frame[-2:]:
                    self.crc_errors += 1
                    self._in.clear()  # nothing after a bad frame can be trusted until the next gap
                    break
                self._on_frame(frame)

    # ---- frames -----------------------------------------------------------------------------
    def _frame_length(self) -> int | None:
        """Length of the frame at the start of the input buffer, None while it is incomplete."""
        buf = self._in
        if len(buf) < 4:
            return None
        fc = buf[1]
        if fc in _FIXED_REQUEST_LENGTH:
            n = _FIXED_REQUEST_LENGTH[fc]
        elif fc in _BYTE_COUNT_REQUESTS:
            if len(buf) < 7:
                return None
            n = 9 + buf[6]
        else:  # a layout we do not know: the frame is what came in, once its CRC holds
            if crc16_modbus(buf[:-2]) == buf[-2:]:
                return len(buf)
            if len(buf) >= MAX_ADU:
                self._in.clear()
            return None
        return n if len(buf) >= n else None

    def _on_frame(self, frame: bytes) -> None:
        address, pdu = frame[0], frame[1:-2]
        if address not in (self.unit, BROADCAST) or not self.answering:
            return
        reply = self.execute(pdu)
        if address != BROADCAST:
            adu = bytes([self.unit]) + reply
            self._out += adu + crc16_modbus(adu)

    def execute(self, pdu: bytes) -> bytes:
        """The response PDU to request ``pdu`` (function code and data), an exception included."""
        fc, data = pdu[0], pdu[1:]
        if fc == 3:
            if len(data) != 4:
                return _exception(fc, ExcCodes.ILLEGAL_VALUE)
            address, count = struct.unpack(">HH", data)
            if (exc := self.refusal(fc)) is not None:
                return _exception(fc, exc)
            if not 1 <= count <= MAX_REGS_PER_READ:
                return _exception(fc, ExcCodes.ILLEGAL_VALUE)
            values = self.read_registers(fc, address, count)
            if isinstance(values, ExcCodes):
                return _exception(fc, values)
            return struct.pack(f">BB{count}H", fc, 2 * count, *values)
        if fc == 6:
            if len(data) != 4:
                return _exception(fc, ExcCodes.ILLEGAL_VALUE)
            address, value = struct.unpack(">HH", data)
            rc = self.write_registers(fc, address, [value])
            return pdu if rc is None else _exception(fc, rc)  # the normal response is an echo
        if fc == 16:
            if len(data) < 5:
                return _exception(fc, ExcCodes.ILLEGAL_VALUE)
            address, count, nbytes = struct.unpack(">HHB", data[:5])
            if (exc := self.refusal(fc)) is not None:
                return _exception(fc, exc)
            if not 1 <= count <= MAX_REGS_PER_WRITE or nbytes != 2 * count or len(data) != 5 + nbytes:
                return _exception(fc, ExcCodes.ILLEGAL_VALUE)
            rc = self.write_registers(fc, address, list(struct.unpack(f">{count}H", data[5:])))
            return struct.pack(">BHH", fc, address, count) if rc is None else _exception(fc, rc)
        return _exception(fc, self.refusal(fc) or ExcCodes.ILLEGAL_FUNCTION)


def _exception(fc: int, code: ExcCodes) -> bytes:
    """Exception response PDU: function code + 0x80, exception code (application protocol section 7)."""
    return bytes(((fc | 0x80) & 0xFF, int(code)))
