"""Base of simulated instruments with a line-oriented ASCII protocol (SCPI, the TPG gauge, ...).

Implements the :class:`bench.sim.registry.SerialDevice` side once: an output buffer that is
available at once (replies have no modelled latency), line assembly on CR/LF with a bounded line
buffer, and an optional set of realtime bytes handled the moment they arrive.

A second interface of the same instrument (the LAN socket of a 34972A beside its serial port)
goes through :meth:`LineDeviceSim.exchange`, which returns that interface's replies without
touching what the serial side has not read yet.
"""

from __future__ import annotations

import threading

from bench.sim.registry import ReplyBuffer


class LineDeviceSim(ReplyBuffer):
    """Subclasses implement :meth:`on_line` and, for realtime bytes, :meth:`on_realtime`."""

    realtime_bytes: frozenset[int] = frozenset()
    max_line = 256
    """Longest line kept (characters); longer lines go to :meth:`on_overflow`."""

    def __init__(self, clock, baudrate: int):
        self.clock = clock
        self.baudrate = baudrate
        self.eol = b"\r\n"
        """Line end of replies on the current interface."""
        self._in = bytearray()
        self._overflow = False
        self._out = bytearray()
        self._lock = threading.RLock()

    def on_line(self, line: str) -> None:
        """Handle one received line (stripped, without its end)."""
        raise TypeError(f"{type(self).__name__} must implement on_line")

    def on_realtime(self, byte: int) -> None:
        """Handle one realtime byte from :attr:`realtime_bytes`."""

    def on_overflow(self, line: str) -> None:
        """A line longer than :attr:`max_line` ended; ``line`` is its first ``max_line`` characters.
        Default: handle the cut line, as a firmware with a plain fixed buffer does."""
        self.on_line(line)

    def reply(self, text: str, eol: bytes | None = None) -> None:
        """Queue ``text`` and a line end (default :attr:`eol`)."""
        self._out += text.encode("ascii") + (self.eol if eol is None else eol)

    def exchange(self, data: bytes, eol: bytes) -> bytes:
        """Handle ``data`` arriving on a second interface whose replies end with ``eol``; return
        the replies it caused. Output pending for the serial side stays where it is."""
        with self._lock:
            pending, saved_eol = bytes(self._out), self.eol
            self._out.clear()
            self.eol = eol
            try:
                self.receive(data)
                return bytes(self._out)
            finally:
                self._out[:] = pending
                self.eol = saved_eol

    # ---- SerialDevice -----------------------------------------------------------------------
    def discard_input(self) -> None:
        with self._lock:
            self._in.clear()
            self._overflow = False

    def receive(self, data: bytes) -> None:
        with self._lock:
            for b in bytes(data):
                if b in self.realtime_bytes:
                    self.on_realtime(b)
                elif b in (0x0A, 0x0D):
                    if self._in or self._overflow:
                        line = self._in.decode("ascii", "replace").strip()
                        overflow, self._overflow = self._overflow, False
                        self._in.clear()
                        (self.on_overflow if overflow else self.on_line)(line)
                elif len(self._in) < self.max_line:
                    self._in.append(b)
                else:
                    self._overflow = True
