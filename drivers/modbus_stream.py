"""Modbus over a byte stream that pyserial opens: pymodbus's synchronous client, its framers and
its transaction manager, with the link replaced by ``serial.serial_for_url(URL)``.

The same request and reply bytes as pymodbus's TCP and serial clients (the framer builds and
parses them; the driver's packet trace sees them), without their waits: the TCP client selects on
a socket, the serial client polls ``in_waiting`` on the wall clock (about 4 ms per request at
9600 bit/s). Here a reply is read as soon as the stream has it; a stream on a virtual clock
(``sim://NAME``, a simulator in this process) advances that clock instead of waiting.

Framing: ``socket`` (Modbus TCP: MBAP header, transaction ids) or ``rtu`` (address, PDU, CRC).
Errors as pymodbus's clients: no reply within ``timeout`` -> the transaction manager's timeout
(``ModbusIOException``); a stream that fails or is closed by the far end -> ``ConnectionException``.
"""

from __future__ import annotations

import serial
from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ConnectionException
from pymodbus.framer import FramerType


class ModbusStreamClient(ModbusTcpClient):
    """pymodbus synchronous client on the pyserial stream ``url`` (8N1 at ``baudrate`` bit/s where
    the stream is a serial port), with ``framer`` framing and a reply timeout of ``timeout`` (s)."""

    def __init__(self, url: str, *, framer: FramerType = FramerType.SOCKET, baudrate: int = 9600,
                 timeout: float = 1.0, retries: int = 0) -> None:
        super().__init__(url, port=0, framer=framer, timeout=timeout, retries=retries, reconnect_delay=0)
        self.url = url
        self.baudrate = baudrate
        self.timeout_s = timeout
        self.socket = None

    def connect(self) -> bool:
        """Open the stream; False if it cannot be opened (refused, no such device)."""
        if self.socket is not None:
            return True
        try:
            self.socket = serial.serial_for_url(self.url, baudrate=self.baudrate, bytesize=serial.EIGHTBITS,
                                                parity=serial.PARITY_NONE, stopbits=serial.STOPBITS_ONE,
                                                timeout=self.timeout_s, write_timeout=self.timeout_s)
        except (serial.SerialException, ValueError, OSError):
            self.socket = None
        return self.socket is not None

    def close(self) -> None:
        if self.socket is not None:
            try:
                self.socket.close()
            except (serial.SerialException, OSError):
                pass
        self.socket = None

    def send(self, request: bytes, addr: tuple | None = None) -> int:
        if self.socket is None:
            raise ConnectionException(str(self))
        if not request:
            return 0
        try:
            return self.socket.write(request) or 0
        except (serial.SerialException, OSError) as exc:
            self.close()
            raise ConnectionException(f"{self.url}: connection lost: {exc}") from None

    def recv(self, size: int | None) -> bytes:
        """``size`` bytes, or (``None``) whatever has arrived once at least one byte has (waiting up
        to the timeout for it); ``b""`` when nothing came in time."""
        if self.socket is None:
            raise ConnectionException(str(self))
        try:
            if size is not None:
                return self.socket.read(size)
            waiting = self.socket.in_waiting
            if waiting:
                return self.socket.read(waiting)
            first = self.socket.read(1)
            if not first:
                return b""
            waiting = self.socket.in_waiting
            return first + self.socket.read(waiting) if waiting else first
        except (serial.SerialException, OSError) as exc:
            self.close()
            raise ConnectionException(f"{self.url}: connection lost: {exc}") from None

    def is_socket_open(self) -> bool:
        return self.socket is not None

    def __repr__(self) -> str:
        return f"<{self.__class__.__name__} {self.url} timeout={self.timeout_s}>"
