"""A client that is not ours: PyVISA (pure-Python ``@py`` backend) talks SCPI to the simulated
34970A/34972A logger served by ``bench sim serve``, over its LAN raw socket
(``TCPIP::127.0.0.1::PORT::SOCKET``) and over its serial pseudo-terminal (``ASRL/dev/pts/N::INSTR``).
"""

from __future__ import annotations

import queue
import re
import signal
import subprocess
import sys
import threading
import time

import pytest

from tests.conftest import ROOT

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="pseudo-terminals are POSIX")
pyvisa = pytest.importorskip("pyvisa", reason="pyvisa not installed (test extra: python3 dev.py installs it)")
pytest.importorskip("pyvisa_py", reason="pyvisa-py not installed (test extra: python3 dev.py installs it)")

STARTUP_S = 30.0  # longest wait for `bench sim serve` to print its endpoints (s)
VISA_TIMEOUT_MS = 5000  # PyVISA I/O timeout (ms)
ROOM_C = 20.0  # the world's ambient temperature: chamber and mount at rest (degC)
TOLERANCE_C = 2.0  # 34970A type-K accuracy 1.0 degC + reference junction 0.8 degC, rounded up
CHANNELS = "(@101:108)"
CONFIG = """\
schema: bench-config/1
name: pyvisa-peer
mode: sim
instruments:
  thermocouples:
    driver: thermocouple_reader
    port: /dev/null
    baudrate: 57600
    timeout: 1 s
    sim:
      backend: thermocouple_reader
      serial: SIM-0003
      scpi_port: 0             # any free port: parallel runs never collide
"""


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """`bench sim serve` of the logger alone; yields {transport: address} of its endpoints."""
    cfg = tmp_path_factory.mktemp("pyvisa") / "logger.yaml"
    cfg.write_text(CONFIG)
    server = subprocess.Popen([sys.executable, "-m", "bench", "sim", "serve", "--config", str(cfg)],
                              cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in server.stdout], daemon=True).start()
    endpoints: dict[str, str] = {}
    deadline = time.monotonic() + STARTUP_S
    try:
        while not {"tcp", "serial"} <= set(endpoints):
            try:
                text = lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                pytest.fail(f"bench sim serve printed no endpoints within {STARTUP_S} s: {endpoints}")
            name, _, rest = text.strip().partition(": ")
            transport, _, address = rest.partition(" ")
            if name == "thermocouples":
                endpoints[transport] = address
        yield endpoints
    finally:
        server.send_signal(signal.SIGTERM)
        try:
            server.wait(timeout=10)
        finally:
            if server.poll() is None:
                server.kill()
                server.wait(timeout=10)
    assert server.returncode == 0, server.stderr.read()


@pytest.fixture(scope="module")
def rm():
    manager = pyvisa.ResourceManager("@py")
    yield manager
    manager.close()


def resource_name(transport: str, address: str) -> tuple[str, dict]:
    """VISA resource name and open options for an endpoint line of `bench sim serve`."""
    if transport == "tcp":
        host, port = re.match(r"([\d.]+):(\d+)", address).groups()
        return f"TCPIP::{host}::{port}::SOCKET", {"read_termination": "\n"}  # LAN answers end with LF
    return f"ASRL{address}::INSTR", {"baud_rate": 57600, "read_termination": "\r\n"}  # RS-232: CR LF


@pytest.mark.parametrize("transport", ["tcp", "serial"])
def test_pyvisa_speaks_scpi_to_the_simulated_logger(served, rm, transport):
    name, options = resource_name(transport, served[transport])
    inst = rm.open_resource(name, write_termination="\n", timeout=VISA_TIMEOUT_MS, **options)
    try:
        vendor, model, serial_no, firmware = inst.query("*IDN?").split(",")
        assert model == "34970A" and serial_no == "SIM-0003"
        inst.write("*CLS")
        inst.write(f"CONF:TEMP TC,K,{CHANNELS}")
        inst.write(f"SENS:TEMP:TRAN:TC:CHEC ON,{CHANNELS}")
        inst.write(f"ROUT:SCAN {CHANNELS}")
        assert inst.query("SYST:ERR?") == '+0,"No error"'
        readings = [float(v) for v in inst.query("READ?").split(",")]
        assert len(readings) == 8
        assert all(abs(v - ROOM_C) < TOLERANCE_C for v in readings), readings  # degC, mount at room temperature
        inst.write("MEAS:WARP?")
        assert inst.query("SYST:ERR?") == '-113,"Undefined header"'
        assert inst.query("SYST:ERR?") == '+0,"No error"'
    finally:
        inst.close()
