"""The chamber controller on Modbus RTU, end to end: the Watlow F4 driver against the simulated
controller on a serial line (``sim://`` in virtual time, a pseudo-terminal under ``bench sim
serve``), a dry-run of a chamber procedure over RTU and its replay, mbpoll on the pty, and the same
decoded values over TCP and RTU for the same simulator state."""

from __future__ import annotations

import itertools
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench.clock import VirtualClock
from bench.config import load_config
from bench.errors import DeviceFault, InputError, InstrumentTimeout, ProtocolError
from bench.record import read_run_summary
from bench.replay import replay
from bench.sim import registry
from bench.sim.chamber import Chamber, ChamberParams
from bench.sim.tpg261 import Tpg261Sim
from bench.sim.watlow_f4_rtu import WatlowF4RtuSim
from bench.sim.watlow_f4_server import WatlowF4Server
from drivers.tvac import TvacChamber
from drivers.watlow_f4 import REGISTERS, WatlowF4
from tests.programs import find_program
from tests.sim_serve import sim_serve
from tests.conftest import ROOT, SIM_CONFIG, run_cli

TIMEOUT_S = 0.3
CHAMBER_SHORT = ROOT / "tests" / "sessions" / "chamber_short.yaml"
ANSWERS = ROOT / "procedures" / "answers" / "ci.yaml"
_names = itertools.count()

# the PV read of docs/golden/watlow-f4.md row G1, request and response (RTU)
GOLDEN_READ_PV = bytes.fromhex("01 03 00 64 00 01 C5 D5")
GOLDEN_READ_UNITS = bytes.fromhex("01 03 03 85 00 01 95 A7")  # row G5, the first request of open()


def rtu_config(tmp_path: Path, **replace: str) -> Path:
    """configs/sim.yaml with the chamber controller on Modbus RTU (``sim.transport: rtu``)."""
    text = SIM_CONFIG.read_text(encoding="utf-8")
    assert text.count("      backend: tvac\n") == 1
    text = text.replace("      backend: tvac\n", "      backend: tvac\n      transport: rtu\n")
    text = text.replace("sensor_model: sensors/", f"sensor_model: {SIM_CONFIG.parent}/sensors/")
    for old, new in replace.items():
        text = text.replace(old, new)
    path = tmp_path / "sim_rtu.yaml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.fixture
def clock():
    return VirtualClock()


@pytest.fixture
def chamber():
    return Chamber(ChamberParams())


@pytest.fixture
def rtu_sim(clock, chamber):
    sim = WatlowF4RtuSim(clock, chamber)
    name = f"f4-rtu-{next(_names)}"
    sim.url = f"modbus-rtu://{registry.register(name, sim)}"
    yield sim
    registry.unregister(name)


@pytest.fixture
def f4(rtu_sim):
    seen: list[tuple[str, str, bytes]] = []
    driver = WatlowF4.open(rtu_sim.url, timeout_s=TIMEOUT_S, on_traffic=lambda d, n, raw: seen.append((d, n, raw)))
    driver.seen = seen
    yield driver
    driver.close()


# ---- the driver's RTU path against the simulator (virtual time) ----------------------------------
def test_driver_over_rtu_reads_writes_and_checks_configuration(f4, clock, chamber):
    assert f4.seen[0] == ("command", "read 901", GOLDEN_READ_UNITS)  # open() checks units first
    f4.set_set_point_c(45.0)
    f4.set_ramp_rate_c_per_min(1.5)
    assert chamber.set_point_c == 45.0 and chamber.ramp_rate_c_per_min == 1.5
    clock.sleep(900)
    assert f4.read_air_temp_c() == pytest.approx(chamber.air_temp_c(clock.now()), abs=0.05)
    assert f4.read_air_temp_c() > 22.0
    assert f4.read_set_point_limits_c() == chamber.set_point_limits_c
    f4.set_event(1, True)
    assert chamber.pump_on and f4.read_event(1)
    assert [raw for d, n, raw in f4.seen if n == "read 100"][0] == GOLDEN_READ_PV


def test_rtu_exceptions_are_protocol_errors_and_leave_the_link_usable(f4, chamber):
    with pytest.raises(ProtocolError, match=r"exception 3 \(illegal data value\) writing 2000 to register 300"):
        f4.set_set_point_c(200.0)
    with pytest.raises(ProtocolError, match=r"exception 2 \(illegal data address\) reading register 101"):
        f4.read_raw(101)
    with pytest.raises(ProtocolError, match=r"exception 2 \(illegal data address\) writing 5 to register 100"):
        f4.write_raw(100, 5)
    assert chamber.set_point_c == 20.0
    assert f4.read_set_point_c() == 20.0


