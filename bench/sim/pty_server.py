"""Serve simulated serial devices on pseudo-terminals, for drivers or terminals in other processes.

``bench sim serve --config configs/sim.yaml`` opens one pseudo-terminal per serial instrument,
prints ``NAME: /dev/pts/N`` lines, and runs the devices on the wall clock until SIGINT/SIGTERM.
The slave side is put in raw mode, so bytes pass unchanged (no echo, no line discipline).
"""

from __future__ import annotations

import os
import select
import termios
import tty
from dataclasses import dataclass

from serial import SerialException

from bench.clock import WallClock
from bench.sim.registry import SerialDevice

POLL_S = 0.005  # select() timeout: how often pending device output is pushed to the terminal (s)


@dataclass
class PtyEndpoint:
    name: str
    device: SerialDevice
    master: int
    slave: int
    path: str


def open_endpoint(name: str, device: SerialDevice) -> PtyEndpoint:
    """Create a raw pseudo-terminal pair for ``device``; the client opens ``path``."""
    master, slave = os.openpty()
    tty.setraw(slave, termios.TCSANOW)
    os.set_blocking(master, False)
    return PtyEndpoint(name, device, master, slave, os.ttyname(slave))


def serve(endpoints: list[PtyEndpoint], clock: WallClock, should_stop) -> None:
    """Shuttle bytes between terminals and devices until ``should_stop()`` is true."""
    by_fd = {ep.master: ep for ep in endpoints}
    while not should_stop():
        readable, _, _ = select.select(list(by_fd), [], [], POLL_S)
        for fd in readable:
            try:
                data = os.read(fd, 4096)
            except (BlockingIOError, InterruptedError):
                continue
            except OSError:
                data = b""
            if data:
                try:
                    by_fd[fd].device.receive(data)
                except SerialException:
                    pass  # simulated cable fault: the bytes are lost
        now = clock.now()
        for ep in endpoints:
            try:
                out = ep.device.take_output(now)
            except SerialException:
                continue
            while out:
                try:
                    n = os.write(ep.master, out)
                except BlockingIOError:
                    # nobody reads the terminal: drop like a UART with no listener
                    break
                out = out[n:]


def close_endpoints(endpoints: list[PtyEndpoint]) -> None:
    for ep in endpoints:
        for fd in (ep.master, ep.slave):
            try:
                os.close(fd)
            except OSError:
                pass
