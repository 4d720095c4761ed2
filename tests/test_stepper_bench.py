"""The stepper bench driver (stock GRBL 1.1) against the simulated GRBL, and the board on the
turning stage seeing the rate. What the real firmware says is in tests/golden/test_grbl_transcripts.py;
here: the driver's own decisions (jog queue, rate changes, stops, the safe state, resync, open)."""

from __future__ import annotations

import numpy as np
import pytest
import serial

from bench.clock import VirtualClock
from bench.config import load_config
from bench.sim import registry
from bench.sim.factory import build_devices
from bench.sim.stepper_bench import StepperBenchSim, bench_eeprom
from drivers import grbl
from drivers.acs_board import AcsBoard
from drivers.errors import InstrumentTimeout, NotConfigured, ProtocolError
from drivers.stepper_bench import JOG_BLOCK_S, QUEUE_S, BenchSetup, StepperBench
from tests.conftest import ROOT

LAB = ROOT / "configs" / "sim_rotating_bench.yaml"
SETUP = BenchSetup("X", 894.33, 3.5)


@pytest.fixture
def lab():
    config = load_config(LAB)
    clock = VirtualClock()
    devices = {n: s.device for n, s in build_devices(config, clock).items()}
    urls = {name: registry.register(f"{name}_t{id(clock)}", dev) for name, dev in devices.items()}
    yield clock, devices, urls
    for name in devices:
        registry.unregister(f"{name}_t{id(clock)}")


def _bench(url: str, traffic: list | None = None, **kw) -> StepperBench:
    hook = None if traffic is None else (lambda d, name, raw: traffic.append((d, raw)))
    return StepperBench.open(url, setup=kw.pop("setup", SETUP), on_traffic=hook, **kw)


def _turn(clock, bench: StepperBench, seconds: float, poll_s: float = 1.0) -> list[dict]:
    """Let ``seconds`` pass, reading the bench's status every ``poll_s`` as the runner does."""
    out = []
    for _ in range(int(round(seconds / poll_s))):
        clock.sleep(poll_s)
        out.append(bench.status())
    return out


def _sent(traffic) -> list[bytes]:
    return [raw for d, raw in traffic if d == "command"]


def test_identify_run_status_stop(lab):
    clock, devices, urls = lab
    bench = _bench(urls["stepper_bench"])
    ident = bench.identify()
    assert ident["vendor"] == "GRBL" and ident["serial"] == "SIM-0002" and "1.1h" in ident["firmware"]
    assert bench.status() == {"state": "Idle", "angle_deg": 0.0, "position_deg": 0.0, "rate_dps": 0.0}
    assert bench.set_rate(3.0) == 3.0  # F180.000 deg/min: the feed is a float, no integer speed parameter
    bench.run()
    statuses = _turn(clock, bench, 60.0)
    assert all(s["state"] == "Jog" and s["rate_dps"] == 3.0 for s in statuses[1:])
    # 60 s at 3 deg/s less what the 0.3 s ramp at 10 deg/s² ($120) costs: v²/(2a)
    assert statuses[-1]["position_deg"] == pytest.approx(3.0 * 60 - 9.0 / 20, abs=2e-3)
    bench.stop()
    at = bench.status()
    assert at["state"] == "Idle" and at["rate_dps"] == 0.0
    clock.sleep(30.0)
    assert bench.status()["position_deg"] == at["position_deg"]


def test_a_long_dwell_turns_without_a_gap(lab):
    """10 minutes at 1 deg/s: jogs of 10 s kept 30 s ahead; the stage never slows down."""
    clock, devices, urls = lab
    traffic: list = []
    bench = _bench(urls["stepper_bench"], traffic)
    bench.set_rate(1.0)
    bench.run()
    t0 = clock.now()
    _turn(clock, bench, 600.0)
    stage = devices["stepper_bench"].stage
    t = np.arange(t0 + 1.0, clock.now(), 0.05)
    assert np.all(stage.commanded_rate_dps(t) == pytest.approx(1.0, abs=1e-12))
    jogs = [raw for raw in _sent(traffic) if raw.startswith(b"$J=")]
    assert jogs[0] == b"$J=G91G21X10.000F60.000\n" and len(set(jogs)) == 1
    assert len(jogs) == pytest.approx((600 + QUEUE_S) / JOG_BLOCK_S, abs=2)


