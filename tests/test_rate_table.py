"""Rate table: the real driver against the simulated CiA 402 drives over real transports.

Transports: python-can's virtual bus (in-process), the simulated SLCAN adapter through ``sim://``,
and the same adapter on a pseudo-terminal used by python-can's ``slcan`` interface in another process.
"""

from __future__ import annotations

import itertools
import math
import os
import subprocess
import threading
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.clock import VirtualClock, WallClock
from bench.errors import DeviceFault, InstrumentError, InstrumentTimeout, ProtocolError
from bench.sim import registry
from bench.sim.pty_server import close_endpoints, open_endpoint, serve
from bench.sim.rate_table import RateTableSim
from bench.sim.slcan_gateway import BEL, SlcanError, SlcanGatewaySim, decode_frame, encode_frame
from bench.sim.table_motion import NPSAT1_TILT_DEG, AxisMotion, Eccentricity
from drivers.can_transport import parse_can_url
from drivers.rate_table import EDS_PATH, RateTable
from tests.conftest import ROOT

_ids = itertools.count()


def _channel() -> str:
    return f"rate_table_test_{os.getpid()}_{next(_ids)}"


@pytest.fixture
def table():
    """(driver, sim, clock) on a fresh python-can virtual channel and a VirtualClock."""
    clock = VirtualClock()
    channel = _channel()
    sim = RateTableSim(clock, bus=channel)
    traffic: list[tuple[str, str, bytes]] = []
    drv = RateTable.open(f"can://virtual/{channel}?node=1", timeout_s=0.3, clock=clock,
                         on_traffic=lambda d, n, raw: traffic.append((d, n, raw)))
    drv.traffic = traffic
    yield drv, sim, clock
    drv.close()
    sim.close()


def test_identify_reads_the_drive_identity(table):
    drv, _, _ = table
    ident = drv.identify()
    assert ident["model"] == "TRT-7 rotation axis drive (simulated)"
    assert ident["serial"] == "SIM-0003"
    assert ident["firmware"] == "sim-1.0"
    assert ident["vendor"] == "0x00000000"


def test_traffic_hook_sees_named_sdo_frames(table):
    drv, _, _ = table
    drv.traffic.clear()
    drv.set_rate(1.0)
    writes = [(n, raw) for d, n, raw in drv.traffic if d == "command" and "0x60FF" in n]
    assert writes and writes[0][0] == "SDO write 0x60FF target_velocity"
    raw = writes[0][1]
    assert raw[:2] == bytes([0x06, 0x01])  # COB-ID 0x601: SDO request to node 1
    assert int.from_bytes(raw[6:10], "little") == 1000  # 1 deg/s = 1000 counts/s
    replies = [d for d, n, _ in drv.traffic if n == "SDO write 0x60FF target_velocity"]
    assert replies == ["command", "reply"]


def test_set_rate_ramps_at_the_acceleration_limit_then_holds(table):
    drv, sim, clock = table
    assert drv.set_rate(10.0, accel_dps2=5.0) == 10.0
    t0 = clock.now()
    clock.sleep(1.0)
    r = drv.read()
    assert r["rate_dps"] == pytest.approx(5.0, abs=0.01)
    assert not r["target_reached"]
    r = drv.wait_until(timeout_s=5.0)
    assert r["rate_dps"] == 10.0 and r["state"] == "OPERATION ENABLED"
    assert clock.now() - t0 == pytest.approx(2.0, abs=0.06)  # 10 deg/s at 5 deg/s^2
    clock.sleep(10.0)
    assert drv.read()["rate_dps"] == 10.0
    t = np.linspace(t0, t0 + 4.0, 401)
    accel = np.diff(sim.rotation.rate_dps(t)) / np.diff(t)
    assert np.all(np.abs(accel) <= 5.0 + 1e-9)


def test_move_to_reaches_the_angle_and_reports_target_reached(table):
    drv, _, clock = table
    drv.move_to(90.0, rate_dps=20.0, accel_dps2=20.0)
    assert not drv.read()["target_reached"]
    r = drv.wait_until(timeout_s=20.0)
    assert r["angle_deg"] == pytest.approx(90.0, abs=0.001)
    assert r["rate_dps"] == 0.0 and r["target_reached"]
    assert 5.5 <= clock.now() <= 6.0  # 1 s ramp + 3.5 s cruise + 1 s ramp, polled at 0.05 s


