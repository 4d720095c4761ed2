"""Replay backends: the far end of each instrument link, answering from the recording.

Every backend works in lockstep with the recording: each request the driver sends takes the next
recorded exchange of that link and is answered with the replies recorded after it (a request
that differs from the recorded one still gets them; the comparison afterwards names the
difference). Replies become available after the recorded latency (zero in a dry-run recording).
Before :meth:`Backend.go_live` (while the drivers open, when the recording lacks that traffic) a
backend hands requests to a simulator instead.

* :class:`ReplaySerial` - a :class:`bench.sim.registry.SerialDevice` for ``sim://`` URLs (line
  protocols, the board's binary frames); :class:`AcsBoardReplay` adds the data stream re-encoded
  from the recorded board rows, in the board's frame description, at the run times they were sent.
* :class:`ModbusTcpReplay` - Modbus TCP ADUs on an in-process stream (``modbus-tcp+stream://sim://...``,
  the default) answering recorded ADUs with the request's transaction id, in the caller's thread;
  :class:`ModbusReplayServer` - the same on a real Modbus TCP server on 127.0.0.1 (any free port;
  ``BENCH_DRYRUN_TRANSPORT=socket``); :class:`ModbusRtuReplay` - the same controller on Modbus RTU,
  a ``sim://`` serial far end (``modbus-rtu+stream://sim://...``, or ``modbus-rtu://`` on the socket path).
* :class:`CanReplayNode` - a participant on a synchronous in-process CAN bus (answering in the
  sender's thread; the default) or on a python-can virtual bus (its own thread), answering SDO
  requests and SYNC with the recorded frames.
"""

from __future__ import annotations

import socket
import struct
import threading
from collections import deque
from typing import Callable

import can
import numpy as np

from bench.replay.recording import Exchange
from bench.sim.watlow_f4_rtu import crc16_modbus
from drivers.board_frames import FrameDescription
from drivers.frame_schema import builtin_description
from drivers.can_transport import SyncBus

Exhausted = Callable[[str], None]


class Backend:
    """Shared lockstep logic: the exchanges of one link and what to do when they run out."""

    def __init__(self, label: str, exchanges: list[Exchange], on_exhausted: Exhausted):
        self.label = label
        self.exchanges = exchanges
        self.pos = 0
        self.live = False
        self.on_exhausted = on_exhausted
        self.extra_requests = 0

    def go_live(self) -> None:
        self.live = True

    def next_exchange(self) -> Exchange | None:
        if self.pos >= len(self.exchanges):
            self.extra_requests += 1
            if self.extra_requests == 1:
                self.on_exhausted(f"replay: the recording has no more commands for {self.label}")
            return None
        ex = self.exchanges[self.pos]
        self.pos += 1
        return ex


