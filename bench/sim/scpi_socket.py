"""A raw SCPI socket (the "SOCKET" resource of VISA) in front of a simulated line instrument.

The 34972A answers SCPI on TCP port 5025 of its LAN interface: commands and answers are ASCII
lines ending with LF, with no framing around them (Keysight 34972A User's Guide, LAN
configuration; VISA ``TCPIP::host::5025::SOCKET``). :class:`ScpiSocketServer` serves a
:class:`~bench.sim.line_device.LineDeviceSim` that way on 127.0.0.1, beside its serial port: both
reach the same instrument state (configuration, error queue), each gets its own answers
(:meth:`~bench.sim.line_device.LineDeviceSim.exchange`).

One thread accepts connections, one thread per connection reads; every wait is bounded by
:data:`POLL_S` so :meth:`ScpiSocketServer.stop` returns within about that time.
"""

from __future__ import annotations

import socket
import threading

from bench.sim.line_device import LineDeviceSim

LAN_PORT = 5025  # SCPI raw socket port of Keysight LAN instruments (34972A)
POLL_S = 0.2  # accept/recv timeout: how often the threads look at the stop flag (s)


class ScpiSocketServer:
    """Serve ``device`` on a TCP socket; answers end with ``eol`` (LF, as the 34972A's LAN port)."""

    def __init__(self, device: LineDeviceSim, eol: bytes = b"\n"):
        self.device = device
        self.eol = eol
        self.port = 0
        self._sock: socket.socket | None = None
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    def start(self, host: str = "127.0.0.1", port: int = 0) -> int:
        """Listen on ``host``:``port`` (0: any free port) and return the port. OSError if taken."""
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host, port))
            sock.listen(4)
        except OSError:
            sock.close()
            raise
        sock.settimeout(POLL_S)
        self._sock = sock
        self.port = sock.getsockname()[1]
        self._spawn(self._accept_loop)
        return self.port

    def stop(self) -> None:
        """Close the listener and every connection; waits at most about 2·POLL_S per thread."""
        self._stop.set()
        if self._sock is not None:
            self._sock.close()
        for t in self._threads:
            t.join(timeout=5 * POLL_S)

    def __enter__(self) -> "ScpiSocketServer":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def _spawn(self, target, *args) -> None:
        t = threading.Thread(target=target, args=args, daemon=True, name=f"scpi-socket-{self.port}")
        self._threads.append(t)
        t.start()

    def _accept_loop(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except socket.timeout:
                continue
            except OSError:
                return  # listener closed
            conn.settimeout(POLL_S)
            self._spawn(self._serve, conn)

    def _serve(self, conn: socket.socket) -> None:
        with conn:
            while not self._stop.is_set():
                try:
                    data = conn.recv(4096)
                except socket.timeout:
                    continue
                except OSError:
                    return
                if not data:
                    return  # client closed
                answer = self.device.exchange(data, self.eol)
                if answer:
                    try:
                        conn.sendall(answer)
                    except OSError:
                        return
