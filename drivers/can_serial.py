"""A byte-stream "serial tunnel" over classic CAN: a pyserial-compatible port on a python-can bus.

The ACS board's byte stream is self-delimiting (sync, length, CRC-16), so over CAN it is carried
as plain bytes (``docs/acs-board-can.md``): host -> board on 11-bit id ``0x300 + node``, board ->
host on ``0x380 + node``; each frame carries the next 1..8 bytes of the stream in order, DLC =
byte count, no padding, no sequence numbers, no flow control. A lost frame loses its bytes; the
protocol's CRC and resynchronising decoder notice, exactly as with bytes lost on a UART.

:class:`CanSerialPort` offers what :class:`drivers.acs_board.AcsBoard` uses of a pyserial port
(``read``, ``write``, ``in_waiting``, ``timeout``, ``baudrate``, ``reset_input_buffer``,
``close``; it is a :class:`serial.SerialBase`, so ``read_until``/context manager work too).
A receive thread moves board -> host frames into a byte buffer as they arrive.

Waiting. Without a clock, or with a wall clock, ``read`` waits up to ``timeout`` s of wall time.
With a virtual clock (dry-run, simulated board) the port asks the far end to *sync*: it sends a
remote frame (RTR) on the board -> host id; the simulator (:mod:`bench.sim.can_serial_bridge`)
answers, after everything it has produced up to the current run time, with a zero-length data
frame on that id (the sync marker; it carries no stream bytes). So:

* when run time moved since the port last looked (someone slept on the clock), ``in_waiting``
  and ``read`` first sync: a poll after a sleep sees exactly the data up to now;
* a ``read`` that cannot be satisfied syncs (the answer to a command written before arrives
  before the marker); if still short, nothing more comes at this run time, so it advances the
  run clock to the read deadline, syncs again and returns what it has.

A sync gives up when the bus stays silent for ``sync_timeout_s`` of wall time (bus-off, a far end
that does not answer RTRs); that is the only wall-time wait of a dry-run. Real boards on a wall
clock never see an RTR.
"""

from __future__ import annotations

import math
import threading
import time
import urllib.parse

import can
import serial
from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from drivers.errors import InstrumentError
from drivers.acs_protocol import DATA_FRAME_LEN
from drivers.can_transport import CanUrl, open_bus, parse_can_url

DEFAULT_NODE = 0x10
HOST_TO_BOARD_BASE = 0x300  # + node: host -> board stream bytes
BOARD_TO_HOST_BASE = 0x380  # + node: board -> host stream bytes
DEFAULT_BITRATE = 500_000  # bit/s; CiA 301 / python-can slcan "S6"
MAX_DATA = 8  # classic CAN payload bytes per frame
MPU6000_MAX_ODR_HZ = 1000  # ESTCube-2 Table 2.1; the board's own limit whatever the link

RX_POLL_S = 0.05  # receive thread: bus.recv timeout (how fast close() is noticed)
RX_BATCH = 64  # frames the receive thread moves to the buffer per lock
SYNC_TIMEOUT_S = 0.15  # virtual clock: a sync gives up after this much wall time without any frame


class CanLinkError(SerialException):
    """The CAN link failed (python-can error while sending or receiving). A ``SerialException``, so
    serial drivers turn it into :class:`bench.errors.InstrumentError` as for a vanished UART."""


# ---- ids and bandwidth ------------------------------------------------------------------------
def can_ids(node: int) -> tuple[int, int]:
    """(host -> board id, board -> host id) of board ``node`` (1..127)."""
    if not 1 <= int(node) <= 127:
        raise ValueError(f"CAN serial node {node} outside 1..127")
    return HOST_TO_BOARD_BASE + int(node), BOARD_TO_HOST_BASE + int(node)


def frame_bits(n_bytes: int) -> int:
    """Worst-case bits on the wire of a classic base-format (11-bit id) data frame with ``n_bytes``
    of data, including worst-case bit stuffing and the 3-bit interframe space:
    ``47 + 8n + floor((34 + 8n - 1) / 4)`` (Davis, Burns, Bril, Lukkien 2007, eq. 3): 135 bits
    for 8 bytes, 111 without stuffing."""
    if not 0 <= n_bytes <= MAX_DATA:
        raise ValueError(f"classic CAN carries 0..8 data bytes, not {n_bytes}")
    return 47 + 8 * n_bytes + (34 + 8 * n_bytes - 1) // 4