# ---- serial -------------------------------------------------------------------------------------
class ReplaySerial(Backend):
    """Serial far end (SerialDevice protocol). One ``write`` of the driver is one command."""

    def __init__(self, label: str, exchanges: list[Exchange], on_exhausted: Exhausted, clock, prelude=None):
        super().__init__(label, exchanges, on_exhausted)
        self.clock = clock
        self.prelude = prelude
        self._out = bytearray()
        self._later: deque[tuple[float, bytes]] = deque()
        self._lock = threading.RLock()

    # hooks for the board's data stream
    def _advance(self, t_s: float) -> None:
        while self._later and self._later[0][0] <= t_s + 1e-9:
            self._out += self._later.popleft()[1]

    def _on_command(self, ex: Exchange) -> None:
        pass

    def receive(self, data: bytes) -> None:
        if not self.live and self.prelude is not None:
            self.prelude.receive(data)
            return
        with self._lock:
            now = self.clock.now()
            self._advance(now)
            ex = self.next_exchange()
            if ex is None:
                return
            self._on_command(ex)
            for t, _name, raw in ex.replies:
                delay = max(0.0, t - ex.t_s) if self.clock_delays else 0.0
                if delay <= 0 and not self._later:
                    self._out += raw
                else:
                    self._later.append((now + delay, raw))

    clock_delays = True

    def take_output(self, t_s: float, max_bytes: int | None = None) -> bytes:
        if not self.live and self.prelude is not None:
            return self.prelude.take_output(t_s, max_bytes)
        with self._lock:
            self._advance(t_s)
            k = len(self._out) if max_bytes is None else min(max_bytes, len(self._out))
            data = bytes(self._out[:k])
            del self._out[:k]
            return data

    def pending_bytes(self, t_s: float) -> int:
        if not self.live and self.prelude is not None:
            return self.prelude.pending_bytes(t_s)
        with self._lock:
            self._advance(t_s)
            return len(self._out)

    def next_output_time(self) -> float | None:
        if not self.live and self.prelude is not None:
            return self.prelude.next_output_time()
        with self._lock:
            if self._out:
                return self.clock.now()
            return self._next_time()

    def _next_time(self) -> float | None:
        return self._later[0][0] if self._later else None

    def set_baudrate(self, baudrate: int) -> None:
        if self.prelude is not None:
            self.prelude.set_baudrate(baudrate)

    def discard_input(self) -> None:
        if not self.live and self.prelude is not None:
            self.prelude.discard_input()


class AcsBoardReplay(ReplaySerial):
    """The sensor board: command frames as :class:`ReplaySerial`, plus its data frames re-encoded
    from the recorded stream rows. Rows belong to the streaming segment that the k-th recorded
    START_STREAM opened; a row is sent at run time ``time - lag`` of its segment, where ``lag`` is
    how late the runner stamped the first row (its ``time`` minus one sample period after the
    START_STREAM command), so the runner's batches come out as in the recording."""

    def __init__(self, label, exchanges, on_exhausted, clock, stream: dict[str, np.ndarray] | None, prelude=None,
                 description: FrameDescription | None = None):
        super().__init__(label, exchanges, on_exhausted, clock, prelude)
        self.description = description or builtin_description()
        """The board's frames (the recorded config's frame description; ours by default)."""
        starts = np.array([ex.t_s for ex in exchanges if ex.name == "START_STREAM"], dtype=float)
        self._segment_of_start = {id(ex): k for k, ex in enumerate(e for e in exchanges if e.name == "START_STREAM")}
        n = 0 if stream is None else int(stream["time"].shape[0])
        self._segments: list[tuple[int, int]] = []
        self._emit_t = np.zeros(n)
        if n:
            t = stream["time"]
            seg = np.searchsorted(starts, t, side="left") - 1  # row strictly after its START_STREAM
            for k in range(len(starts)):
                idx = np.nonzero(seg == k)[0]
                if idx.size == 0:
                    self._segments.append((0, 0))
                    continue
                a, b = int(idx[0]), int(idx[-1]) + 1
                bt = stream["board_time"][a:b]
                period = float(np.median(np.diff(bt))) if b - a > 1 else 0.0
                lag = max(0.0, float(t[a]) - (starts[k] + period))
                self._emit_t[a:b] = t[a:b] - lag
                self._segments.append((a, b))
            d = self.description
            raw, _sat = d.to_raw({f.name: stream[f.name] for f in d.signals})
            for f in d.recorded:
                if f.role in ("counter", "status"):
                    raw[f.name] = stream[f.name]
            raw["board_time"] = d.clock_ticks(stream["board_time"])
            self._raw = raw
        self._cur: tuple[int, int] | None = None  # [next row, end) of the segment streaming now
        self.frames_sent = 0

    def _on_command(self, ex: Exchange) -> None:
        if ex.name == "START_STREAM":
            k = self._segment_of_start.get(id(ex))
            if k is not None and k < len(self._segments):
                self._cur = self._segments[k]
        elif ex.name in ("STOP_STREAM", "SENSOR_POWER"):
            self._cur = None

    def _advance(self, t_s: float) -> None:
        if self._cur is not None:
            a, b = self._cur
            if a < b and self._emit_t[a] <= t_s + 1e-6:  # a row is due (the driver asks far more often than rows come)
                j = a + int(np.searchsorted(self._emit_t[a:b], t_s + 1e-6, side="right"))
                if j > a:
                    # replies due before these frames go first
                    while self._later and self._later[0][0] <= self._emit_t[a]:
                        self._out += self._later.popleft()[1]
                    self._out += self.description.encode_data({k: v[a:j] for k, v in self._raw.items()})
                    self.frames_sent += j - a
                    self._cur = (j, b)
        super()._advance(t_s)

    def _next_time(self) -> float | None:
        times = []
        if self._cur is not None and self._cur[0] < self._cur[1]:
            times.append(float(self._emit_t[self._cur[0]]))
        if self._later:
            times.append(self._later[0][0])
        return min(times) if times else None


