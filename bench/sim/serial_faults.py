"""Fault injection on a simulated serial link, for every serial simulator at once.

:class:`FaultySerialLink` wraps any :class:`bench.sim.registry.SerialDevice` and sits where the
cable would be: between the device simulator and the port (the ``sim://`` URL handler or a
pseudo-terminal). Faults act on the bytes, so every driver meets them exactly as on hardware:

========== =========================================================================================
fault      effect (parameters)
========== =========================================================================================
disconnect the cable is pulled: reads and writes fail with ``SerialException`` as on a vanished
           USB adapter; the device keeps running and its output in the meantime is lost
stall      the device hangs: it still receives, but sends nothing (its output is discarded)
garbage    ``count`` random bytes (default 64) are inserted before the device's next output
corrupt    each output byte is bit-flipped with probability ``p`` (default 1e-3): CRC errors
drop       each output byte is lost with probability ``p`` (default 1e-3)
========== =========================================================================================

Each fault lasts until :meth:`clear` (or, with ``duration_s``, until that much run time passed).
A seeded generator makes injected faults reproducible.
"""

from __future__ import annotations

import threading

import numpy as np
from serial import SerialException

FAULTS = ("disconnect", "stall", "garbage", "corrupt", "drop")


class FaultySerialLink:
    """A serial device seen through a link that can fail. Thread-safe."""

    def __init__(self, device, seed: int = 0):
        self.device = device
        self.clock = device.clock
        self._rng = np.random.default_rng(seed)
        self._faults: dict[str, tuple[dict, float | None]] = {}
        self._lock = threading.Lock()
        self.injected: dict[str, int] = {}
        self._extra = bytearray()  # faulted bytes beyond what the last read asked for

    # ---- fault control ------------------------------------------------------------------------
    def inject(self, fault: str, duration_s: float | None = None, **params) -> None:
        """Start ``fault`` (one of :data:`FAULTS`) now, for ``duration_s`` of run time or until cleared."""
        if fault not in FAULTS:
            raise ValueError(f"unknown serial fault {fault!r} (available: {', '.join(FAULTS)})")
        until = None if duration_s is None else self.clock.now() + float(duration_s)
        with self._lock:
            self._faults[fault] = (params, until)
            self.injected[fault] = self.injected.get(fault, 0) + 1

    def clear(self, fault: str | None = None) -> None:
        """End ``fault`` (all faults if None)."""
        with self._lock:
            if fault is None:
                self._faults.clear()
            else:
                self._faults.pop(fault, None)

    def active(self, fault: str) -> dict | None:
        """Parameters of ``fault`` if it is active now, else None (expired faults are removed)."""
        with self._lock:
            entry = self._faults.get(fault)
            if entry is None:
                return None
            params, until = entry
            if until is not None and self.clock.now() >= until:
                del self._faults[fault]
                return None
            return params

    @property
    def disconnected(self) -> bool:
        return self.active("disconnect") is not None

    def _check_connected(self) -> None:
        if self._faults and self.disconnected:
            self.device.take_output(self.clock.now())  # sent into the void while unplugged
            raise SerialException("device disconnected (simulated cable fault)")

    # ---- SerialDevice -------------------------------------------------------------------------
    def receive(self, data: bytes) -> None:
        self._check_connected()
        self.device.receive(data)

    def take_output(self, t_s: float, max_bytes: int | None = None) -> bytes:
        if not self._faults and not self._extra:
            return self.device.take_output(t_s, max_bytes)  # healthy link: no overhead
        self._check_connected()
        data = self.device.take_output(t_s, max_bytes)
        if self.active("stall") is not None:
            return b""
        data = self._faulted(data)
        with self._lock:
            self._extra += data
            k = len(self._extra) if max_bytes is None else min(max_bytes, len(self._extra))
            out = bytes(self._extra[:k])
            del self._extra[:k]
        return out

    def _faulted(self, data: bytes) -> bytes:
        if (g := self.active("garbage")) is not None and data:
            with self._lock:
                self._faults.pop("garbage", None)  # one burst per injection
            data = self._rng.integers(0, 256, int(g.get("count", 64)), dtype=np.uint8).tobytes() + data
        if (c := self.active("corrupt")) is not None and data:
            buf = np.frombuffer(data, dtype=np.uint8).copy()
            hit = self._rng.random(buf.size) < float(c.get("p", 1e-3))
            buf[hit] ^= (1 << self._rng.integers(0, 8, int(hit.sum()))).astype(np.uint8)
            data = buf.tobytes()
        if (d := self.active("drop")) is not None and data:
            buf = np.frombuffer(data, dtype=np.uint8)
            data = buf[self._rng.random(buf.size) >= float(d.get("p", 1e-3))].tobytes()
        return data

    def pending_bytes(self, t_s: float) -> int:
        if not self._faults and not self._extra:
            return self.device.pending_bytes(t_s)
        self._check_connected()
        if self.active("stall") is not None:
            self.device.take_output(t_s)  # a hung device's output never arrives
            return 0
        return len(self._extra) + self.device.pending_bytes(t_s)

    def next_output_time(self) -> float | None:
        if not self._faults and not self._extra:
            return self.device.next_output_time()
        if self.active("stall") is not None or self.disconnected:
            return None
        if self._extra:
            return self.clock.now()
        return self.device.next_output_time()

    def on_open(self) -> None:
        """The port was opened: the device may reset (an Arduino's DTR)."""
        on_open = getattr(self.device, "on_open", None)
        if on_open is not None:
            on_open()

    def set_baudrate(self, baudrate: int) -> None:
        self.device.set_baudrate(baudrate)

    def discard_input(self) -> None:
        self.device.discard_input()
