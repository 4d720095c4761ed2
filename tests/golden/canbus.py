"""CAN test tools for golden-frame tests: a capturing bus and a scripted node on python-can virtual buses.

Nothing here knows a protocol: frames are ``(COB-ID, data bytes)`` pairs that the tests take from
the documents. Every wait is bounded in wall time (s).
"""

from __future__ import annotations

import itertools
import os
import threading
import time
from dataclasses import dataclass, field

import can

Frame = tuple[int, bytes]
"""(11-bit COB-ID, data bytes)."""

RECV_POLL_S = 0.02  # receive-thread poll (wall s): bounds close() time
MARKER_ID = 0x1FFFF800
"""Extended (29-bit) identifier of the marker frame :meth:`ScriptedNode.settle` sends: not a CANopen
COB-ID (those are 11-bit), and its low 11 bits (0) name neither a node nor a service, so a canopen
network on the channel ignores it."""
_ids = itertools.count()


def unique_channel(prefix: str) -> str:
    """A python-can virtual channel name no other test uses."""
    return f"{prefix}-{os.getpid()}-{next(_ids)}"


def frame(cob_id: int, hex_bytes: str) -> Frame:
    """``frame(0x601, "40 41 60 00 00 00 00 00")``; ``"(none)"`` or ``""`` is a frame without data."""
    text = "" if hex_bytes.strip() == "(none)" else hex_bytes
    return cob_id, bytes.fromhex(text)


def _message(f: Frame) -> can.Message:
    return can.Message(arbitration_id=f[0], data=f[1], is_extended_id=False)


class Capture:
    """A bus on ``channel`` that records every data frame it receives (not its own) and can send."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self._frames: list[Frame] = []
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"capture {channel}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(RECV_POLL_S)
            if msg is None or msg.is_error_frame or msg.is_remote_frame:
                continue
            with self._cond:
                self._frames.append((msg.arbitration_id, bytes(msg.data)))
                self._cond.notify_all()

    def send(self, f: Frame) -> int:
        """Send ``f``; returns the index the next received frame will have (for :meth:`wait_for`)."""
        with self._cond:
            mark = len(self._frames)
        self.bus.send(_message(f))
        return mark

    def mark(self) -> int:
        """Index the next received frame will have."""
        with self._cond:
            return len(self._frames)

    def frames(self, since: int = 0, cob_ids: set[int] | None = None) -> list[Frame]:
        """Frames received from index ``since`` on, optionally only those with the given COB-IDs."""
        with self._cond:
            return [f for f in self._frames[since:] if cob_ids is None or f[0] in cob_ids]

    def wait_for(self, cob_ids: set[int], since: int = 0, count: int = 1, timeout_s: float = 1.0) -> list[Frame]:
        """The first ``count`` frames with one of ``cob_ids`` received from index ``since`` on; fewer if
        they have not all arrived within ``timeout_s`` (wall s)."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                got = [f for f in self._frames[since:] if f[0] in cob_ids]
                left = deadline - time.monotonic()
                if len(got) >= count or left <= 0:
                    return got[:count]
                self._cond.wait(left)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.bus.shutdown()


@dataclass(frozen=True)
class Exchange:
    """The host must send ``request`` next; the node answers with ``responses`` (possibly none)."""

    request: Frame
    responses: tuple[Frame, ...] = ()


@dataclass(frozen=True)
class Emit:
    """The node sends ``frame`` unsolicited as soon as the script reaches this step."""

    frame: Frame


@dataclass
class ScriptedNode:
    """Plays a script of :class:`Exchange` / :class:`Emit` steps on ``channel``, in order.

    The first frame from the host that differs from the next expected request is recorded in
    :attr:`mismatch` and the node falls silent (so the host then times out). :attr:`received` holds
    every frame the host sent.
    """

    channel: str
    script: list = field(default_factory=list)
    received: list[Frame] = field(default_factory=list)
    mismatch: str | None = None
    pos: int = 0

    def __post_init__(self) -> None:
        self._bus = can.Bus(interface="virtual", channel=self.channel, receive_own_messages=False)
        self._cond = threading.Condition()
        self._markers: set[bytes] = set()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"scripted node {self.channel}", daemon=True)
        self._thread.start()

    def extend(self, steps: list) -> None:
        """Append steps (emits at the new position are sent at once)."""
        with self._cond:
            self.script.extend(steps)
            self._emit_pending()

    def _emit_pending(self) -> None:
        while self.pos < len(self.script) and isinstance(self.script[self.pos], Emit):
            self._bus.send(_message(self.script[self.pos].frame))
            self.pos += 1
        self._cond.notify_all()

    def _run(self) -> None:
        with self._cond:
            self._emit_pending()
        while not self._stop.is_set():
            msg = self._bus.recv(RECV_POLL_S)
            if msg is None or msg.is_error_frame or msg.is_remote_frame:
                continue
            if msg.is_extended_id and msg.arbitration_id == MARKER_ID:
                with self._cond:
                    self._markers.add(bytes(msg.data))
                    self._cond.notify_all()
                continue
            got = (msg.arbitration_id, bytes(msg.data))
            with self._cond:
                self.received.append(got)
                if self.mismatch is not None:
                    continue
                step = self.script[self.pos] if self.pos < len(self.script) else None
                if step is None or step.request != got:
                    want = "nothing more" if step is None else _fmt(step.request)
                    self.mismatch = f"step {self.pos}: host sent {_fmt(got)}, script expects {want}"
                    self._cond.notify_all()
                    continue
                for f in step.responses:
                    self._bus.send(_message(f))
                self.pos += 1
                self._emit_pending()

    def wait_done(self, timeout_s: float = 2.0) -> bool:
        """True once every step was played (False on a mismatch or after ``timeout_s`` wall s)."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self.mismatch is None and self.pos < len(self.script):
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._cond.wait(left)
            return self.mismatch is None and self.pos == len(self.script)

    def settle(self, timeout_s: float = 2.0) -> bool:
        """Wait until this node has judged every frame sent on the channel so far: send a marker frame
        from a bus of its own and wait (at most ``timeout_s`` wall s) for the node to receive it. A
        virtual bus delivers frames in the order they were sent, so a frame the host sent before this
        call is in :attr:`received` (or :attr:`mismatch`) once it returns True."""
        token = next(_ids).to_bytes(8, "big")
        bus = can.Bus(interface="virtual", channel=self.channel, receive_own_messages=False)
        try:
            bus.send(can.Message(arbitration_id=MARKER_ID, data=token, is_extended_id=True))
        finally:
            bus.shutdown()
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while token not in self._markers:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
            return True

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self._bus.shutdown()


def _fmt(f: Frame) -> str:
    return f"0x{f[0]:03X} [{f[1].hex(' ').upper() or '(none)'}]"