class ModbusRtuReplay(ReplaySerial):
    """Modbus RTU far end of the chamber controller: one write of the driver is one request frame,
    answered at once with the recorded reply frames (pymodbus's serial client polls the port on the
    wall clock, so a reply held back in virtual time would never arrive); a request recorded
    without reply stays unanswered (a recorded timeout). Out of recorded exchanges: exception 4
    (device failure), as :class:`ModbusReplayServer`."""

    clock_delays = False

    def receive(self, data: bytes) -> None:
        exhausted = self.live and self.pos >= len(self.exchanges)
        super().receive(data)
        if exhausted and len(data) >= 2:
            adu = bytes((data[0], (data[1] | 0x80) & 0xFF, 4))
            with self._lock:
                self._out += adu + crc16_modbus(adu)


# ---- Modbus TCP ---------------------------------------------------------------------------------
DEVICE_FAILURE = 4
"""Modbus exception a replayed controller answers once the recording has no more exchanges."""


def tcp_replies(req: bytes, ex: Exchange | None) -> bytes:
    """What a replayed Modbus TCP controller sends for request ADU ``req``: the recorded reply ADUs of
    exchange ``ex`` with the request's transaction id, or exception 4 (device failure) when the
    recording has none (out of exchanges, or a request recorded without answer)."""
    if ex is None or not ex.replies:
        fc = req[7] if len(req) > 7 else 3
        unit = req[6] if len(req) > 6 else 1
        return req[:4] + struct.pack(">HBBB", 3, unit, (fc | 0x80) & 0xFF, DEVICE_FAILURE)
    return b"".join(req[:2] + raw[2:] for _t, _n, raw in ex.replies)


class ModbusTcpReplay(ReplaySerial):
    """Modbus TCP far end of the chamber controller on an in-process stream: one write of the driver
    is one request ADU, answered at once (:func:`tcp_replies`). Before :meth:`go_live` requests go to
    the prelude simulator's stream."""

    clock_delays = False

    def receive(self, data: bytes) -> None:
        if not self.live and self.prelude is not None:
            self.prelude.receive(data)
            return
        with self._lock:
            self._out += tcp_replies(bytes(data), self.next_exchange())


