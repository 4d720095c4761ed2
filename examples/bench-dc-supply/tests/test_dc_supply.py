"""The DC supply kind end to end: found by its entry point, validated, planned, dry-run powering the
simulated board, replayed, checked, served (PyVISA as a peer client), and its protection dropping
the board. bench's test command runs these (pyproject.toml testpaths).

Golden lines come from the DP800 Programming Guide and two drivers written for the real DP800
(README.md): the test tables are typed from them, not produced by our driver.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import pytest

from bench.kinds import registry
from tests.conftest import ROOT, run_cli

HERE = Path(__file__).resolve().parents[1]
CONFIG = HERE / "configs" / "board_on_supply.yaml"
PROCEDURE = HERE / "procedures" / "unit_power_on.yaml"


def _run(tmp_path: Path, config: Path = CONFIG, procedure: Path = PROCEDURE, *extra: str):
    r = run_cli("run", str(procedure), "--config", str(config), "--runs-dir", str(tmp_path / "runs"), *extra, timeout=300)
    files = sorted((tmp_path / "runs").glob("*.h5"))
    return r, files[-1] if files else None


def _config(tmp_path: Path, old: str, new: str) -> Path:
    text = CONFIG.read_text()
    assert old in text
    p = tmp_path / "lab.yaml"
    p.write_text(text.replace(old, new, 1))
    return p


# ---- the kind ------------------------------------------------------------------------------------
def test_the_supply_is_a_kind_of_its_own_package_found_by_its_entry_point():
    kind = registry.get("dc_supply")
    assert kind is not None and kind.package == "bench-dc-supply"
    assert kind.__class__.__module__ == "bench.kinds.record"
    r = run_cli("instruments", "kinds")
    assert r.returncode == 0 and "dc_supply (bench-dc-supply)" in r.stdout


# ---- the driver's bytes: the documented command forms --------------------------------------------
class ScriptedPort:
    """A serial port answering each query line from a table (what a DP832 answers, README.md), and
    keeping every line the driver sent."""

    baudrate = 9600
    in_waiting = 0

    def __init__(self, answers: dict[str, str]):
        self.answers = answers
        self.sent: list[str] = []
        self._rx = bytearray()

    def write(self, data: bytes) -> int:
        line = data.decode("ascii").rstrip("\n")
        self.sent.append(line)
        if line.endswith("?") or "?" in line:
            self._rx += (self.answers[line] + "\n").encode("ascii")
        return len(data)

    def read(self, n: int = 1) -> bytes:
        out, self._rx = bytes(self._rx[:max(n, len(self._rx))]), bytearray()
        return out

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass


def test_the_driver_sends_the_documented_commands():
    """Each line as the Programming Guide and the DP800 drivers of sigrok and gotmc/ivi write it."""
    from bench_dc_supply.driver import DcSupply, OutputSetting

    port = ScriptedPort({"*IDN?": "RIGOL TECHNOLOGIES,DP832,DP8C180100123,00.01.16", ":SYST:ERR?": '0,"No error"',
                         ":OUTP? CH1": "ON", ":MEAS:VOLT? CH1": "5.002", ":MEAS:CURR? CH1": "0.0151",
                         ":OUTP:CVCC? CH1": "CV", ":OUTP:OVP:QUES? CH1": "NO", ":OUTP:OCP:QUES? CH1": "NO"})
    drv = DcSupply(port, timeout_s=0.5, outputs={"1": OutputSetting(5.0, 0.1, 5.5, 0.08, settle_s=0.0)})
    assert drv.identify() == {"vendor": "RIGOL TECHNOLOGIES", "model": "DP832", "serial": "DP8C180100123", "firmware": "00.01.16"}
    port.sent.clear()
    told = drv.power_up("1")
    assert port.sent == [
        ":OUTP:OVP:VAL CH1,5.5000", ":OUTP:OVP CH1,ON", ":OUTP:OCP:VAL CH1,0.0800", ":OUTP:OCP CH1,ON", ":SYST:ERR?",  # guide 2-35, 2-56, 2-57
        ":INST:NSEL 1", ":VOLT 5.000", ":CURR 0.1000", ":SYST:ERR?",                      # sigrok rigol_dp800_cmd
        ":OUTP:OVP:CLEAR CH1", ":OUTP:OCP:CLEAR CH1", ":SYST:ERR?",                       # gotmc/ivi dp800
        ":OUTP CH1,ON", ":SYST:ERR?", ":OUTP? CH1",                                      # guide 2-35
        ":OUTP? CH1", ":MEAS:VOLT? CH1", ":MEAS:CURR? CH1", ":OUTP:CVCC? CH1", ":OUTP:OVP:QUES? CH1", ":OUTP:OCP:QUES? CH1",
    ]
    assert told == "on, 5.002 V, 0.0151 A (CV)"


def test_a_trip_reads_back_and_the_driver_says_so():
    from bench.errors import DeviceFault
    from bench_dc_supply.driver import DcSupply, OutputSetting

    port = ScriptedPort({":SYST:ERR?": '0,"No error"', ":OUTP? CH1": "OFF", ":MEAS:VOLT? CH1": "0.000", ":MEAS:CURR? CH1": "0.0000",
                         ":OUTP:CVCC? CH1": "UR", ":OUTP:OVP:QUES? CH1": "NO", ":OUTP:OCP:QUES? CH1": "YES"})
    drv = DcSupply(port, timeout_s=0.5, outputs={"1": OutputSetting(5.0, 0.1, None, 0.02, settle_s=0.0)})
    with pytest.raises(DeviceFault, match="told on reads off .*OCP tripped"):
        drv.power_up("1")


# ---- the simulator: both drivers' forms, the guide's ---------------------------------------------
def _sim():
    from bench.clock import VirtualClock
    from bench_dc_supply.sim import Dp800Sim

    clock = VirtualClock()
    return Dp800Sim(clock, serial="DP8C000000001"), clock


def _ask(dev, line: str) -> str:
    dev.receive((line + "\n").encode())
    return dev.take_output(dev.clock.now()).decode().strip()


def test_the_simulator_answers_both_drivers_forms_and_the_guide_s():
    dev, _ = _sim()
    assert _ask(dev, "*IDN?") == "RIGOL TECHNOLOGIES,DP832,DP8C000000001,00.01.14"
    for line in (":INST:NSEL 2", ":VOLT 12.5", ":CURR 0.5"):  # sigrok: select, then set the selected output
        assert _ask(dev, line) == ""
    assert _ask(dev, ":SOUR2:VOLT?") == "12.500" and _ask(dev, ":APPL? CH2") == "CH2:32V/3.2A,12.500,0.5000"
    assert _ask(dev, ":APPL CH1,5,0.1") == "" and _ask(dev, ":INST?") == "CH1"  # the guide's :APPLy selects CH1
    assert _ask(dev, ":OUTP CH1,ON") == "" and _ask(dev, ":OUTP? CH1") == "ON"    # ivi / guide 2-35
    assert _ask(dev, ":MEAS:VOLT? CH1") == "5.000" and _ask(dev, ":MEAS:CURR? CH1") == "0.0000"  # nothing connected
    assert _ask(dev, ":OUTP:CVCC? CH1") == "CV" and _ask(dev, ":OUTP:MODE?") == "CV"
    assert _ask(dev, ":SYST:ERR?") == '0,"No error"'
    assert _ask(dev, ":VOLT 40") == "" and _ask(dev, ":SYST:ERR?") == '-222,"Data out of range"'
    assert _ask(dev, ":FOO:BAR 1") == "" and _ask(dev, ":SYST:ERR?") == '-113,"Undefined header"'
    assert _ask(dev, ":OUTP:OVP:VAL CH1,4.5") == "" and _ask(dev, ":OUTP:OVP CH1,ON") == ""
    assert _ask(dev, ":OUTP? CH1") == "OFF" and _ask(dev, ":OUTP:OVP:QUES? CH1") == "YES"  # 5 V above 4.5 V: tripped
    assert _ask(dev, ":OUTP CH1,ON") == "" and _ask(dev, ":OUTP? CH1") == "OFF"  # stays off until cleared
    assert _ask(dev, ":OUTP:OVP:CLEAR CH1") == "" and _ask(dev, ":OUTP:OVP:QUES? CH1") == "NO"


# ---- the supply powers the board -----------------------------------------------------------------
def test_the_board_answers_only_while_its_supply_powers_it_within_its_range(tmp_path):
    """In the simulated world (``powered_by``): the board is off until psu output 1 is on at a voltage
    within 4.40-5.25 V (USB VBUS); it draws its modelled current; a protection trip drops it."""
    from bench.clock import VirtualClock
    from bench.config import load_config
    from bench.sim.board_power import MCU_A
    from bench.sim.factory import build_devices

    config = load_config(CONFIG)
    clock = VirtualClock()
    sims = build_devices(config, clock)
    psu, board = sims["psu"].device, sims["imu"].device
    try:
        assert not board.power.running(clock.now())
        for line in (":INST:NSEL 1", ":VOLT 5", ":CURR 0.1", ":OUTP CH1,ON"):
            _ask(psu, line)
        clock.sleep(0.2)
        assert board.power.running(clock.now())
        assert float(_ask(psu, ":MEAS:CURR? CH1")) == pytest.approx(MCU_A, abs=1e-4)  # booted, sensors off
        _ask(psu, ":VOLT 4.2")  # below its range: off
        clock.sleep(0.2)
        assert not board.power.running(clock.now()) and float(_ask(psu, ":MEAS:CURR? CH1")) == 0.0
        _ask(psu, ":VOLT 5")
        clock.sleep(0.2)
        assert board.power.running(clock.now())
        _ask(psu, ":OUTP:OCP:VAL CH1,0.01")
        _ask(psu, ":OUTP:OCP CH1,ON")  # 10.8 mA above 10 mA: it trips now
        assert _ask(psu, ":OUTP:OCP:QUES? CH1") == "YES" and _ask(psu, ":OUTP? CH1") == "OFF"
        assert not board.power.running(clock.now())
    finally:
        for s in sims.values():
            s.close()


def test_the_example_validates_plans_runs_replays_and_reports(tmp_path):
    v = run_cli("validate", str(PROCEDURE), "--config", str(CONFIG))
    assert v.returncode == 0, v.stderr
    plan = run_cli("plan", str(PROCEDURE), "--config", str(CONFIG))
    assert plan.returncode == 0 and "supply" in plan.stdout, plan.stderr
    flat = " ".join(plan.stdout.replace("│", " ").split())
    assert "voltage 5 V" in flat and "current 0.1 A" in flat, plan.stdout  # the step's units, declared by the kind
    r, run = _run(tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    from bench.record.reader import read_run_summary

    s = read_run_summary(run)
    assert s.instruments["psu"]["driver"] == "dc_supply" and s.instruments["psu"]["model"] == "DP832"
    streams = {st.key: st for st in s.streams}
    assert streams["psu/monitor"].columns == {"voltage1": "V", "current1": "A"}  # units declared once, by the kind
    assert streams["imu"].rows == 6000  # the board streamed once powered again
    checks = {e.source: json.loads(e.data) for e in s.events if e.kind == "check"}
    current = checks["power-on current"]
    assert current["outcome"] == "passed" and 0.010 <= current["value"] <= 0.025 and current["units"] == "A"
    notes = [e.message for e in s.events if e.kind == "note" and "powered at opening" in e.message]
    assert notes and notes[0].startswith("imu powered at opening: psu output 1: on, 5.000 V")
    rep = run_cli("replay", str(run), "--runs-dir", str(tmp_path / "replays"), timeout=300)
    assert rep.returncode == 0 and "MATCH" in rep.stdout, rep.stdout + rep.stderr
    html = tmp_path / "r.html"
    out = run_cli("report", str(run), "-o", str(html), timeout=300)
    assert out.returncode == 0, out.stderr
    assert "Instrument readings" in html.read_text() and "psu: unit power" in html.read_text()


def test_a_limit_of_the_lab_refuses_a_voltage_before_anything_moves(tmp_path):
    """The config limits psu's voltage to the board's range: a step asking 12 V is refused at its line."""
    proc = tmp_path / "too_high.yaml"
    proc.write_text(PROCEDURE.read_text().replace("voltage: 5 V", "voltage: 12 V"))
    v = run_cli("validate", str(proc), "--config", str(CONFIG))
    line = next(i for i, t in enumerate(proc.read_text().splitlines(), 1) if "12 V" in t)
    assert v.returncode == 2 and f"{proc}:{line}:" in v.stderr and "5.25" in v.stderr and "lab config" in v.stderr, v.stderr


def test_an_ocp_below_the_inrush_trips_at_power_up_and_the_run_stops_before_it_starts(tmp_path):
    """Inrush into the board's 10 uF (50 mA at 5 V for 1 ms) plus its MCU trips a 55 mA OCP."""
    config = _config(tmp_path, "ocp: 0.08 A", "ocp: 0.055 A")
    r, run = _run(tmp_path, config)
    assert r.returncode != 0 and "OCP tripped" in r.stdout + r.stderr and "Traceback" not in r.stderr


