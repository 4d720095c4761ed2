"""The real ACS-board driver against the simulator, through the sim:// pyserial URL handler."""

from __future__ import annotations

import math

import numpy as np
import pytest
import serial

from bench.sim.chamber import ChamberParams
from bench.errors import DeviceFault, InstrumentTimeout, ProtocolError
from drivers import acs_protocol as proto
from drivers.acs_board import AcsBoard

# Expected values computed here from the source documents, not from the model code:
EARTH_DPS = 360.0 / 86164.0905
LAT = math.radians(36.4)  # NPSAT1 IV.E, Monterey


def estcube_bias_dps(t_c: float) -> float:
    """ESTCube-2 Table 4.1 MPU-6000 z-axis correction at 0 deg/s, negated."""
    return -(1.124e-4 * t_c**2 + 7.561e-3 * t_c + 1.150e-1)


def test_identify_and_power_up_configuration(sim_board):
    _, _, url = sim_board
    board = AcsBoard.open(url)
    ident = board.identify()
    assert ident["serial"] == "SIM-0001" and ident["vendor"] == "bench-sim"
    cfg = board.get_config()
    assert cfg["odr_hz"] == 100 and cfg["moving_avg_n"] == 1
    assert not cfg["streaming"] and not cfg["sensor_power"] and cfg["baud"] == 115200


def test_stream_needs_sensor_power(sim_board):
    _, _, url = sim_board
    board = AcsBoard.open(url)
    with pytest.raises(DeviceFault, match="START_STREAM"):
        board.start_stream()


def _record(board: AcsBoard, clock, seconds: float):
    board.start_stream()
    batches = []
    t_end = clock.now() + seconds
    while clock.now() < t_end:
        clock.sleep_until(min(clock.now() + 1.0, t_end))
        batches.append(board.poll())
    board.stop_stream()
    batches.append(board.poll())
    return batches


def test_stream_rate_values_and_continuity(sim_board):
    device, clock, url = sim_board
    board = AcsBoard.open(url)
    board.sensor_power(True)
    clock.sleep(20 * 60.0)  # let the 12-minute warm-up transient settle
    batches = _record(board, clock, 60.0)
    counter = np.concatenate([b.counter for b in batches])
    gyro = np.concatenate([b.gyro_dps for b in batches])
    accel = np.concatenate([b.accel_g for b in batches])
    temp = np.concatenate([b.temp_degc for b in batches])
    board_t = np.concatenate([b.board_time_s for b in batches])
    assert counter.size == 6000  # 60 s at 100 Hz
    assert sum(b.dropped_frames + b.crc_errors + b.garbage_bytes for b in batches) == 0
    assert np.all(np.diff(counter.astype(int)) % 65536 == 1)
    assert np.allclose(np.diff(board_t), 0.01, atol=2e-6)
    # the powered die settles self_heating_c above its mount (chamber at the 20 degC ambient)
    die_c = 20.0 + ChamberParams().self_heating_c
    assert np.allclose(temp, die_c, atol=0.05)
    expected = estcube_bias_dps(die_c) + np.array([EARTH_DPS * math.cos(LAT), 0.0, EARTH_DPS * math.sin(LAT)])
    # MPU-6000 0.005 deg/s/sqrt(Hz) over min(pi/2*12.5, 50) Hz -> sigma 0.022 deg/s; mean of 6000: 3e-4
    assert np.allclose(gyro.mean(axis=0), expected, atol=2e-3)
    sigma = 0.005 * math.sqrt(math.pi / 2 * 12.5)
    assert np.allclose(gyro.std(axis=0), sigma, rtol=0.1)
    assert np.allclose(accel.mean(axis=0), [0, 0, 1], atol=1e-3)


def test_warmup_transient_visible_after_power_on(sim_board):
    _, clock, url = sim_board
    board = AcsBoard.open(url)
    board.sensor_power(True)

    def thermally_compensated_mean(batches):
        # the die warms by self-heating after power-on; remove the temperature-dependent bias
        gyro = np.concatenate([b.gyro_dps for b in batches])
        temp = np.concatenate([b.temp_degc for b in batches]).reshape(gyro.shape[0], -1)  # per sensor
        return (gyro - estcube_bias_dps(temp)).mean(axis=0), temp

    first, t_first = thermally_compensated_mean(_record(board, clock, 30.0))
    clock.sleep(30 * 60.0)
    late, t_late = thermally_compensated_mean(_record(board, clock, 30.0))
    assert t_late.mean() - t_first.mean() > 2.0  # self-heating is visible in the temperature channel
    # NPSAT1 IV.A: the outputs change by 0.024 / 0.017 / 0.019 deg/s from turn-on until stable
    assert np.allclose(first - late, [0.024, 0.017, 0.019], atol=0.004)


