"""Serial transport shared by every serial driver: open a port from a URL with typed errors.

A URL is anything ``serial.serial_for_url`` accepts: ``/dev/ttyUSB0``, ``COM3``,
``sim://acs_board`` (a simulator registered in this process by ``bench.sim``), ``socket://host:port``, ``loop://``.
"""

from __future__ import annotations

import serial

from drivers.errors import DeviceFault, InstrumentError, InstrumentTimeout, ProtocolError


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


class LineChannel:
    """Line-oriented commands over a serial port: GRBL style (:meth:`transact`: information lines,
    then ``ok`` or ``error:N``) or SCPI style (:meth:`send` without answer, :meth:`query` with one).

    ``on_traffic(direction, name, raw)`` sees every command line sent and every line received.
    Waiting is bounded both by the port timeout (no bytes at all) and by a byte budget (the
    link's capacity over the timeout), so a chatty device cannot hold a command forever.
    ``meanings`` maps answer words (``"error:9"``, ``"ALARM:3"``) to the text errors quote.
    """

    def __init__(self, port: serial.SerialBase, timeout_s: float, name: str, on_traffic=None, eol: bytes = b"\n",
                 meanings: dict[str, str] | None = None):
        self.port = port
        self.timeout_s = timeout_s
        self.name = name
        self.on_traffic = on_traffic
        self.eol = eol
        self.meanings = dict(meanings or {})
        self._rx = bytearray()

    def send_realtime(self, byte: bytes) -> None:
        """A one-byte realtime command (no line end, no reply)."""
        self._write(byte, repr(byte))

    def send(self, line: str) -> None:
        """Send a command line that has no answer (SCPI commands without ``?``)."""
        self._write(line.encode("ascii") + self.eol, line)

    def query(self, line: str) -> str:
        """Send ``line`` and return the one answer line (SCPI queries)."""
        self._write(line.encode("ascii") + self.eol, line)
        return self._read_line(line, self._budget())[0]

    def identify(self) -> dict[str, str]:
        """``*IDN?`` (IEEE 488.2 common command): its four comma-separated fields as ``vendor``,
        ``model``, ``serial``, ``firmware``; :class:`ProtocolError` naming the instrument otherwise."""
        parts = [p.strip() for p in self.query("*IDN?").split(",")]
        if len(parts) != 4:
            raise ProtocolError(f"{self.name}: unexpected *IDN? answer {','.join(parts)!r}")
        return dict(zip(("vendor", "model", "serial", "firmware"), parts))

    def transact(self, line: str) -> list[str]:
        """Send ``line``; return the information lines received before ``ok``.

        Raises :class:`ProtocolError` on ``error:N``, :class:`InstrumentTimeout` without an
        answer, and :class:`DeviceFault` when the device pushed ``ALARM:N`` before its answer
        (raised once the line's own ``ok``/``error:N`` has been read, so the next command starts
        in step).
        """
        self._write(line.encode("ascii") + self.eol, line)
        info: list[str] = []
        alarms: list[str] = []
        budget = self._budget()
        while True:
            text, budget = self._read_line(line, budget)
            if text == "ok" or text.startswith("error:"):
                break
            (alarms if text.startswith("ALARM:") else info).append(text)
        if alarms:
            raise DeviceFault(f"{self.name} raised {', '.join(self._described(a) for a in alarms)} "
                              f"(answer to {line!r}: {self._described(text)})")
        if text != "ok":
            raise ProtocolError(f"{self.name} refused {line!r}: {self._described(text)}")
        return info

    def _described(self, word: str) -> str:
        meaning = self.meanings.get(word)
        return f"{word} ({meaning})" if meaning else word

    def _budget(self) -> int:
        """Bytes the link can carry within the timeout: the most we read waiting for one answer."""
        return max(256, int(link_bytes_per_s(self.port.baudrate) * self.timeout_s))

    def _read_line(self, line: str, budget: int) -> tuple[str, int]:
        """The next non-empty received line (stripped) and the budget left; timeout when none comes."""
        while True:
            while b"\n" in self._rx:
                raw, _, rest = self._rx.partition(b"\n")
                self._rx = bytearray(rest)
                text = raw.decode("ascii", "replace").strip()
                if text:
                    if self.on_traffic is not None:
                        self.on_traffic("reply", text, raw + b"\n")
                    return text, budget
            if budget < 0:
                break
            try:
                chunk = self.port.read(max(1, self.port.in_waiting))
            except serial.SerialException as exc:
                raise InstrumentError(f"{self.name}: reading the answer to {line!r} failed: {exc}") from None
            if not chunk:
                break
            budget -= len(chunk)
            self._rx += chunk
        raise InstrumentTimeout(f"{self.name}: no answer to {line!r} within {self.timeout_s:g} s")

    def _write(self, data: bytes, name: str) -> None:
        try:
            self.port.write(data)
        except serial.SerialException as exc:
            raise InstrumentError(f"{self.name}: writing {name} failed: {exc}") from None
        if self.on_traffic is not None:
            self.on_traffic("command", name, data)