def test_the_bench_stops_by_itself_when_nobody_asks_and_says_so(lab):
    """The queue is the dead man's switch: no status read for longer than it lasts, the bench
    stops; the next read notes it and turns again."""
    clock, devices, urls = lab
    bench = _bench(urls["stepper_bench"])
    bench.set_rate(2.0)
    bench.run()
    clock.sleep(120.0)
    assert devices["stepper_bench"].machine_state() == "Idle"
    assert devices["stepper_bench"].angle_deg() == pytest.approx(2.0 * QUEUE_S, abs=0.01)
    assert bench.status()["state"] == "Idle" and "its jog queue ran out" in bench.notes[-1]
    clock.sleep(5.0)
    assert bench.status()["state"] == "Jog"


def test_a_rate_change_is_a_cancel_then_new_jogs(lab):
    clock, devices, urls = lab
    traffic: list = []
    bench = _bench(urls["stepper_bench"], traffic)
    bench.set_rate(1.0)
    bench.run()
    _turn(clock, bench, 20.0)
    del traffic[:]
    assert bench.set_rate(-0.2) == -0.2
    sent = _sent(traffic)
    assert sent[0] == grbl.JOG_CANCEL and set(sent[1:-3]) == {b"?"} and sent[-3:] == [b"$J=G91G21X-2.000F12.000\n"] * 3
    _turn(clock, bench, 5.0)
    t = clock.now()
    assert devices["stepper_bench"].stage.commanded_rate_dps(np.array([t]))[0] == pytest.approx(-0.2)


def test_rates_beyond_the_bench_are_refused(lab):
    clock, devices, urls = lab
    bench = _bench(urls["stepper_bench"])
    for bad in (4.0, 0.0, float("nan")):
        with pytest.raises(ValueError):
            bench.set_rate(bad)
    with pytest.raises(ValueError, match="no rate set"):
        bench.run()


def test_safe_state_cancels_a_jog_and_confirms(lab):
    clock, devices, urls = lab
    bench = _bench(urls["stepper_bench"])
    bench.set_rate(3.5)
    bench.run()
    _turn(clock, bench, 5.0)
    told = bench.safe_state()
    assert told.startswith("jog cancel (0x85): Idle, feed 0 at") and "answered at once" in told
    sim = devices["stepper_bench"]
    assert sim.machine_state() == "Idle" and not sim.motion.blocks and sim.rate_dps() == 0.0


def test_safe_state_stops_a_g_code_program_with_hold_and_reset(lab):
    """A program someone else started (G1, not a jog: the cancel does nothing to it): feed hold,
    then a soft reset empties the planner; no alarm, as the hold was complete."""
    clock, devices, urls = lab
    bench = _bench(urls["stepper_bench"])
    bench.channel.transact("G91G1X100F120")
    clock.sleep(2.0)
    assert devices["stepper_bench"].machine_state() == "Run" and bench.status()["state"] == "Run"
    told = bench.safe_state()
    assert told.startswith("jog cancel (0x85), then feed hold (!), then soft reset (0x18): Idle, feed 0")
    sim = devices["stepper_bench"]
    angle = sim.angle_deg()
    bench.channel.realtime(grbl.CYCLE_START)  # nothing queued is left to resume
    clock.sleep(5.0)
    assert sim.machine_state() == "Idle" and sim.angle_deg() == angle


def test_after_a_timeout_a_late_answer_is_not_taken_for_the_next():
    """GRBL answers a jog late (its planner was full): the driver times out, then brings the
    channel back in step with $G before its next line, dropping the late ok."""
    script = [(b"$J=G91G21X1.000F60.000\n", b""), (b"$G\n", b"ok\r\n[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]\r\nok\r\n"),
              (b"$I\n", b"[VER:1.1h.20190830:STEPPER_BENCH:EC2-01]\r\n[OPT:V,15,128]\r\nok\r\n")]
    from tests.golden.grbl_replay import Exchange, transcript_port

    port = transcript_port([Exchange(h, f) for h, f in script])
    ch = grbl.GrblChannel(port, 0.01, "bench")
    with pytest.raises(InstrumentTimeout):
        ch.transact("$J=G91G21X1.000F60.000")
    assert grbl.parse_build_info(ch.transact("$I"))[1] == "STEPPER_BENCH:EC2-01"
    assert ch.discarded == ["ok"] and ch.in_step and port.played()