def test_a_trip_during_the_run_drops_the_board_and_aborts_to_the_safe_state(tmp_path):
    proc = tmp_path / "stall.yaml"
    proc.write_text(PROCEDURE.read_text().replace("steps:\n", "interlocks:\n  - {stall: imu, max_gap: 2 s}\nsteps:\n", 1))
    r, run = _run(tmp_path, CONFIG, proc, "--inject-faults", "supply_trip@30s")
    assert r.returncode == 1, r.stdout + r.stderr
    from bench.record.reader import read_run_summary

    s = read_run_summary(run)
    assert s.status == "aborted" and "no frames from imu" in s.abort_reason
    outcomes = [(e.kind, e.source, e.message) for e in s.events if e.kind in ("safe_state", "error") and "safe state" in e.message
                or e.kind == "safe_state"]
    # the unit first (unpowered: it cannot answer), then its power (bench.runner.safe_state waves), confirmed by read-back
    assert [(k, src) for k, src, _ in outcomes] == [("error", "imu"), ("safe_state", "psu")], outcomes
    assert outcomes[1][2].startswith("output 1 off (read back OFF); confirmed") and "after the abort once what it powers had ended" in outcomes[1][2]


def test_instruments_check_reads_the_supply_without_switching_it(tmp_path):
    r = run_cli("instruments", "check", "--config", str(CONFIG))
    assert r.returncode == 0, r.stdout + r.stderr
    assert "psu: ok (RIGOL TECHNOLOGIES DP832 DP8C000000001; output 1: off, 0.000 V, 0.0000 A (UR))" in r.stdout


