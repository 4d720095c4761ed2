"""Serve simulated serial devices on pseudo-terminals, for drivers or terminals in other processes.

``bench sim serve --config configs/sim.yaml`` opens one pseudo-terminal per serial instrument,
prints ``NAME: /dev/pts/N`` lines, and runs the devices on the wall clock until SIGINT/SIGTERM.
The slave side is put in raw mode, so bytes pass unchanged (no echo, no line discipline).

A device's output goes on the wire whether or not anybody reads: what the pseudo-terminal cannot
take yet (a client that reads late, a starved core) waits in the endpoint's ``pending`` buffer, as a
real serial port's bytes wait in the kernel's tty flip buffers, and is written as the client reads.
Only beyond :data:`HOST_BUFFER_BYTES` are bytes lost (counted in ``dropped``), as a real port
overruns when its reader stops for good.
"""

from __future__ import annotations

import os
import select
import termios
import tty
from dataclasses import dataclass, field

from serial import SerialException

from bench.clock import WallClock
from bench.sim.registry import SerialDevice

POLL_S = 0.005  # select() timeout: how often pending device output is pushed to the terminal (s)
HOST_BUFFER_BYTES = 640 * 1024
"""Bytes of a device's output held for a client that does not read (B): Linux's limit on a tty
port's flip buffers, ``TTYB_DEFAULT_MEM_LIMIT`` = 640 KiB (drivers/tty/tty_buffer.c), where a
real serial port starts to lose received bytes."""


@dataclass
class PtyEndpoint:
    name: str
    device: SerialDevice
    master: int
    slave: int
    path: str
    pending: bytearray = field(default_factory=bytearray)
    """Device output the terminal could not take yet (at most :data:`HOST_BUFFER_BYTES`)."""
    dropped: int = 0
    """Bytes of device output lost because ``pending`` was full."""


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
            room = HOST_BUFFER_BYTES - len(ep.pending)
            ep.pending += out[:room]
            ep.dropped += max(len(out) - room, 0)
            _flush(ep)


def _flush(ep: PtyEndpoint) -> None:
    """Write as much of ``ep.pending`` as the terminal takes now (it is non-blocking)."""
    while ep.pending:
        try:
            n = os.write(ep.master, ep.pending)
        except (BlockingIOError, InterruptedError):
            return  # the client has not read yet: the rest waits, as in a port's kernel buffer
        except OSError:
            ep.dropped += len(ep.pending)  # the terminal is gone
            ep.pending.clear()
            return
        del ep.pending[:n]


def close_endpoints(endpoints: list[PtyEndpoint]) -> None:
    for ep in endpoints:
        for fd in (ep.master, ep.slave):
            try:
                os.close(fd)
            except OSError:
                pass