def test_open_waits_out_a_dtr_reset():
    """An Uno resets when its port opens and GRBL answers 2 s later: the driver's reset byte is
    lost in the boot, the welcome message comes, the driver goes on."""
    clock = VirtualClock()
    sim = StepperBenchSim(clock, None, bench_eeprom(894.33, 210.0, 10.0, build_info="STEPPER_BENCH:UNO"), dtr_reset_s=2.0)
    url = registry.register(f"dtr{id(clock)}", sim)
    try:
        bench = _bench(url)
        assert bench.identify()["serial"] == "UNO" and clock.now() == pytest.approx(2.0, abs=0.6)
    finally:
        registry.unregister(f"dtr{id(clock)}")


def test_open_reports_a_blank_eeprom_and_a_plain_grbl():
    clock = VirtualClock()
    sim = StepperBenchSim(clock, None, None, dtr_reset_s=1.5)
    url = registry.register(f"blank{id(clock)}", sim)
    try:
        with pytest.raises(NotConfigured) as err:
            _bench(url)
        assert "GRBL, not configured as this bench" in str(err.value) and "$100=894.330" in err.value.fix
        assert err.value.fix.count("$") == 2  # $I= and $100=; the defaults' $110=500 and $120=10 will do
    finally:
        registry.unregister(f"blank{id(clock)}")


def test_open_unlocks_the_alarm_of_a_reset_while_turning(lab):
    clock, devices, urls = lab
    port = serial.serial_for_url(urls["stepper_bench"], baudrate=115200, timeout=0.5)
    port.write(b"$J=G91G21X30.000F120.000\n")
    assert port.readline() == b"ok\r\n"
    clock.sleep(1.0)
    port.write(b"\x18")
    assert port.readline() == b"ALARM:3\r\n"
    port.close()
    bench = _bench(urls["stepper_bench"])
    assert bench.status()["state"] == "Idle" and "unlocked with $X" in bench.notes[0]


def test_a_bench_set_up_otherwise_is_refused_with_the_settings_to_send(lab):
    clock, devices, urls = lab
    for setup, fix in ((BenchSetup("X", 900.0, 3.5), "$100=900.000"), (BenchSetup("X", 894.33, 5.0), "$110=300.000"),
                       (BenchSetup("X", 894.33, 3.5, 20.0), "$120=20.000"), (BenchSetup("Y", 894.33, 3.5), "$101=894.330")):
        with pytest.raises(NotConfigured) as err:
            _bench(urls["stepper_bench"], setup=setup)
        assert fix in err.value.fix and "$I=" not in err.value.fix


def test_status_fields_in_any_order_and_unknown_ones():
    st = grbl.parse_status("<Hold:1|Zz:42|FS:102.5,0|WPos:1.000,2.000,-3.250|Bf:14,127|WCO:0.500,0.000,0.000|A:SF>")
    assert (st.state, st.substate, st.feed, st.wpos, st.buffer, st.wco) == ("Hold", 1, 102.5, (1.0, 2.0, -3.25), (14, 127), (0.5, 0.0, 0.0))
    assert st.mpos is None and st.moving and st.fields["Zz"] == "42"
    for bad in ("<Idle>", "<Flying|MPos:0,0,0>", "<Idle|MPos:1.2.3,0,0>", "Idle|MPos:0,0,0", "<Idle|MPos:0,0,0|nofield>"):
        with pytest.raises(ProtocolError):
            grbl.parse_status(bad)


def test_board_on_the_stage_sees_the_commanded_rate(lab):
    clock, devices, urls = lab
    bench = _bench(urls["stepper_bench"])
    board = AcsBoard.open(urls["acs_board"])
    board.sensor_power(True)
    clock.sleep(3600.0)  # past the warm-up
    rates = {}
    for rate in (0.0, 1.0, -2.0):
        if rate:
            rates[rate] = bench.set_rate(rate)
            bench.run()
            _turn(clock, bench, 2.0)  # past the 0.2-s ramp
        board.start_stream()
        _turn(clock, bench, 30.0)
        board.stop_stream()
        rates.setdefault(rate, 0.0)
        gz = board.poll().gyro_dps[:, 2]
        rates[rate] = (rates[rate], gz.mean())
        if rate:
            bench.stop()
    base = rates[0.0][1]
    for rate in (1.0, -2.0):
        actual, measured = rates[rate]
        # the board's z gyro shows the bench rate on top of the same bias (noise of the mean 4e-4)
        assert measured - base == pytest.approx(actual, abs=3e-3)


