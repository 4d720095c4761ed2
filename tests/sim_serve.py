"""`bench sim serve` in a subprocess, for the tests that reach simulators from outside: start it,
read the endpoints it prints (``NAME: TRANSPORT ADDRESS`` per line), stop it cleanly."""

from __future__ import annotations

import queue
import signal
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import pytest

from tests.conftest import ROOT

SERVE_WAIT_S = 30.0
"""Longest wait for `bench sim serve` to print the endpoints a test needs (s)."""
STOP_WAIT_S = 10.0
"""Longest wait for it to exit after SIGTERM (s)."""


class Served:
    """A running ``bench sim serve``; :attr:`endpoints` holds ``(name, transport, address)`` rows."""

    def __init__(self, config: Path, *extra: str):
        self.proc = subprocess.Popen([sys.executable, "-m", "bench", "sim", "serve", "--config", str(config), *extra],
                                     cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self._lines: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=self._pump, daemon=True).start()
        self.endpoints: list[tuple[str, str, str]] = []

    def _pump(self) -> None:
        for line in self.proc.stdout:
            self._lines.put(line)
        self._lines.put(None)

    def endpoint(self, name: str, transport: str | None = None, timeout_s: float = SERVE_WAIT_S) -> str:
        """Address of ``name``'s endpoint (of ``transport`` if given), waiting for it to be printed."""
        deadline = time.monotonic() + timeout_s
        while True:
            for n, t, address in self.endpoints:
                if n == name and (transport is None or t == transport):
                    return address
            try:
                line = self._lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                pytest.fail(f"bench sim serve printed no {transport or ''} endpoint for {name} within {timeout_s:g} s: {self.endpoints}")
            if line is None:
                pytest.fail(f"bench sim serve exited: {self.proc.stderr.read()}")
            n, _, rest = line.strip().partition(": ")
            t, _, address = rest.partition(" ")
            self.endpoints.append((n, t, address))

    def transport(self, name: str) -> str:
        """Transport of ``name``'s first endpoint (after :meth:`endpoint` found it)."""
        return next(t for n, t, _ in self.endpoints if n == name)

    def stop(self) -> None:
        """SIGTERM; it must exit with status 0 (killed after :data:`STOP_WAIT_S`)."""
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(timeout=STOP_WAIT_S)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait(timeout=STOP_WAIT_S)
        assert self.proc.returncode == 0, self.proc.stderr.read()


@contextmanager
def sim_serve(config: Path, *extra: str) -> Iterator[Served]:
    """Run ``bench sim serve --config CONFIG EXTRA...`` for the block; stopped (exit 0 checked) after."""
    served = Served(config, *extra)
    try:
        yield served
    finally:
        served.stop()