class ModbusReplayServer(Backend):
    """Modbus TCP server on 127.0.0.1 answering each request ADU with the recorded reply ADU (its
    transaction id set to the request's). Out of recorded exchanges: exception 4 (device failure).
    Before :meth:`go_live`: requests are relayed to the simulator at ``prelude_addr``."""

    def __init__(self, label, exchanges, on_exhausted, prelude_addr: tuple[str, int] | None = None):
        super().__init__(label, exchanges, on_exhausted)
        self.prelude_addr = prelude_addr
        self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._listener.bind(("127.0.0.1", 0))
        self._listener.listen(4)
        self.port = self._listener.getsockname()[1]
        self._stop = False
        self._conns: list[socket.socket] = []
        self._thread = threading.Thread(target=self._serve, name=f"replay-modbus-{label}", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while not self._stop:
            try:
                conn, _ = self._listener.accept()
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._conns.append(conn)
            threading.Thread(target=self._client, args=(conn,), daemon=True).start()

    def _client(self, conn: socket.socket) -> None:
        upstream = None
        try:
            while not self._stop:
                head = _recv_exact(conn, 6)
                if head is None:
                    return
                (length,) = struct.unpack(">H", head[4:6])
                body = _recv_exact(conn, length)
                if body is None:
                    return
                req = head + body
                if not self.live and self.prelude_addr is not None:
                    if upstream is None:
                        upstream = socket.create_connection(self.prelude_addr, timeout=5)
                    upstream.sendall(req)
                    h = _recv_exact(upstream, 6)
                    b = _recv_exact(upstream, struct.unpack(">H", h[4:6])[0]) if h else None
                    if h is None or b is None:
                        return
                    conn.sendall(h + b)
                    continue
                conn.sendall(tcp_replies(req, self.next_exchange()))
        except OSError:
            return
        finally:
            if upstream is not None:
                upstream.close()
            conn.close()

    def close(self) -> None:
        self._stop = True
        try:
            self._listener.close()
        except OSError:
            pass
        for c in self._conns:
            try:
                c.shutdown(socket.SHUT_RDWR)
                c.close()
            except OSError:
                pass
        self._thread.join(1.0)


def _recv_exact(conn: socket.socket, n: int) -> bytes | None:
    buf = bytearray()
    while len(buf) < n:
        chunk = conn.recv(n - len(buf))
        if not chunk:
            return None
        buf += chunk
    return bytes(buf)


# ---- CAN ------------------------------------------------------------------------------------------
class CanReplayNode(Backend):
    """A participant on a CAN channel answering the driver's frames (SDO requests, SYNC) with the
    recorded reply frames (recorded as 2-byte big-endian CAN id + data). Out of recorded exchanges:
    SDO abort 0x08000000 (general error) to an SDO request, nothing to SYNC. ``sync``: the channel
    is a :class:`~drivers.can_transport.SyncBus` one (answers in the sender's thread), else a
    python-can virtual channel served by a thread of its own."""

    def __init__(self, label, exchanges, on_exhausted, channel: str, *, sync: bool = False):
        super().__init__(label, exchanges, on_exhausted)
        self.channel = channel
        self.sync = sync
        self._bus: can.BusABC | None = None
        self._thread: threading.Thread | None = None
        self._stop = False

    def go_live(self) -> None:
        super().go_live()
        if self.sync:
            self._bus = SyncBus(self.channel)
            self._bus.add_listener(self._on_frame)  # a bound method: no cycle through the bus (freed when closed)
            return
        self._bus = can.Bus(interface="virtual", channel=self.channel, receive_own_messages=False)
        self._thread = threading.Thread(target=self._serve, name=f"replay-can-{self.label}", daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        bus = self._bus
        while not self._stop:
            msg = bus.recv(0.05)
            if msg is not None:
                self._answer(bus, msg)

    def _on_frame(self, msg: can.Message) -> None:
        bus = self._bus
        if bus is not None:
            self._answer(bus, msg)

    def _answer(self, bus: can.BusABC, msg: can.Message) -> None:
        """Send the recorded replies to the driver's frame ``msg``."""
        if msg.is_error_frame:
            return
        ex = self.next_exchange()
        if ex is None:
            if 0x600 <= msg.arbitration_id <= 0x67F and len(msg.data) >= 4:
                node = msg.arbitration_id - 0x600
                data = bytes([0x80, msg.data[1], msg.data[2], msg.data[3]]) + (0x08000000).to_bytes(4, "little")
                bus.send(can.Message(arbitration_id=0x580 + node, data=data, is_extended_id=False))
            return
        for _t, _n, raw in ex.replies:
            bus.send(can.Message(arbitration_id=int.from_bytes(raw[:2], "big"), data=raw[2:], is_extended_id=False))

    def close(self) -> None:
        self._stop = True
        if self._thread is not None:
            self._thread.join(1.0)
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None
