"""`bench sim serve` on a pseudo-terminal, reached by the real driver from another process."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

from drivers.acs_board import AcsBoard
from tests.conftest import ROOT, SIM_CONFIG

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="pseudo-terminals are POSIX")


def test_driver_in_this_process_talks_to_served_simulator():
    server = subprocess.Popen(
        [sys.executable, "-m", "bench", "sim", "serve", "--config", str(SIM_CONFIG)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        endpoints = {}
        while "acs_board" not in endpoints:
            line = server.stdout.readline()
            assert line, server.stderr.read()
            name, _, rest = line.strip().partition(": ")
            transport, _, address = rest.partition(" ")
            endpoints[name] = (transport, address)
        transport, path = endpoints["acs_board"]
        assert transport == "serial" and path.startswith("/dev/"), endpoints
        board = AcsBoard.open(path, timeout_s=1.0)
        assert board.identify()["model"].startswith("ACS-IMU")
        board.sensor_power(True)
        board.set_odr(200)
        board.start_stream()
        t0 = time.monotonic()
        frames = 0
        while time.monotonic() - t0 < 1.0:
            time.sleep(0.05)
            frames += board.poll().counter.size
        board.stop_stream()
        frames += board.poll().counter.size
        board.close()
        assert 120 <= frames <= 260  # 200 Hz for about a second, over a real tty
        assert board.decoder.crc_errors == 0 and board.decoder.dropped_frames == 0
    finally:
        server.send_signal(signal.SIGTERM)
        try:
            server.wait(timeout=10)
        finally:
            if server.poll() is None:
                server.kill()
    assert server.returncode == 0, server.stderr.read()
