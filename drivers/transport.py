"""Serial transport shared by every serial driver: open a port from a URL with typed errors.

A URL is anything ``serial.serial_for_url`` accepts: ``/dev/ttyUSB0``, ``COM3``,
``sim://acs_board`` (a simulator registered in this process by ``bench.sim``), ``socket://host:port``, ``loop://``.
"""

from __future__ import annotations

import serial

from bench.errors import InstrumentError


def open_serial(url: str, baudrate: int = 115200, timeout_s: float = 0.5) -> serial.SerialBase:
    """Open ``url`` as 8N1 at ``baudrate`` (bit/s) with a read timeout of ``timeout_s`` (s).

    Raises :class:`InstrumentError` naming the port when it cannot be opened.
    """
    try:
        return serial.serial_for_url(
            url,
            baudrate=baudrate,
            bytesize=serial.EIGHTBITS,
            parity=serial.PARITY_NONE,
            stopbits=serial.STOPBITS_ONE,
            timeout=timeout_s,
            write_timeout=timeout_s,
        )
    except (serial.SerialException, ValueError, OSError) as exc:
        raise InstrumentError(f"cannot open serial port {url!r}: {exc}") from None


def link_bytes_per_s(baudrate: int) -> float:
    """Payload bytes per second of an 8N1 UART link (10 bits on the wire per byte)."""
    return baudrate / 10.0