def test_magnetometer_turns_with_the_stage(lab):
    clock, devices, urls = lab
    bench = _bench(urls["stepper_bench"])
    board = AcsBoard.open(urls["acs_board"])
    board.sensor_power(True)
    actual = bench.set_rate(3.0)
    bench.run()
    _turn(clock, bench, 2.0)
    board.start_stream()
    _turn(clock, bench, 120.0)
    board.stop_stream()
    b = board.poll()
    heading = np.degrees(np.unwrap(np.arctan2(-b.mag_ut[:, 1], b.mag_ut[:, 0])))
    slope = np.polyfit(b.board_time_s, heading, 1)[0]
    assert slope == pytest.approx(actual, rel=0.01)  # the horizontal field turns at the bench rate


def test_steps_per_degree_error_shows_as_a_rate_error(lab):
    """GRBL set up with the wrong $100 (900 for a bench of 894.33 steps/deg: 0.6 %) turns the
    table faster than commanded: what bench calibrate-bench measures and corrects."""
    clock, devices, urls = lab
    sim = devices["stepper_bench"]
    sim.true_steps_per_deg = 894.33
    sim.eeprom.settings[100] = 900.0
    sim.motion.limits = sim._limits()
    bench = _bench(urls["stepper_bench"], setup=BenchSetup("X", 900.0, 3.5))
    bench.set_rate(2.0)
    bench.run()
    _turn(clock, bench, 100.0)
    # the firmware counts its own steps: it reports 2 deg/s; 1800 steps/s turn the table 2·900/894.33
    assert bench.status()["rate_dps"] == 2.0
    assert sim.stage.commanded_rate_dps(np.array([clock.now()]))[0] == pytest.approx(2.0 * 900 / 894.33, rel=1e-9)


def test_worm_eccentricity_period_changes_with_speed(tmp_path):
    """ESTCube-2 section 4.3: a periodic error on the turning axis whose period differs at every speed."""
    from bench.lab import open_lab

    text = (ROOT / "configs" / "sim_rotating_bench.yaml").read_text()
    text = text.replace("      backend: stepper_bench", "      eccentricity: {amplitude: 0.01, harmonic: 200}\n      backend: stepper_bench", 1)
    text = text.replace("sensor_model: sensors/", f"sensor_model: {ROOT}/configs/sensors/")
    cfg = tmp_path / "ecc.yaml"
    cfg.write_text(text)
    lab = open_lab(load_config(cfg), ["acs_board", "stepper_bench"], sim=True, realtime=False)
    try:
        board, bench, clock = lab.instruments["acs_board"], lab.instruments["stepper_bench"], lab.clock
        board.sensor_power(True)
        clock.sleep(1800.0)
        peaks = {}
        for rate in (1.0, 3.0):
            actual = bench.set_rate(rate)
            bench.run()
            _turn(clock, bench, 10.0)
            board.poll()
            board.start_stream()
            gz = []
            for _ in range(60):
                clock.sleep(1.0)
                bench.status()
                gz.append(board.poll().gyro_dps[:, 2])
            board.stop_stream()
            bench.stop()
            z = np.concatenate(gz)
            spectrum = np.abs(np.fft.rfft(z - z.mean()))
            freqs = np.fft.rfftfreq(z.size, 0.01)
            peaks[rate] = (freqs[np.argmax(spectrum[1:]) + 1], actual)
        for rate, (f_peak, actual) in peaks.items():
            expected = 200 * actual / 360.0  # one error period per worm turn: 200 per stage revolution
            assert f_peak == pytest.approx(expected, abs=2.0 / 60), (rate, f_peak, expected)
        assert peaks[3.0][0] > 2.5 * peaks[1.0][0]
    finally:
        lab.close()


def test_a_recorded_stepper_session_replays_to_the_same_results(tmp_path):
    """tests/data/stepper_two_rates.h5 (tests/sessions/regenerate.py): the procedure at 1 and
    0.2 deg/s, then stopped, as dry-run with GRBL's bytes; its replay sends the same bytes."""
    from bench.replay import replay

    result = replay(ROOT / "tests" / "data" / "stepper_two_rates.h5", runs_dir=tmp_path)
    assert result.ok, result.report()
    assert result.status == "completed"