@pytest.mark.parametrize("fault", ["timeout", "disconnect"])
def test_silent_rtu_line_is_a_timeout_within_the_timeout(f4, rtu_sim, fault):
    rtu_sim.inject(fault)
    t0 = time.monotonic()
    with pytest.raises(InstrumentTimeout):
        f4.read_air_temp_c()
    assert time.monotonic() - t0 < TIMEOUT_S + 0.5  # pymodbus waits on the wall clock
    with pytest.raises(InstrumentTimeout, match="not retried"):
        f4.set_set_point_c(30.0)
    rtu_sim.clear_faults()
    assert f4.read_air_temp_c() == pytest.approx(20.0)


def test_rtu_faults_busy_and_open_sensor(f4, rtu_sim):
    rtu_sim.inject("exception", code=6)
    with pytest.raises(ProtocolError, match="busy"):
        f4.read_set_point_c()
    rtu_sim.clear_faults()
    rtu_sim.inject("open_sensor", input=1)
    with pytest.raises(DeviceFault, match="open sensor"):
        f4.read_air_temp_c()
    assert f4.read_alarms()["input_1_code"] == "open sensor"


def test_rtu_simulator_ignores_a_corrupted_frame_and_answers_the_next(f4, rtu_sim):
    bad = bytearray(GOLDEN_READ_PV)
    bad[-1] ^= 0x01
    rtu_sim.receive(bytes(bad))
    assert rtu_sim.take_output(rtu_sim.clock.now()) == b"" and rtu_sim.crc_errors == 1
    rtu_sim.clock.sleep(0.01)  # line silence: a new frame starts
    assert f4.read_air_temp_c() == pytest.approx(20.0)


def test_tvac_composite_over_rtu(rtu_sim, clock, chamber):
    gauge = Tpg261Sim(clock, chamber)
    name = f"f4-rtu-gauge-{next(_names)}"
    tvac = TvacChamber.open(rtu_sim.url, timeout_s=TIMEOUT_S, gauge_url=registry.register(name, gauge))
    try:
        tvac.pump_down()
        clock.sleep(600)
        state = tvac.read()
        assert state["pump_on"] and not state["vent_open"] and state["pressure_torr"] < 1e-2
        assert "units=1" in tvac.identify()["model"]
    finally:
        tvac.close()
        registry.unregister(name)


# ---- TCP and RTU: same state, same values ---------------------------------------------------------
def test_tcp_and_rtu_give_the_same_values_and_pdus_for_the_same_state(clock, chamber):
    """One chamber behind both simulated transports: every register decodes to the same value,
    and every response PDU is the same bytes (TCP ADU minus MBAP = RTU ADU minus address and CRC)."""
    rtu = WatlowF4RtuSim(clock, chamber)
    name = f"f4-rtu-both-{next(_names)}"
    url = f"modbus-rtu://{registry.register(name, rtu)}"
    traffic: dict[str, list[tuple[str, bytes]]] = {"tcp": [], "rtu": []}
    with WatlowF4Server(clock, chamber) as tcp_sim:
        drivers = {
            "tcp": WatlowF4.open(f"modbus-tcp://127.0.0.1:{tcp_sim.port}", timeout_s=TIMEOUT_S,
                                 on_traffic=lambda d, n, raw: traffic["tcp"].append((d, raw))),
            "rtu": WatlowF4.open(url, timeout_s=TIMEOUT_S, on_traffic=lambda d, n, raw: traffic["rtu"].append((d, raw))),
        }
        try:
            drivers["tcp"].set_set_point_c(-25.0)
            drivers["rtu"].set_event(2, True)  # vent valve
            clock.sleep(3600)  # cooling at ambient pressure: negative temperatures, cooling output
            values = {}
            for kind, d in drivers.items():
                values[kind] = {
                    "registers": {r.name: d.read(r.name) for r in REGISTERS},
                    "air": d.read_air_temp_c(), "mount": d.read_mount_temp_c(), "output": d.read_output_pct(),
                    "alarms": d.read_alarms(), "events": (d.read_event(1), d.read_event(2)), "run_state": d.read_run_state(),
                }
        finally:
            for d in drivers.values():
                d.close()
            registry.unregister(name)
    assert values["tcp"] == values["rtu"]
    assert values["rtu"]["air"] < 0 and values["rtu"]["output"] < 0 and values["rtu"]["registers"]["set_point_1"] == -25.0
    pdus = {k: [(d, raw[7:] if k == "tcp" else raw[1:-2]) for d, raw in t] for k, t in traffic.items()}
    assert len(pdus["tcp"]) == len(pdus["rtu"]) > 2 * len(REGISTERS)
    tail = slice(-2 * (len(REGISTERS) + 10), None)  # the reads above, after the different writes
    assert pdus["tcp"][tail] == pdus["rtu"][tail]


# ---- config --------------------------------------------------------------------------------------
def test_config_selects_rtu_and_refuses_other_transports(tmp_path):
    inst = load_config(rtu_config(tmp_path)).instruments["tvac"]
    assert inst.sim.transport == "rtu" and inst.baudrate == 9600
    assert load_config(SIM_CONFIG).instruments["tvac"].sim.transport == "tcp"
    bad = rtu_config(tmp_path, **{"transport: rtu": "transport: can"})
    with pytest.raises(InputError, match=r"expected transport tcp or rtu, got 'can'"):
        load_config(bad)


