"""Simulated SLCAN (LAWICEL) USB-CAN adapter: a serial device bridging to an in-process CAN bus.

Implements :class:`bench.sim.registry.SerialDevice`, so it is reached in-process through
``sim://NAME`` (``can://slcan/sim://NAME`` for the rate table driver) and from another process
through ``bench sim serve`` / :mod:`bench.sim.pty_server` on a pseudo-terminal, where python-can's
``slcan`` interface talks to it as to a CANable or CANUSB.

Protocol (LAWICEL CANUSB manual; what python-can ``can/interfaces/slcan.py`` 4.6 sends and
parses): commands end with CR; success is answered by CR, failure by BEL (0x07).

* ``S0``..``S8`` bit rate (10k..1M), ``sXXYY`` BTR registers: only while closed;
* ``O`` open, ``L`` open listen-only, ``C`` close;
* ``V`` -> ``Vhhss`` hardware/software version, ``N`` -> ``Nxxxx`` serial number;
* ``F`` -> ``Fxx`` status flags (read and cleared; bit 3 data overrun, bit 7 bus error);
* ``tIIILDD..`` / ``TIIIIIIIILDD..`` standard / extended data frame -> ``z`` / ``Z`` + CR;
  ``rIIIL`` / ``RIIIIIIIIL`` remote frames; frames from the bus are sent as the same text + CR;
* ``Z0``/``Z1`` (timestamps), ``X``, ``W``, ``M``, ``m`` (filters): accepted, no effect.

CAN error frames on the bus have no SLCAN text: they set the bus-error flag (bit 7) of ``F``.
The gateway's clock is a WallClock by default: the CAN side answers asynchronously in wall time,
so a port read must wait in wall time, not advance a virtual run clock.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import can

from bench.clock import WallClock

HW_VERSION = "10"  # reported by V as hh (two decimal digits, as python-can parses them)
SW_VERSION = "13"
BITRATE_CODES = {"0": 10_000, "1": 20_000, "2": 50_000, "3": 100_000, "4": 125_000,
                 "5": 250_000, "6": 500_000, "7": 750_000, "8": 1_000_000, "9": 83_300}  # LAWICEL S0..S8 (+ python-can S9)
OK = b"\r"
BEL = b"\a"
MAX_LINE = 64  # longest valid command: T + 8 id + 1 dlc + 16 data = 26 chars; longer is cut
MAX_OUTPUT = 65_536  # bytes buffered towards the host before frames are dropped (overrun flag)
FLAG_DATA_OVERRUN = 0x08
FLAG_BUS_ERROR = 0x80


class SlcanError(ValueError):
    """A line that is not a valid SLCAN frame."""


@dataclass(frozen=True)
class _Kind:
    extended: bool
    remote: bool


_FRAME_KINDS = {"t": _Kind(False, False), "T": _Kind(True, False), "r": _Kind(False, True), "R": _Kind(True, True)}


def decode_frame(line: str) -> can.Message:
    """One SLCAN frame line (without CR) -> :class:`can.Message`; :class:`SlcanError` otherwise."""
    if not line or line[0] not in _FRAME_KINDS:
        raise SlcanError(f"not a frame command: {line[:16]!r}")
    kind = _FRAME_KINDS[line[0]]
    n_id = 8 if kind.extended else 3
    head = line[1:1 + n_id + 1]
    if len(head) != n_id + 1 or not all(c in "0123456789abcdefABCDEF" for c in head):
        raise SlcanError(f"bad identifier or length in {line[:16]!r}")
    can_id = int(head[:n_id], 16)
    if can_id > (0x1FFFFFFF if kind.extended else 0x7FF):
        raise SlcanError(f"identifier 0x{can_id:X} out of range")
    dlc = int(head[n_id], 16)
    if dlc > 8:
        raise SlcanError(f"data length {dlc} > 8")
    body = line[1 + n_id + 1:]
    if kind.remote:
        if body:
            raise SlcanError("remote frame with data")
        data = b""
    else:
        if len(body) != 2 * dlc or not all(c in "0123456789abcdefABCDEF" for c in body):
            raise SlcanError(f"expected {dlc} data bytes in {line[:32]!r}")
        data = bytes.fromhex(body)
    return can.Message(arbitration_id=can_id, is_extended_id=kind.extended, is_remote_frame=kind.remote,
                       dlc=dlc, data=data)


def encode_frame(msg: can.Message) -> str:
    """:class:`can.Message` -> SLCAN frame text (without CR), as python-can's slcan ``send`` writes it."""
    if msg.is_remote_frame:
        return f"R{msg.arbitration_id:08X}{msg.dlc:d}" if msg.is_extended_id else f"r{msg.arbitration_id:03X}{msg.dlc:d}"
    head = f"T{msg.arbitration_id:08X}" if msg.is_extended_id else f"t{msg.arbitration_id:03X}"
    return f"{head}{len(msg.data):d}{bytes(msg.data).hex().upper()}"