def chunk_bits(n_bytes: int) -> int:
    """Worst-case wire bits to carry ``n_bytes`` of stream sent in one go (8-byte frames, then the rest)."""
    full, rest = divmod(int(n_bytes), MAX_DATA)
    return full * frame_bits(MAX_DATA) + (frame_bits(rest) if rest else 0)


def max_records_per_s(bitrate: float, record_len: int = DATA_FRAME_LEN) -> float:
    """Records of ``record_len`` bytes per second the link carries in the worst case: every record
    segmented on its own (a 38-byte data frame = 4 x 8 + 6 bytes = 5 CAN frames, 655 bits)."""
    return float(bitrate) / chunk_bits(record_len)


def max_odr_hz(bitrate: float) -> int:
    """Highest output data rate (Hz) of the board over CAN at ``bitrate`` bit/s: the link limit
    (763 Hz at 500 kbit/s, 1526 at 1 Mbit/s) capped by the MPU-6000's 1000 Hz."""
    return min(MPU6000_MAX_ODR_HZ, int(max_records_per_s(bitrate)))


def uart_equivalent_baud(bitrate: float, record_len: int = DATA_FRAME_LEN) -> int:
    """The 8N1 UART baud rate that carries as many ``record_len``-byte records per second as CAN at
    ``bitrate`` (10 UART bits per byte): what a serial-device simulator is told as its link rate."""
    return int(math.floor(max_records_per_s(bitrate, record_len))) * record_len * 10


def segment(data: bytes) -> list[bytes]:
    """Split a byte string into CAN payloads: consecutive pieces of 8 bytes, the last one shorter."""
    data = bytes(data)
    return [data[i:i + MAX_DATA] for i in range(0, len(data), MAX_DATA)]


