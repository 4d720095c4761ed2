"""Where simulated serial devices live so that ``sim://NAME`` URLs can find them.

A device registered here is reached by any code that opens ``serial.serial_for_url("sim://NAME")``
in this process: the real driver cannot tell it from hardware. The registry is per process; a
device in another process is reached through ``bench sim serve`` (a pseudo-terminal).
"""

from __future__ import annotations

import threading
from typing import Protocol

import serial


class SerialDevice(Protocol):
    """What a device simulator offers to a serial transport. Times are run times in s."""

    clock: object

    def receive(self, data: bytes) -> None: ...

    def take_output(self, t_s: float, max_bytes: int | None = None) -> bytes: ...

    def pending_bytes(self, t_s: float) -> int: ...

    def next_output_time(self) -> float | None: ...

    def set_baudrate(self, baudrate: int) -> None: ...

    def discard_input(self) -> None: ...


class ReplyBuffer:
    """The output side of a device that answers at once: replies wait in ``_out`` (guarded by
    ``_lock``) and are due at the clock's current time. Subclasses set ``clock``, ``baudrate``,
    ``_out`` (bytearray) and ``_lock`` in their constructor."""

    clock: object
    baudrate: int
    _out: bytearray
    _lock: threading.RLock

    def set_baudrate(self, baudrate: int) -> None:
        self.baudrate = int(baudrate)

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


_devices: dict[str, SerialDevice] = {}
_lock = threading.Lock()

URL_HANDLER_PACKAGE = "bench.sim.urlhandler"


def install_url_handler() -> None:
    """Make pyserial's ``serial_for_url`` understand ``sim://`` (idempotent)."""
    if URL_HANDLER_PACKAGE not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(URL_HANDLER_PACKAGE)


def register(name: str, device: SerialDevice) -> str:
    """Register ``device`` under ``name`` (replacing any previous one); returns its URL ``sim://name``."""
    install_url_handler()
    with _lock:
        _devices[name] = device
    return f"sim://{name}"


def unregister(name: str) -> None:
    with _lock:
        _devices.pop(name, None)


def lookup(name: str) -> SerialDevice:
    """The device registered under ``name``; ``KeyError`` naming the known ones if absent."""
    with _lock:
        try:
            return _devices[name]
        except KeyError:
            known = ", ".join(sorted(_devices)) or "none"
            raise KeyError(f"no simulated device {name!r} in this process (registered: {known})") from None
