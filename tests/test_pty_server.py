"""The pseudo-terminal server of ``bench sim serve``: a device's output reaches a client that reads
late, whole and in order (bench/sim/pty_server.py), as a real port's kernel buffer keeps it."""

from __future__ import annotations

import os
import select
import threading
import time

import pytest

from bench.clock import WallClock
from bench.sim import pty_server
from bench.sim.pty_server import close_endpoints, open_endpoint, serve


class _Talker:
    """A device that sends ``data`` once, at once, and ignores what it receives."""

    def __init__(self, data: bytes) -> None:
        self.clock = None
        self._out = bytearray(data)

    def receive(self, data: bytes) -> None:
        pass

    def take_output(self, t_s: float, max_bytes: int | None = None) -> bytes:
        out, self._out = bytes(self._out), bytearray()
        return out


def _served(device: _Talker, late_s: float, want: int, timeout_s: float = 20.0) -> tuple[bytes, pty_server.PtyEndpoint]:
    """What a client that starts reading ``late_s`` after the server starts gets, up to ``want``
    bytes or ``timeout_s``."""
    ep = open_endpoint("talker", device)
    stop = threading.Event()
    server = threading.Thread(target=serve, args=([ep], WallClock(), stop.is_set), daemon=True)
    server.start()
    got = bytearray()
    try:
        time.sleep(late_s)
        deadline = time.monotonic() + timeout_s
        while len(got) < want and time.monotonic() < deadline:
            if select.select([ep.slave], [], [], 0.2)[0]:
                got += os.read(ep.slave, 65536)
    finally:
        stop.set()
        server.join(timeout=5.0)
        close_endpoints([ep])
    return bytes(got), ep


def test_a_client_that_reads_late_gets_every_byte_in_order() -> None:
    data = bytes(i % 251 for i in range(200_000))  # 50x a pseudo-terminal's own buffer
    got, ep = _served(_Talker(data), late_s=0.3, want=len(data))
    assert len(got) == len(data) and got == data, (len(got), ep.dropped)
    assert ep.dropped == 0


def test_past_the_host_buffer_bytes_are_counted_lost(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(pty_server, "HOST_BUFFER_BYTES", 10_000)
    data = bytes(i % 251 for i in range(100_000))
    got, ep = _served(_Talker(data), late_s=0.3, want=len(data), timeout_s=1.0)
    assert got == data[:len(got)] and 10_000 <= len(got) < len(data)
    assert ep.dropped == len(data) - len(got)