def test_tilt_moves_the_tilt_axis_within_its_limits(table):
    drv, sim, _ = table
    drv.tilt(NPSAT1_TILT_DEG)
    r = drv.wait_until(timeout_s=30.0)
    assert r["tilt_deg"] == pytest.approx(NPSAT1_TILT_DEG, abs=0.001)
    assert r["angle_deg"] == 0.0
    assert sim.tilt.angle_deg(np.array([1e6]))[0] == pytest.approx(NPSAT1_TILT_DEG)
    with pytest.raises(ValueError, match="limits"):
        drv.tilt(150.0)


def test_stop_halts_and_stays_enabled(table):
    drv, _, clock = table
    drv.set_rate(20.0, accel_dps2=40.0)
    clock.sleep(2.0)
    drv.stop()
    r = drv.wait_until(lambda r: r["rate_dps"] == 0.0, timeout_s=5.0)
    assert r["state"] == "OPERATION ENABLED"
    angle = r["angle_deg"]
    clock.sleep(5.0)
    assert drv.read()["angle_deg"] == angle
    drv.set_rate(-3.0)  # releases the halt
    assert drv.wait_until(timeout_s=5.0)["rate_dps"] == -3.0


def test_safe_state_from_moving_stops_and_disables_both_axes(table):
    drv, sim, clock = table
    drv.set_rate(30.0, accel_dps2=30.0)
    drv.tilt(45.0)
    clock.sleep(1.5)
    drv.safe_state()
    r = drv.read()
    assert r["rate_dps"] == 0.0 and r["tilt_rate_dps"] == 0.0
    assert r["state"] == r["tilt_state"] == "SWITCH ON DISABLED"
    assert sim.rotation.rate_dps(np.array([clock.now() + 100.0]))[0] == 0.0


def test_safe_state_with_one_axis_in_fault_still_stops_the_other(table):
    drv, sim, clock = table
    drv.set_rate(10.0)
    drv.tilt(20.0, rate_dps=2.0)
    clock.sleep(0.5)
    sim.inject("fault", axis="rotation", code=0x2310)
    drv.safe_state()
    r = drv.read()
    assert r["state"] == "FAULT" and r["fault"] and r["any_fault"]
    assert r["tilt_state"] == "SWITCH ON DISABLED" and r["tilt_rate_dps"] == 0.0
    with pytest.raises(DeviceFault, match="0x2310") as info:
        drv.set_rate(1.0)
    assert info.value.error_code == 0x2310
    assert any(n.startswith("EMCY 0x2310") for d, n, _ in drv.traffic if d == "reply")
    drv.reset_fault("rotation")
    drv.set_rate(1.0)
    assert drv.wait_until(timeout_s=5.0)["rate_dps"] == 1.0


def test_wait_until_raises_device_fault_when_a_drive_faults(table):
    drv, sim, _ = table
    drv.move_to(360.0, rate_dps=10.0)
    sim.inject("fault", axis="rotation", code=0x8611)
    with pytest.raises(DeviceFault, match="0x8611"):
        drv.wait_until(timeout_s=60.0)


def test_sdo_abort_becomes_protocol_error_with_its_meaning(table):
    drv, sim, _ = table
    sim.inject("sdo_abort", code=0x08000022, count=1)
    with pytest.raises(ProtocolError, match="0x08000022"):
        drv.set_rate(1.0)
    drv.set_rate(1.0)  # count=1: healed
    with pytest.raises(ProtocolError, match="0x06090031.*too high"):
        drv.set_rate(500.0)  # beyond 0x607F max profile velocity


def test_silent_drive_gives_instrument_timeout_within_the_timeout(table):
    drv, sim, _ = table
    sim.inject("silent")
    t0 = time.monotonic()
    with pytest.raises(InstrumentTimeout, match="no answer"):
        drv.read()
    assert time.monotonic() - t0 < 0.3 + 0.25  # timeout_s plus scheduling margin
    sim.clear_faults()
    assert drv.read()["state"] == "SWITCH ON DISABLED"


def test_stuck_axis_never_reaches_target_and_wait_is_bounded(table):
    drv, sim, clock = table
    sim.inject("stuck", axis="rotation")
    drv.move_to(10.0)
    t0 = clock.now()
    with pytest.raises(InstrumentTimeout):
        drv.wait_until(timeout_s=3.0)
    assert clock.now() - t0 == pytest.approx(3.0, abs=0.06)
    r = drv.read()
    assert r["following_error"] and r["angle_deg"] == 0.0


def test_error_frames_reach_the_driver_and_the_slcan_status_flags():
    clock = VirtualClock()
    channel = _channel()
    sim = RateTableSim(clock, bus=channel)
    gateway = SlcanGatewaySim(channel)
    drv = RateTable.open(f"can://virtual/{channel}", clock=clock)
    try:
        sim.inject("error_frames", count=3)
        deadline = time.monotonic() + 2.0
        while drv.read()["error_frames"] < 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert drv.read()["error_frames"] == 3
        assert gateway.handle_line(b"F") == b"F80\r"  # bus error flag, then cleared
        assert gateway.handle_line(b"F") == b"F00\r"
    finally:
        drv.close()
        sim.close()
        gateway.close()


