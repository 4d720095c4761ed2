"""Stepper bench driver against its simulator, and the board on the turning stage seeing the rate."""

from __future__ import annotations

import math

import numpy as np
import pytest
import serial

from bench.clock import VirtualClock
from bench.config import load_config
from bench.errors import ProtocolError
from bench.sim import registry
from bench.sim.factory import build_devices
from drivers.acs_board import AcsBoard
from drivers.stepper_bench import StepperBench
from drivers.stepper_speed import BenchSpeedCalibration
from tests.conftest import ROOT

LAB = ROOT / "configs" / "sim_rotating_bench.yaml"


@pytest.fixture
def lab():
    config = load_config(LAB)
    clock = VirtualClock()
    devices = {n: s.device for n, s in build_devices(config, clock).items()}
    urls = {name: registry.register(f"{name}_t{id(clock)}", dev) for name, dev in devices.items()}
    yield clock, devices, urls
    for name in devices:
        registry.unregister(f"{name}_t{id(clock)}")


def test_identify_run_status_stop(lab):
    clock, devices, urls = lab
    bench = StepperBench.open(urls["stepper_bench"])
    assert bench.identify()["serial"] == "SIM-0002"
    assert bench.status() == {"state": "Idle", "n": 0, "angle_deg": 0.0}
    actual = bench.set_rate(3.0)
    n = bench.n_for_rate(3.0)
    assert n == round(19.5154 * (1 / math.radians(3.0) - 0.4088))  # Eq. 3.1
    assert actual == pytest.approx(3.0, abs=0.01)  # n is an integer: rate resolution
    bench.run()
    clock.sleep(10.0)
    st = bench.status()
    assert st["state"] == "Run" and st["angle_deg"] == pytest.approx(10 * actual, abs=1e-3)
    bench.safe_state()
    clock.sleep(10.0)
    assert bench.status()["angle_deg"] == pytest.approx(10 * actual, abs=1e-3)


def test_errors_are_typed(lab):
    _, _, urls = lab
    bench = StepperBench.open(urls["stepper_bench"])
    with pytest.raises(ProtocolError, match="error:22"):
        bench.run()  # no speed set yet: GRBL's "feed rate has not yet been set" (docs/golden/grbl.md)
    with pytest.raises(ProtocolError, match="error:3"):
        bench.channel.transact("$WARP")
    with pytest.raises(ProtocolError, match="error:2"):
        bench.channel.transact("$N=abc")
    with pytest.raises(ValueError):
        bench.n_for_rate(1e6)  # faster than n = 1 allows


def test_board_on_the_stage_sees_the_commanded_rate(lab):
    clock, devices, urls = lab
    bench = StepperBench.open(urls["stepper_bench"])
    board = AcsBoard.open(urls["acs_board"])
    board.sensor_power(True)
    clock.sleep(3600.0)  # past the warm-up
    rates = {}
    for rate in (0.0, 1.0, -2.0):
        if rate:
            rates[rate] = bench.set_rate(rate)
            bench.run()
        board.start_stream()
        clock.sleep(30.0)
        board.stop_stream()
        rates.setdefault(rate, 0.0)
        gz = board.poll().gyro_dps[:, 2]
        rates[rate] = (rates[rate], gz.mean())
        bench.stop()
    base = rates[0.0][1]
    for rate in (1.0, -2.0):
        actual, measured = rates[rate]
        # the board's z gyro shows the bench rate on top of the same bias (noise of the mean 4e-4)
        assert measured - base == pytest.approx(actual, abs=3e-3)


def test_magnetometer_turns_with_the_stage(lab):
    clock, devices, urls = lab
    bench = StepperBench.open(urls["stepper_bench"])
    board = AcsBoard.open(urls["acs_board"])
    board.sensor_power(True)
    actual = bench.set_rate(3.0)
    bench.run()
    board.start_stream()
    clock.sleep(120.0)
    board.stop_stream()
    b = board.poll()
    heading = np.degrees(np.unwrap(np.arctan2(-b.mag_ut[:, 1], b.mag_ut[:, 0])))
    slope = np.polyfit(b.board_time_s, heading, 1)[0]
    assert slope == pytest.approx(actual, rel=0.01)  # the horizontal field turns at the bench rate


def test_calibration_mismatch_between_driver_and_bench_shows(lab):
    """A driver using the thesis calibration on a bench whose k differs commands the wrong rate."""
    clock, devices, urls = lab
    devices["stepper_bench"].cal = BenchSpeedCalibration(k=21.0, b_s_per_rad=0.4088)
    bench = StepperBench.open(urls["stepper_bench"])
    bench.set_rate(2.0)
    bench.run()
    clock.sleep(100.0)
    angle = bench.status()["angle_deg"]
    assert abs(angle - 200.0) > 5.0


def test_realtime_bytes_act_inside_a_line(lab):
    clock, devices, urls = lab
    port = serial.serial_for_url(urls["stepper_bench"], baudrate=115200, timeout=0.1)
    port.write(b"$N=3")
    port.write(b"?")  # realtime status in the middle of a line: answered at once
    assert port.readline() == b"<Idle|MPos:0.000,0.000,0.000|F:0|N:0>\r\n"
    port.write(b"00\n$RUN\n")  # the line continues: $N=300
    assert port.readline() == b"ok\r\n" and port.readline() == b"ok\r\n"
    assert devices["stepper_bench"].running and devices["stepper_bench"].n == 300
    port.write(b"\x18")  # reset while turning: GRBL's ALARM:3, then its welcome message
    assert port.readline() == b"ALARM:3\r\n" and port.readline() == b"\r\n"
    assert port.readline().startswith(b"Grbl 1.1f ['$' for help]")
    assert not devices["stepper_bench"].running


def test_worm_eccentricity_period_changes_with_speed(tmp_path):
    """ESTCube-2 section 4.3: a periodic error on the turning axis whose period differs at every speed."""
    from bench.lab import open_lab

    text = (ROOT / "configs" / "sim_rotating_bench.yaml").read_text()
    text = text.replace("      backend: stepper_bench\n", "      backend: stepper_bench\n      eccentricity: {amplitude: 0.01, harmonic: 200}\n")
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
            clock.sleep(10.0)
            board.poll()
            board.start_stream()
            gz = []
            for _ in range(60):
                clock.sleep(1.0)
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
