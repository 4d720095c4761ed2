"""Base of simulated instruments with a line-oriented ASCII protocol (GRBL, SCPI, ...).

Implements the :class:`bench.sim.registry.SerialDevice` side once: an output buffer that is
available at once (replies have no modelled latency), line assembly on CR/LF with a bounded line
buffer, and an optional set of realtime bytes handled the moment they arrive.
"""

from __future__ import annotations

import threading


class LineDeviceSim:
    """Subclasses implement :meth:`on_line` and, for realtime bytes, :meth:`on_realtime`."""

    realtime_bytes: frozenset[int] = frozenset()
    max_line = 256

    def __init__(self, clock, baudrate: int):
        self.clock = clock
        self.baudrate = baudrate
        self._in = bytearray()
        self._out = bytearray()
        self._lock = threading.RLock()

    def on_line(self, line: str) -> None:
        """Handle one received line (stripped, without its end)."""
        raise TypeError(f"{type(self).__name__} must implement on_line")

    def on_realtime(self, byte: int) -> None:
        """Handle one realtime byte from :attr:`realtime_bytes`."""

    def reply(self, text: str, eol: bytes = b"\r\n") -> None:
        self._out += text.encode("ascii") + eol

    # ---- SerialDevice -----------------------------------------------------------------------
    def set_baudrate(self, baudrate: int) -> None:
        self.baudrate = int(baudrate)

    def discard_input(self) -> None:
        with self._lock:
            self._in.clear()

    def take_output(self, t_s: float, max_bytes: int | None = None) -> bytes:
        with self._lock:
            k = len(self._out) if max_bytes is None else min(max_bytes, len(self._out))
            data = bytes(self._out[:k])
            del self._out[:k]
            return data

    def pending_bytes(self, t_s: float) -> int:
        return len(self._out)

    def next_output_time(self) -> float | None:
        return self.clock.now() if self._out else None

    def receive(self, data: bytes) -> None:
        with self._lock:
            for b in bytes(data):
                if b in self.realtime_bytes:
                    self.on_realtime(b)
                elif b in (0x0A, 0x0D):
                    if self._in:
                        line = self._in.decode("ascii", "replace").strip()
                        self._in.clear()
                        self.on_line(line)
                elif len(self._in) < self.max_line:  # longer lines are cut, as by a firmware buffer
                    self._in.append(b)