def test_the_same_driver_works_through_the_slcan_gateway():
    clock = VirtualClock()
    channel = _channel()
    sim = RateTableSim(clock, bus=channel, node_id=5)
    gateway = SlcanGatewaySim(channel)
    name = f"slcan_{channel}"
    registry.register(name, gateway)
    try:
        drv = RateTable.open(f"can://slcan/sim://{name}?bitrate=500000&node=5", timeout_s=0.5, clock=clock)
        try:
            assert drv.identify()["serial"] == "SIM-0003"
            drv.set_rate(-5.0, accel_dps2=10.0)
            r = drv.wait_until(timeout_s=5.0)
            assert r["rate_dps"] == -5.0
            assert gateway.bitrate == 500_000 and gateway.is_open
            sim.inject("sdo_abort", axis="rotation", code=0x06010002, count=1)
            with pytest.raises(ProtocolError, match="0x06010002"):
                drv.read()
            drv.safe_state()
            assert drv.read()["state"] == "SWITCH ON DISABLED"
        finally:
            drv.close()
        assert not gateway.is_open  # python-can closes the channel with C on shutdown
    finally:
        registry.unregister(name)
        sim.close()
        gateway.close()


def test_python_can_slcan_in_another_process_reads_the_device_name_through_a_pty():
    clock = WallClock()
    channel = _channel()
    sim = RateTableSim(clock, bus=channel)
    gateway = SlcanGatewaySim(channel)
    ep = open_endpoint("rate_table", gateway)
    stop = threading.Event()
    server = threading.Thread(target=serve, args=([ep], clock, stop.is_set), daemon=True)
    server.start()
    script = (
        "import can, canopen, sys\n"
        "bus = can.Bus(interface='slcan', channel=sys.argv[1], bitrate=500000, sleep_after_open=0)\n"
        "net = canopen.Network(bus); net.NOTIFIER_CYCLE = 0.05; net.connect()\n"
        "node = net.add_node(1, sys.argv[2])\n"
        "print(node.sdo['Manufacturer device name'].raw)\n"
        "net.disconnect()\n"
    )
    try:
        out = subprocess.run([str(ROOT / ".venv" / "bin" / "python"), "-c", script, ep.path, str(EDS_PATH)],
                             cwd=ROOT, capture_output=True, text=True, timeout=20)
        assert out.returncode == 0, out.stderr
        assert out.stdout.strip() == "TRT-7 rotation axis drive (simulated)"
    finally:
        stop.set()
        server.join(timeout=2)
        close_endpoints([ep])
        sim.close()
        gateway.close()


def test_can_url_forms_and_errors():
    u = parse_can_url("can://slcan/sim://gw?bitrate=250000&node=3")
    assert (u.interface, u.channel, u.node, u.options) == ("slcan", "sim://gw", 3, {"bitrate": "250000"})
    assert parse_can_url("can://slcan//dev/pts/3").channel == "/dev/pts/3"
    assert parse_can_url("can://socketcan/can0?node=7").node == 7
    for bad in ("virtual/x", "can://pcan/x", "can://virtual/x?speed=1", "can://virtual/x?node=200", "can://virtual/"):
        with pytest.raises(InstrumentError):
            parse_can_url(bad)


# ---- SLCAN line decoder ------------------------------------------------------------------------
@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=40))
def test_slcan_gateway_answers_any_line_with_ok_bel_or_a_reply(line):
    gateway = SlcanGatewaySim(_channel())
    try:
        gateway.handle_line(b"O")
        answer = gateway.handle_line(line.replace(b"\r", b""))
        assert answer.endswith(b"\r") or answer == BEL
        gateway.receive(line + b"\r")  # the byte stream path never raises either
    finally:
        gateway.close()


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=30))
def test_slcan_decode_frame_gives_a_frame_or_a_clean_error(text):
    try:
        msg = decode_frame(text)
    except SlcanError:
        return
    assert encode_frame(msg).upper() == text.upper()


@settings(max_examples=200, deadline=None)
@given(st.booleans(), st.integers(0, 0x1FFFFFFF), st.binary(max_size=8))
def test_slcan_frames_round_trip(extended, can_id, data):
    import can

    can_id = can_id if extended else can_id & 0x7FF
    msg = can.Message(arbitration_id=can_id, is_extended_id=extended, data=data)
    back = decode_frame(encode_frame(msg))
    assert (back.arbitration_id, back.is_extended_id, bytes(back.data)) == (can_id, extended, data)


