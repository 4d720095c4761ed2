"""A client that is not ours: PyVISA (pure-Python ``@py`` backend) talks SCPI to the simulated
34970A/34972A logger served by ``bench sim serve``, over its LAN raw socket
(``TCPIP::127.0.0.1::PORT::SOCKET``) and over its serial pseudo-terminal (``ASRL/dev/pts/N::INSTR``).
"""

from __future__ import annotations

import re
import sys

import pytest

from tests.sim_serve import sim_serve

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="pseudo-terminals are POSIX")
pyvisa = pytest.importorskip("pyvisa", reason="pyvisa not installed (test extra: python3 dev.py installs it)")
pytest.importorskip("pyvisa_py", reason="pyvisa-py not installed (test extra: python3 dev.py installs it)")

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
    with sim_serve(cfg) as server:
        yield {transport: server.endpoint("thermocouples", transport) for transport in ("tcp", "serial")}


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