# ---- the port ---------------------------------------------------------------------------------
class CanSerialPort(SerialBase):
    """A serial-port look-alike whose bytes travel in CAN frames (module docstring).

    :param bus: an open python-can bus
    :param node: board node (1..127): ids ``0x300 + node`` (writes) and ``0x380 + node`` (reads)
    :param bitrate: the CAN bit rate in bit/s, reported as ``baudrate``
    :param timeout: read timeout in s (None: wait for ``size`` bytes; with a virtual clock never forever)
    :param clock: the run clock; a virtual one makes reads wait in run time (module docstring)
    :param own_bus: ``close`` shuts the bus down
    """

    def __init__(self, bus: can.BusABC, node: int = DEFAULT_NODE, *, bitrate: int = DEFAULT_BITRATE,
                 timeout: float | None = 0.5, clock=None, own_bus: bool = True,
                 sync_timeout_s: float = SYNC_TIMEOUT_S):
        self.node = int(node)
        self.tx_id, self.rx_id = can_ids(self.node)
        self.bus = bus
        self.clock = clock
        self.own_bus = own_bus
        self.sync_timeout_s = float(sync_timeout_s)
        self.bitrate = int(bitrate)
        self._cond = threading.Condition()
        self._buf = bytearray()
        self._rx_frames = 0  # board -> host frames received (all time)
        self.error_frames = 0  # CAN error frames seen on the bus
        self.other_frames = 0  # frames with other ids (other nodes, CANopen traffic)
        self._rx_error: BaseException | None = None
        self._want: int | None = 0  # bytes the waiting reader needs (None: wake only on error/close)
        self._stop = threading.Event()
        self._syncs_sent = 0  # RTRs sent (virtual clock only)
        self._markers = 0  # zero-length sync markers received
        self.sync_failures = 0  # syncs that gave up (silent bus)
        self._seen_t = clock.now() if clock is not None else 0.0
        super().__init__(port=None, baudrate=self.bitrate, timeout=timeout, write_timeout=timeout)
        self._port = f"can:{getattr(bus, 'channel_info', '?')}:node{self.node}"
        self.is_open = True
        self._thread = threading.Thread(target=self._rx_loop, name=f"can-serial rx {self._port}", daemon=True)
        self._thread.start()

    # ---- pyserial plumbing ------------------------------------------------------------------
    def open(self) -> None:
        raise SerialException("a CanSerialPort is opened by open_can_serial (or constructed on an open bus)")

    def _reconfigure_port(self) -> None:
        if self._baudrate != self.bitrate:
            wanted, self._baudrate = self._baudrate, self.bitrate
            raise SerialException(f"the CAN bit rate ({self.bitrate} bit/s) is fixed when the bus is opened, not {wanted}")

    def close(self) -> None:
        """Stop receiving and shut the bus down (if owned). Safe to call twice."""
        if not getattr(self, "is_open", False):
            return
        self._stop.set()
        with self._cond:
            self.is_open = False
            self._cond.notify_all()
        if self._thread is not threading.current_thread():
            self._thread.join(2 * RX_POLL_S + 1.0)
        if self.own_bus:
            try:
                self.bus.shutdown()
            except (can.CanError, OSError, SerialException) as exc:
                raise CanLinkError(f"{self._port}: shutting the CAN bus down failed: {exc}") from None

    @property
    def link_bytes_per_s(self) -> float:
        """Stream bytes per second the CAN link carries in the worst case (38-byte records)."""
        return max_records_per_s(self.bitrate) * DATA_FRAME_LEN

    @property
    def in_waiting(self) -> int:
        self._check_open()
        self._settle_if_time_moved()
        with self._cond:
            if not self._buf and self._rx_error is not None:
                self._raise_rx_error()
            return len(self._buf)

    @property
    def out_waiting(self) -> int:
        return 0  # python-can sends synchronously

    def read(self, size: int = 1) -> bytes:
        self._check_open()
        if size <= 0:
            return b""
        virtual = self._virtual()
        if virtual:
            self._settle_if_time_moved()
        with self._cond:
            if len(self._buf) >= size or self._timeout == 0:
                return self._take(size)
        if not virtual:
            deadline = None if self._timeout is None else time.monotonic() + self._timeout
            with self._cond:
                self._want = size
                try:
                    while len(self._buf) < size and self._rx_error is None and self.is_open:
                        left = None if deadline is None else deadline - time.monotonic()
                        if left is not None and left <= 0:
                            break
                        self._cond.wait(left if left is not None else RX_POLL_S)
                finally:
                    self._want = 0
                return self._take(size)
        # virtual run clock: first all the far end sends at this run time, then let run time pass
        deadline_t = None if self._timeout is None else self.clock.now() + self._timeout
        self._sync(size)
        with self._cond:
            if len(self._buf) >= size or deadline_t is None:
                return self._take(size)
        self.clock.sleep_until(deadline_t)
        self._seen_t = self.clock.now()
        self._sync(size)
        with self._cond:
            return self._take(size)

    def write(self, data) -> int:
        self._check_open()
        data = serial.to_bytes(data)
        try:
            for piece in segment(data):
                self.bus.send(can.Message(arbitration_id=self.tx_id, is_extended_id=False, data=piece),
                              timeout=self._write_timeout)
        except (can.CanError, OSError, SerialException) as exc:
            raise CanLinkError(f"{self._port}: sending on the CAN bus failed: {exc}") from None
        return len(data)

    def flush(self) -> None:
        self._check_open()

    def reset_input_buffer(self) -> None:
        self._check_open()
        with self._cond:
            self._buf.clear()

    def reset_output_buffer(self) -> None:
        self._check_open()  # nothing is queued: every write is on the bus when it returns

    def cancel_read(self) -> None:
        pass

    def cancel_write(self) -> None:
        pass

    def _update_break_state(self) -> None:
        pass

    def _update_rts_state(self) -> None:
        pass

    def _update_dtr_state(self) -> None:
        pass

    @property
    def cts(self) -> bool:
        return True

    @property
    def dsr(self) -> bool:
        return True

    @property
    def ri(self) -> bool:
        return False

    @property
    def cd(self) -> bool:
        return True

    # ---- internals --------------------------------------------------------------------------
    def _check_open(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()

    def _virtual(self) -> bool:
        return self.clock is not None and bool(getattr(self.clock, "virtual", False))

    def _raise_rx_error(self) -> None:
        raise CanLinkError(f"{self._port}: receiving from the CAN bus failed: {self._rx_error}")

    def _take(self, size: int) -> bytes:
        """Up to ``size`` buffered bytes (caller holds the lock); the receive error once drained."""
        if not self._buf and self._rx_error is not None:
            self._raise_rx_error()
        out = bytes(self._buf[:size])
        del self._buf[:size]
        return out

    def _sync(self, size: int | None) -> bool:
        """Ask the far end for everything up to the current run time (RTR) and wait in wall time for
        its marker, or until ``size`` bytes are buffered. False when the bus stayed silent for
        ``sync_timeout_s`` (the outstanding markers are then forgotten)."""
        try:
            self.bus.send(can.Message(arbitration_id=self.rx_id, is_extended_id=False, is_remote_frame=True, dlc=0),
                          timeout=self._write_timeout)
        except (can.CanError, OSError, SerialException) as exc:
            raise CanLinkError(f"{self._port}: sending on the CAN bus failed: {exc}") from None
        with self._cond:
            self._syncs_sent += 1
            target = self._syncs_sent
            self._want = size
            try:
                while self._markers < target and self._rx_error is None and self.is_open:
                    if size is not None and len(self._buf) >= size:
                        return True
                    seen = self._rx_frames
                    self._cond.wait(self.sync_timeout_s)
                    if self._rx_frames == seen and self._markers < target:
                        self.sync_failures += 1
                        self._syncs_sent = self._markers
                        return False
                return self._markers >= target
            finally:
                self._want = 0

    def _settle_if_time_moved(self) -> None:
        if not self._virtual():
            return
        now = self.clock.now()
        if now == self._seen_t:
            return
        self._seen_t = now
        self._sync(None)

    def _rx_loop(self) -> None:
        while not self._stop.is_set():
            try:
                msgs = []
                msg = self.bus.recv(timeout=RX_POLL_S)
                while msg is not None:
                    msgs.append(msg)
                    if len(msgs) >= RX_BATCH:
                        break
                    msg = self.bus.recv(timeout=0)
            except Exception as exc:  # noqa: BLE001 - any bus failure ends reception; read() reports it
                if not self._stop.is_set():
                    with self._cond:
                        self._rx_error = exc
                        self._cond.notify_all()
                return
            if msgs:
                self._on_messages(msgs)

    def _on_messages(self, msgs: list[can.Message]) -> None:
        with self._cond:
            markers = self._markers
            for msg in msgs:
                if msg.is_error_frame:
                    self.error_frames += 1
                elif msg.arbitration_id != self.rx_id or msg.is_extended_id or msg.is_remote_frame or msg.is_fd:
                    self.other_frames += 1
                else:
                    self._rx_frames += 1
                    if msg.dlc == 0:
                        self._markers += 1
                    else:
                        self._buf += msg.data
            want = self._want
            if want == 0 or (want is not None and len(self._buf) >= want) or self._markers != markers:
                self._cond.notify_all()


# ---- URL --------------------------------------------------------------------------------------
def parse_can_serial_url(url: str) -> tuple[CanUrl, int, int]:
    """(parsed URL, node, bit rate) of ``can://INTERFACE/CHANNEL?node=N[&bitrate=B]``.

    ``node`` defaults to 0x10 (16) here, not to :mod:`drivers.can_transport`'s CANopen default 1;
    the bit rate comes from ``bitrate`` (slcan, socketcan), default 500000 (virtual buses take no
    ``bitrate`` option: can_transport refuses it, so their nominal bit rate is 500000).
    """
    u = parse_can_url(url)
    query = url.rpartition("?")[2] if "?" in url else ""
    explicit = {k for k, _ in urllib.parse.parse_qsl(query, keep_blank_values=True)}
    node = u.node if "node" in explicit else DEFAULT_NODE
    try:
        bitrate = int(u.options.get("bitrate", DEFAULT_BITRATE))
    except ValueError:
        raise InstrumentError(f"CAN URL {url!r}: bitrate must be an integer (bit/s)") from None
    if bitrate <= 0:
        raise InstrumentError(f"CAN URL {url!r}: bitrate must be positive")
    return u, node, bitrate


def open_can_serial(url: str, timeout_s: float = 0.5, clock=None) -> CanSerialPort:
    """Open the board's byte stream on the CAN bus of ``url`` (:func:`parse_can_serial_url`).

    Raises :class:`InstrumentError` when the URL is wrong or the bus cannot be opened.
    """
    u, node, bitrate = parse_can_serial_url(url)
    bus = open_bus(u)
    try:
        return CanSerialPort(bus, node, bitrate=bitrate, timeout=timeout_s, clock=clock, own_bus=True)
    except (ValueError, SerialException) as exc:
        bus.shutdown()
        raise InstrumentError(f"cannot open CAN serial tunnel on {url!r}: {exc}") from None