# ---- kinematics --------------------------------------------------------------------------------
_command = st.one_of(
    st.tuples(st.just("rate"), st.floats(-60, 60), st.floats(0.5, 60)),
    st.tuples(st.just("position"), st.floats(-720, 720), st.floats(0.5, 60), st.floats(0.5, 60)),
    st.tuples(st.just("stop"), st.floats(0.5, 60)),
)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 8.0), _command), min_size=1, max_size=6),
       st.floats(0.0, 0.01), st.integers(1, 4), st.floats(0, 2 * math.pi))
def test_kinematics_angle_is_the_integral_of_rate_and_accel_is_limited(commands, ecc, harmonic, phase):
    m = AxisMotion(eccentricity=Eccentricity(ecc, harmonic, phase))
    t = 0.0
    limits = []
    for dt, cmd in commands:
        t += dt
        if cmd[0] == "rate":
            m.command_rate(t, cmd[1], cmd[2])
            limits.append(cmd[2])
        elif cmd[0] == "position":
            m.command_position(t, cmd[1], cmd[2], cmd[3])
            limits.append(cmd[3])
        else:
            m.stop(t, cmd[1])
            limits.append(cmd[1])
    end = max(m.settled_at(), t) + 2.0
    grid = np.linspace(0.0, end, 200_001)
    h = grid[1] - grid[0]
    # commanded profile: |acceleration| never above the largest limit used
    cr = m.commanded_rate_dps(grid)
    assert np.all(np.abs(np.diff(cr)) / h <= max(limits) * (1 + 1e-6) + 1e-6)
    # true (eccentric) angle is the integral of the true rate (trapezoid rule error bound)
    rate, angle = m.rate_dps(grid), m.angle_deg(grid)
    integral = angle[0] + np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * h)])
    assert np.max(np.abs(integral - angle)) < 1e-3 * max(1.0, np.max(np.abs(angle)))


@settings(max_examples=100, deadline=None)
@given(st.floats(-60, 60), st.floats(0.0, 5.0), st.floats(-1000, 1000), st.floats(0.1, 60), st.floats(0.1, 60))
def test_kinematics_position_moves_end_at_rest_on_the_target(rate0, t_cmd, target, rate, accel):
    m = AxisMotion()
    m.command_rate(0.0, rate0, 60.0)
    t_end = m.command_position(t_cmd, target, rate, accel)
    assert m.settled_at() == t_end
    a, w = m.commanded_state(t_end + 1.0)
    assert a == target and w == 0.0
    grid = np.linspace(t_cmd, t_end, 20_001)
    assert np.max(np.abs(m.commanded_rate_dps(grid))) <= max(rate, abs(rate0)) * (1 + 1e-9)
    if t_end - t_cmd > 1e-9:  # a move shorter than a nanosecond has no resolvable acceleration
        h = grid[1] - grid[0]
        steps = np.abs(np.diff(m.commanded_rate_dps(grid))) / h
        # rounding of run times near t_end (one ulp of t) shows up divided by a tiny grid step
        rounding = 4 * accel * np.finfo(float).eps * max(1.0, t_end) / h
        assert np.all(steps <= accel * (1 + 1e-6) + 1e-6 + rounding)


def test_kinematics_history_is_not_rewritten_and_memory_is_bounded():
    m = AxisMotion(horizon_s=10.0, max_segments=50)
    m.command_rate(5.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="rewritten"):
        m.command_rate(4.0, 2.0, 1.0)
    with pytest.raises(ValueError, match="limit"):
        m.command_rate(6.0, 100.0)
    for k in range(2000):
        m.command_rate(10.0 + k, (-1) ** k * 5.0, 60.0)
    assert len(m) <= 50
    with pytest.raises(ValueError, match="retained"):
        m.angle_deg(np.array([0.0]))
    assert m.rate_dps(np.array([2009.5]))[0] == -5.0


def test_encoder_quantisation_and_eccentricity_are_separate_views():
    m = AxisMotion(eccentricity=Eccentricity(0.01, 2, 0.0))
    m.command_rate(0.0, 10.0, 10.0)
    t = 10.0  # 5 deg ramp, then 9 s at 10 deg/s: 95 deg commanded
    assert m.position_counts(t) == 95_000 and m.velocity_counts(t) == 10_000
    true_rate = m.rate_dps(np.array([t]))[0]
    assert true_rate == pytest.approx(10.0 * (1 + 0.01 * math.sin(2 * math.radians(95.0))))
    assert not AxisMotion().ever_moved and m.ever_moved