class SlcanGatewaySim:
    """A LAWICEL adapter whose CAN side is ``bus`` (a python-can bus or a virtual channel name)."""

    def __init__(self, bus: can.BusABC | str, clock=None, serial_number: str = "SIM1", baudrate: int = 115_200) -> None:
        self.clock = clock or WallClock()
        self.baudrate = baudrate
        self.serial_number = serial_number[:4]
        self._own_bus = isinstance(bus, str)
        self.bus = can.Bus(interface="virtual", channel=bus, receive_own_messages=False) if self._own_bus else bus
        self.is_open = False
        self.listen_only = False
        self.bitrate: int | None = None
        self.flags = 0
        self._in = bytearray()
        self._out = bytearray()
        self._lock = threading.RLock()

    def close(self) -> None:
        if self._own_bus:
            self.bus.shutdown()

    # ---- SerialDevice -----------------------------------------------------------------------
    def set_baudrate(self, baudrate: int) -> None:
        self.baudrate = int(baudrate)

    def discard_input(self) -> None:
        with self._lock:
            self._in.clear()

    def receive(self, data: bytes) -> None:
        with self._lock:
            for b in bytes(data):
                if b == 0x0D:
                    line, self._in = bytes(self._in), bytearray()
                    self._out += self.handle_line(line)
                elif b == 0x0A and not self._in:
                    continue  # tolerate CR LF from terminals
                elif len(self._in) < MAX_LINE:
                    self._in.append(b)

    def take_output(self, t_s: float, max_bytes: int | None = None) -> bytes:
        with self._lock:
            self._pump()
            k = len(self._out) if max_bytes is None else min(max_bytes, len(self._out))
            data = bytes(self._out[:k])
            del self._out[:k]
            return data

    def pending_bytes(self, t_s: float) -> int:
        with self._lock:
            self._pump()
            return len(self._out)

    def next_output_time(self) -> float | None:
        with self._lock:
            self._pump()
            return self.clock.now() if self._out else None

    # ---- protocol ---------------------------------------------------------------------------
    def handle_line(self, raw: bytes) -> bytes:
        """Answer one command line (without CR). Never raises: bad input is answered with BEL."""
        try:
            line = raw.decode("ascii")
        except UnicodeDecodeError:
            return BEL
        if not line:
            return OK  # an empty line is a no-op; python-can sends none, terminals do
        cmd = line[0]
        if cmd in _FRAME_KINDS:
            if not self.is_open or self.listen_only:
                return BEL
            try:
                msg = decode_frame(line)
            except SlcanError:
                return BEL
            try:
                self.bus.send(msg)
            except can.CanError:
                return BEL
            return b"Z\r" if msg.is_extended_id else b"z\r"
        if cmd == "S" and len(line) == 2 and line[1] in BITRATE_CODES:
            if self.is_open:
                return BEL
            self.bitrate = BITRATE_CODES[line[1]]
            return OK
        if cmd == "s" and len(line) == 5 and _is_hex(line[1:]):
            return BEL if self.is_open else OK
        if line in ("O", "L"):
            if self.is_open:
                return BEL
            self.is_open, self.listen_only = True, line == "L"
            self._drain()  # frames from before the channel opened are not delivered
            return OK
        if line == "C":
            self.is_open = self.listen_only = False
            return OK
        if line == "V":
            return f"V{HW_VERSION}{SW_VERSION}\r".encode()
        if line == "v":
            return f"v{SW_VERSION}\r".encode()
        if line == "N":
            return f"N{self.serial_number:>4}\r".encode()
        if line == "F":
            self._pump()
            flags, self.flags = self.flags, 0
            return f"F{flags:02X}\r".encode()
        if line in ("Z0", "Z1") or (cmd in "MmWX" and _is_hex(line[1:]) or cmd == "X"):
            return OK
        return BEL

    def _drain(self) -> None:
        while self.bus.recv(timeout=0) is not None:
            pass

    def _pump(self) -> None:
        """Move frames from the CAN side to the serial output (only while the channel is open)."""
        while True:
            msg = self.bus.recv(timeout=0)
            if msg is None:
                return
            if msg.is_error_frame:
                self.flags |= FLAG_BUS_ERROR
                continue
            if not self.is_open or msg.is_fd:
                continue
            text = encode_frame(msg).encode() + OK
            if len(self._out) + len(text) > MAX_OUTPUT:
                self.flags |= FLAG_DATA_OVERRUN
                continue
            self._out += text


def _is_hex(s: str) -> bool:
    return bool(s) and all(c in "0123456789abcdefABCDEF" for c in s)