# ---- a dry-run over RTU and its replay --------------------------------------------------------------
def test_dry_run_of_a_chamber_procedure_over_rtu_replays_with_match(tmp_path):
    cfg = rtu_config(tmp_path)
    res = run_cli("run", str(CHAMBER_SHORT), "--config", str(cfg), "--runs-dir", str(tmp_path / "runs"),
                  "--answers", str(ANSWERS), timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    (run_file,) = (tmp_path / "runs").glob("*.h5")
    summary = read_run_summary(run_file)
    assert summary.status == "completed"
    cmds = [e for e in summary.events if e.source == "tvac" and e.kind == "command" and re.match(r"(read|write) \d+", e.message)]
    assert cmds[0].data == GOLDEN_READ_UNITS  # RTU frames (address, PDU, CRC) are what was recorded
    assert any(e.message == "read 100" and e.data == GOLDEN_READ_PV for e in cmds)
    # 24.0 degC = raw 240 = 0x00F0 to register 300 (0x012C); CRC computed once as in docs/golden/watlow-f4.md
    assert any(e.message == "write 300" and e.data == bytes.fromhex("01 06 01 2C 00 F0 49 BB") for e in cmds)

    result = replay(run_file, runs_dir=tmp_path / "replays")
    assert result.ok, result.report()
    assert "MATCH" in result.report()
    assert result.commands == sum(1 for e in summary.events if e.kind == "command")

    edited = tmp_path / "chamber_short_edited.yaml"
    edited.write_text(CHAMBER_SHORT.read_text().replace("set_point: 24 degC", "set_point: 25 degC"))
    changed = replay(run_file, edited, runs_dir=tmp_path / "replays")
    assert not changed.ok
    first = changed.divergences[0].render()
    assert "instrument tvac controller: command" in first
    assert "01 06 01 2c 00 f0" in first and "01 06 01 2c 00 fa" in first  # 24.0 vs 25.0 degC on the wire


# ---- bench sim serve: the RTU controller on a pseudo-terminal -------------------------------------
@pytest.fixture
def served_rtu(tmp_path):
    if sys.platform == "win32":
        pytest.skip("pseudo-terminals are POSIX")
    with sim_serve(rtu_config(tmp_path), "--instrument", "tvac") as served:
        path = served.endpoint("tvac")
        assert served.transport("tvac") == "serial", served.endpoints
        served.endpoint("tvac.gauge")
        yield path


def test_driver_in_this_process_talks_rtu_to_the_served_controller(served_rtu):
    driver = WatlowF4.open(f"modbus-rtu://{served_rtu}", timeout_s=1.0)
    try:
        assert driver.read_air_temp_c() == pytest.approx(20.0, abs=0.1)  # the world's 20 degC ambient
        driver.set_set_point_c(31.5)
        assert driver.read_set_point_c() == 31.5
    finally:
        driver.close()


def test_served_controller_answers_a_golden_frame_on_the_tty(served_rtu):
    """docs/golden/watlow-f4.md row G5 (units), raw bytes through the pseudo-terminal."""
    import serial

    with serial.Serial(served_rtu, 9600, timeout=1.0) as tty:
        tty.write(GOLDEN_READ_UNITS)
        assert tty.read(7) == bytes.fromhex("01 03 02 00 01 79 84")


def test_mbpoll_reads_the_served_controller_in_rtu_mode(served_rtu):
    mbpoll = find_program("mbpoll")
    if mbpoll is None:
        pytest.skip("mbpoll not installed (python3 dev.py test installs it with apt-get where allowed): foreign RTU client not run")
    common = [mbpoll, "-m", "rtu", "-a", "1", "-b", "9600", "-d", "8", "-P", "none", "-s", "1", "-c", "1", "-1", "-o", "2"]
    # mbpoll numbers registers from 1 by default: reference 101 is PDU address 100 (PV input 1)
    one_based = subprocess.run(common + ["-r", "101", served_rtu], capture_output=True, text=True, timeout=20)
    assert one_based.returncode == 0, one_based.stdout + one_based.stderr
    assert re.search(r"\[101\]:\s+200\b", one_based.stdout), one_based.stdout  # 20.0 degC in tenths
    zero_based = subprocess.run(common + ["-0", "-r", "100", served_rtu], capture_output=True, text=True, timeout=20)
    assert re.search(r"\[100\]:\s+200\b", zero_based.stdout), zero_based.stdout
    unmapped = subprocess.run(common + ["-0", "-r", "101", served_rtu], capture_output=True, text=True, timeout=20)
    assert "Illegal data address" in unmapped.stdout + unmapped.stderr  # exception 2 through a foreign client