def test_two_supplies_each_record_their_readings(tmp_path):
    config = _config(tmp_path, "  imu:\n", "  psu2:\n    driver: dc_supply\n    port: /dev/ttyUSB4\n    outputs: {2: {voltage: 3.3 V, current: 0.2 A}}\n"
                     "    sim: {backend: dc_supply, serial: DP8C000000002, scpi_port: 0}\n  imu:\n")
    proc = tmp_path / "two.yaml"
    proc.write_text(PROCEDURE.read_text().replace("instruments: [psu, imu]", "instruments: [psu, psu2, imu]")
                    .replace("  - power: {instrument: imu, on: true", "  - supply: {instrument: psu2, output: 2, on: true}\n  - power: {instrument: imu, on: true"))
    r, run = _run(tmp_path, config, proc)
    assert r.returncode == 0, r.stdout + r.stderr
    from bench.record import by_kind
    from bench.record.reader import read_run_summary

    s = read_run_summary(run)
    currents = by_kind.role_columns(s, "supply_current")
    assert {(c.instrument, c.column, c.label) for c in currents} == {("psu", "current1", "psu: current1"), ("psu2", "current2", "psu2: current2")}


# ---- a client that is not ours -------------------------------------------------------------------
@pytest.mark.skipif(sys.platform == "win32", reason="pseudo-terminals are POSIX")
def test_pyvisa_drives_the_served_supply_and_powers_the_served_board(tmp_path):
    """`bench sim serve` of the example lab: PyVISA (``@py``) on the supply's LAN socket switches
    output 1 on; our board driver on the board's pseudo-terminal is answered only then."""
    pyvisa = pytest.importorskip("pyvisa", reason="pyvisa not installed (test extra: python3 dev.py installs it)")
    pytest.importorskip("pyvisa_py", reason="pyvisa-py not installed (test extra: python3 dev.py installs it)")
    from bench.errors import InstrumentTimeout
    from drivers.acs_board import AcsBoard
    from tests.sim_serve import sim_serve

    config = _config(tmp_path, "scpi_port: 5555", "scpi_port: 0")
    with sim_serve(config) as server:
        host, port = re.match(r"([\d.]+):(\d+)", server.endpoint("psu", "tcp")).groups()
        board_pty = server.endpoint("imu", "serial")
        rm = pyvisa.ResourceManager("@py")
        try:
            psu = rm.open_resource(f"TCPIP::{host}::{port}::SOCKET", read_termination="\n", write_termination="\n", timeout=5000)
            assert psu.query("*IDN?").startswith("RIGOL TECHNOLOGIES,DP832,")
            with pytest.raises(InstrumentTimeout):
                AcsBoard.open(board_pty, baudrate=115200, timeout_s=0.3).identify()  # unpowered: silent
            psu.write(":APPL CH1,5,0.1")
            psu.write(":OUTP CH1,ON")
            assert psu.query(":OUTP? CH1") == "ON" and float(psu.query(":MEAS:VOLT? CH1")) == pytest.approx(5.0)
            import time

            time.sleep(0.3)  # the board boots (50 ms) on the wall clock of `sim serve`
            board = AcsBoard.open(board_pty, baudrate=115200, timeout_s=1.0)
            try:
                assert board.identify()["serial"] == "SIM-0001"
            finally:
                board.close()
            assert 0.009 < float(psu.query(":MEAS:CURR? CH1")) < 0.013  # its MCU, sensors off
            psu.write(":OUTP CH1,OFF")
            assert psu.query(":OUTP? CH1") == "OFF" and psu.query(':SYST:ERR?') == '0,"No error"'
            psu.close()
        finally:
            rm.close()