def test_moving_average_reduces_noise_and_is_prefilled(sim_board):
    _, clock, url = sim_board
    board = AcsBoard.open(url)
    board.sensor_power(True)
    clock.sleep(3600.0)
    raw = np.concatenate([b.gyro_dps for b in _record(board, clock, 40.0)])
    board.set_moving_average(16)
    avg = np.concatenate([b.gyro_dps for b in _record(board, clock, 40.0)])
    ratio = raw.std(axis=0) / avg.std(axis=0)
    assert np.all(ratio > 3.0) and np.all(ratio < 5.0)  # boxcar of 16 independent samples: 4x
    # pre-filled buffer: the first averaged samples start at one real sample (noise sigma 0.022
    # deg/s), not pulled towards zero as a zero-filled buffer would (-0.31/16 = -0.02 deg/s)
    assert np.allclose(avg[:5].mean(axis=0), raw.mean(axis=0), atol=0.08)


def test_commands_during_streaming_lose_no_frames(sim_board):
    _, clock, url = sim_board
    board = AcsBoard.open(url)
    board.sensor_power(True)
    board.start_stream()
    got = 0
    for _ in range(10):
        clock.sleep(0.5)
        board.get_config()  # replies interleave with data frames
        got += board.poll().counter.size
    clock.sleep(0.5)
    board.stop_stream()
    got += board.poll().counter.size
    assert got == 550
    assert board.decoder.dropped_frames == 0


def test_odr_limited_by_link(sim_board):
    device, clock, url = sim_board
    port = serial.serial_for_url(url, baudrate=9600, timeout=0.5)
    board = AcsBoard(port)
    with pytest.raises(ValueError, match="outside 1..25 Hz"):
        board.set_odr(100)
    # the board itself refuses too (NAK BAD_VALUE), when the driver's check is bypassed
    port.write(proto.encode_frame(proto.FrameType.SET_ODR, (100).to_bytes(2, "little")))
    replies = proto.FrameDecoder().feed(port.read(64)).replies
    assert replies == [(proto.FrameType.NAK, bytes([proto.FrameType.SET_ODR, proto.NakCode.BAD_VALUE]))]
    board.set_odr(25)
    assert board.get_config()["odr_hz"] == 25


def test_nak_becomes_protocol_error(sim_board):
    _, _, url = sim_board
    board = AcsBoard.open(url)
    port = board.port
    port.write(proto.encode_frame(0x3C))
    assert proto.FrameDecoder().feed(port.read(64)).replies == [(proto.FrameType.NAK, bytes([0x3C, proto.NakCode.UNKNOWN_COMMAND]))]
    with pytest.raises(ProtocolError, match="BAD_LENGTH"):
        board._exchange(board.description.commands["set_moving_avg"], b"\x01\x02")


def test_silent_port_times_out_after_retries():
    # loop:// echoes our own command frames back: a real transport on which no board answers
    port = serial.serial_for_url("loop://", baudrate=115200, timeout=0.05)
    board = AcsBoard(port, timeout_s=0.05, retries=2)
    sent = []
    board.on_traffic = lambda d, t, raw: sent.append((d, t))
    with pytest.raises(InstrumentTimeout, match="IDENTIFY.*3 attempt"):
        board.identify()
    assert sent == [("command", "IDENTIFY")] * 3
    sent.clear()
    with pytest.raises(InstrumentTimeout, match="1 attempt"):
        board.start_stream()  # not idempotent: never retried
    assert sent == [("command", "START_STREAM")]


def test_missed_reply_costs_virtual_time_not_wall_time(sim_board):
    import time

    device, clock, url = sim_board
    port = serial.serial_for_url(url, baudrate=115200, timeout=2.0)
    t0, w0 = clock.now(), time.monotonic()
    assert port.read(10) == b""  # nothing will come: the read times out on the virtual clock
    assert clock.now() - t0 == pytest.approx(2.0)
    assert time.monotonic() - w0 < 0.5


def test_unknown_sim_device_is_a_clear_error():
    from bench.errors import InstrumentError
    from bench.sim.registry import install_url_handler

    install_url_handler()
    with pytest.raises(InstrumentError, match="no simulated device 'nope'"):
        AcsBoard.open("sim://nope")
