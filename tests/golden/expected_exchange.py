"""A scripted serial peer for golden-exchange tests, in the style of PyMeasure's
``expected_protocol`` (``pymeasure.test.expected_protocol`` with its ``ProtocolAdapter``): the
test lists (request, response) byte pairs transcribed from a document; the port expects exactly
the request bytes, in order, and then makes exactly the response bytes readable.

Differences from PyMeasure's adapter: pairs are raw bytes *with* their terminators (the line
ends are part of what the documents specify), the port is a pyserial-like object handed to our
drivers instead of an adapter, a ``None`` response means the device stays silent (a read then
returns nothing, like a port after its timeout), and bytes the device sends unasked (a power-up
stream) can be put in front with ``pushed``.
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator, Sequence

Exchange = tuple[bytes, bytes | None]
"""(request the host must write, response the device gives or None for silence)."""


class ExpectedExchangePort:
    """Duck-typed ``serial.SerialBase`` replaying ``exchanges``; a mismatch raises AssertionError
    naming the row, the bytes written and the bytes the document expects."""

    def __init__(self, exchanges: Sequence[Exchange], *, pushed: bytes = b"", baudrate: int = 9600,
                 unread_ok: bool = False):
        for i, pair in enumerate(exchanges):
            if len(pair) != 2 or not isinstance(pair[0], bytes) or not pair[0]:
                raise ValueError(f"exchange {i} must be (request bytes, response bytes or None), got {pair!r}")
        self.exchanges = list(exchanges)
        self.baudrate = baudrate
        self.timeout = 0.0
        self.is_open = True
        self.index = 0
        self._written = bytearray()
        self._rx = bytearray(pushed)
        self._pushed = len(pushed)  # unasked bytes still at the front of the input
        self.unread_ok = unread_ok
        """Allow a request while bytes of earlier responses are unread (a transcript: the host
        read what it wanted and went on; pushed lines it never asked for may stay unread)."""

    # ---- the pyserial side the drivers use --------------------------------------------------
    def write(self, data: bytes) -> int:
        self._written += bytes(data)
        while self._written:
            if self.index >= len(self.exchanges):
                raise AssertionError(f"wrote {bytes(self._written)!r} after the last documented exchange")
            request, response = self.exchanges[self.index]
            if self._written.startswith(request):
                unread = len(self._rx) - self._pushed
                if unread > 0 and not self.unread_ok:
                    raise AssertionError(f"exchange {self.index} ({request!r}) written while {unread} bytes of the "
                                         f"previous response are unread: {bytes(self._rx[self._pushed:])!r}")
                del self._written[:len(request)]
                self._rx += response or b""
                self.index += 1
            elif request.startswith(bytes(self._written)):
                break  # a request written in pieces: wait for the rest
            else:
                raise AssertionError(f"exchange {self.index}: wrote {bytes(self._written)!r}, the document "
                                     f"expects {request!r}")
        return len(data)

    @property
    def in_waiting(self) -> int:
        return len(self._rx)

    def read(self, size: int = 1) -> bytes:
        """Up to ``size`` buffered bytes; b"" when nothing is buffered (the timeout of a real port)."""
        out = bytes(self._rx[:size])
        del self._rx[:size]
        self._pushed = max(0, self._pushed - len(out))
        return out

    def reset_input_buffer(self) -> None:
        self._rx.clear()
        self._pushed = 0

    def close(self) -> None:
        self.is_open = False

    # ---- checks -------------------------------------------------------------------------------
    def played(self) -> bool:
        """Every request was written, none half-written (responses may be unread)."""
        return self.index == len(self.exchanges) and not self._written

    def assert_done(self) -> None:
        """Every exchange happened, nothing half-written, every response read."""
        assert self.index == len(self.exchanges), (
            f"only {self.index} of {len(self.exchanges)} exchanges happened; next: {self.exchanges[self.index]!r}")
        assert not self._written, f"half-written request left: {bytes(self._written)!r}"
        assert not self._rx, f"response bytes never read: {bytes(self._rx)!r}"


@contextmanager
def expected_exchange(exchanges: Sequence[Exchange], *, pushed: bytes = b"",
                      baudrate: int = 9600) -> Iterator[ExpectedExchangePort]:
    """Yield an :class:`ExpectedExchangePort`; on leaving the block without an exception, assert
    that the whole script was played (``assert_done``)."""
    port = ExpectedExchangePort(exchanges, pushed=pushed, baudrate=baudrate)
    yield port
    port.assert_done()
