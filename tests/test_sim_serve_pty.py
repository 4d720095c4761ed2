"""`bench sim serve` on a pseudo-terminal, reached by the real driver from another process."""

from __future__ import annotations

import re
import subprocess
import sys
import time

import pytest

from drivers.acs_board import AcsBoard
from tests.conftest import SIM_CONFIG
from tests.sim_serve import sim_serve

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="pseudo-terminals are POSIX")


def test_driver_in_this_process_talks_to_served_simulator():
    with sim_serve(SIM_CONFIG) as served:
        path = served.endpoint("acs_board")
        assert served.transport("acs_board") == "serial" and path.startswith("/dev/"), served.endpoints
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


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_serve_starts_all_five_and_foreign_clients_reach_them(tmp_path):
    """The done-criterion of the instruments issue: all five served, endpoints printed, the
    chamber's PV read by mbpoll, the rate table reached by python-can's own slcan interface."""
    from tests.programs import find_program

    port = _free_port()
    text = SIM_CONFIG.read_text().replace("modbus_port: 5020", f"modbus_port: {port}")
    text = text.replace("sensor_model: sensors/", f"sensor_model: {SIM_CONFIG.parent}/sensors/")
    text = text.replace("      serial: SIM-0003\n", "      serial: SIM-0003\n      scpi_port: 0\n")  # any free port, not 5025
    cfg = tmp_path / "sim.yaml"
    cfg.write_text(text)
    with sim_serve(cfg) as served:
        served.endpoint("rate_table.slcan")
        endpoints = {n: (t, a) for n, t, a in served.endpoints}
        for name in ("acs_board", "stepper_bench", "thermocouples", "tvac.gauge", "rate_table.slcan"):
            assert endpoints[name][0] == "serial" and endpoints[name][1].startswith("/dev/"), endpoints
        assert endpoints["tvac"] == ("modbus-tcp", f"127.0.0.1:{port} (unit id 1)")
        assert endpoints["rate_table"][0] == "can"

        # the rate table from another process, through python-can's slcan interface on the pty
        probe = (
            "import can, canopen, sys\n"
            "net = canopen.Network(); net.connect(interface='slcan', channel=sys.argv[1], bitrate=500000, sleep_after_open=0)\n"
            "node = canopen.RemoteNode(1, canopen.ObjectDictionary()); net.add_node(node)\n"
            "print(node.sdo.upload(0x1008, 0).decode()); net.disconnect()\n"  # device name, CiA 301
        )
        out = subprocess.run([sys.executable, "-c", probe, endpoints["rate_table.slcan"][1]], capture_output=True, text=True, timeout=30)
        assert out.returncode == 0, out.stderr
        assert "TRT-7" in out.stdout

        mbpoll = find_program("mbpoll")
        if mbpoll is None:
            pytest.skip("mbpoll not installed (python3 dev.py test installs it with apt-get where allowed): foreign Modbus client not run")
        res = subprocess.run([mbpoll, "-m", "tcp", "-p", str(port), "-a", "1", "-0", "-r", "100", "-c", "1", "-1", "127.0.0.1"],
                             capture_output=True, text=True, timeout=20)
        assert res.returncode == 0, res.stdout + res.stderr
        assert re.search(r"\[100\]:\s+200\b", res.stdout), res.stdout  # 20.0 degC in tenths of a degree
