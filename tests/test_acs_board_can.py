"""The unchanged ACS-board driver over CAN: CanSerialPort (host) <-> CanSerialBridge (simulated board)
on python-can virtual buses, and through python-can's slcan interface via the simulated SLCAN adapter."""

from __future__ import annotations

import struct

import itertools
import math
import os
import time

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench.clock import VirtualClock, WallClock
from bench.config import load_config
from bench.errors import InstrumentError, InstrumentTimeout, ProtocolError
from bench.sim import registry
from bench.sim.can_serial_bridge import CanSerialBridge
from bench.sim.factory import build_devices
from bench.sim.slcan_gateway import SlcanGatewaySim
from drivers import acs_protocol as proto
from drivers.acs_board import AcsBoard
from drivers.can_serial import (
    CanSerialPort,
    can_ids,
    chunk_bits,
    frame_bits,
    max_odr_hz,
    open_can_serial,
    parse_can_serial_url,
    uart_equivalent_baud,
)
from tests.conftest import SIM_CONFIG

_seq = itertools.count()


def _channel() -> str:
    return f"acs-can-test-{os.getpid()}-{next(_seq)}"


def _board_sim(clock):
    return build_devices(load_config(SIM_CONFIG), clock, ["acs_board"])["acs_board"].device


@pytest.fixture
def rig():
    """(clock, simulated board, bridge, channel) on a fresh virtual bus; closed afterwards."""
    clock = VirtualClock()
    device = _board_sim(clock)
    channel = _channel()
    bridge = CanSerialBridge(device, channel, node=16)
    yield clock, device, bridge, channel
    bridge.close()
    assert bridge.error is None


def _stream(board: AcsBoard, clock, seconds: float, poll_s: float = 1.0):
    """Stream ``seconds`` of run time, polling every ``poll_s``; (batches before stop, all batches)."""
    board.start_stream()
    batches = []
    t_end = clock.now() + seconds
    while clock.now() < t_end - 1e-9:
        clock.sleep_until(min(clock.now() + poll_s, t_end))
        batches.append(board.poll())
    during = list(batches)
    board.stop_stream()
    batches.append(board.poll())
    return during, batches


def _check_contiguous(batches, n: int, odr_hz: float) -> None:
    counter = np.concatenate([b.counter for b in batches])
    board_t = np.concatenate([b.board_time_s for b in batches])
    assert counter.size == n
    assert sum(b.crc_errors + b.dropped_frames + b.garbage_bytes for b in batches) == 0
    assert np.all(np.diff(counter.astype(int)) % 65536 == 1)
    assert np.allclose(np.diff(board_t), 1.0 / odr_hz, atol=2e-6)


def test_driver_configures_and_streams_60_s_over_a_virtual_can_bus(rig):
    clock, device, bridge, channel = rig
    board = AcsBoard(open_can_serial(f"can://virtual/{channel}?node=16", 0.5, clock), timeout_s=0.5)
    try:
        assert board.port.baudrate == 500_000
        ident = board.identify()
        assert ident["serial"] == "SIM-0001" and ident["vendor"] == "bench-sim"
        board.set_odr(100)
        board.set_moving_average(4)
        board.sensor_power(True)
        cfg = board.get_config()
        assert (cfg["odr_hz"], cfg["moving_avg_n"], cfg["sensor_power"]) == (100, 4, True)
        # the simulator is told the UART rate that carries as many 38-byte frames as 500 kbit/s CAN
        assert cfg["baud"] == 763 * 38 * 10
        during, batches = _stream(board, clock, 60.0)
        _check_contiguous(batches, 6000, 100.0)
        # each poll after a 1 s sleep has exactly that second's frames (the RTR sync), none come late
        assert [b.counter.size for b in during] == [100] * 60 and batches[-1].counter.size == 0
        assert board.port.sync_failures == 0 and bridge.syncs_answered >= 60
        assert board.unsolicited_replies == 0
        assert board.port.error_frames == 0
        assert bridge.frames_sent >= math.ceil(6000 * 38 / 8)
    finally:
        board.close()


def test_the_same_driver_through_python_can_slcan_and_the_simulated_adapter(rig):
    clock, device, bridge, channel = rig
    gateway = SlcanGatewaySim(channel)
    name = f"slcan_{channel}"
    url = registry.register(name, gateway)
    try:
        board = AcsBoard(open_can_serial(f"can://slcan/{url}?bitrate=500000&node=16", 0.5, clock), timeout_s=0.5)
        try:
            assert board.identify()["serial"] == "SIM-0001"
            assert gateway.is_open and gateway.bitrate == 500_000
            board.set_moving_average(2)
            board.sensor_power(True)
            # python-can's slcan parses its adapter's text byte by byte (~0.12 s wall per run second
            # here): 20 s of the 60 s stream keep the file fast; the path per second is the same
            during, batches = _stream(board, clock, 20.0)
            _check_contiguous(batches, 2000, 100.0)
            # frames per poll are exact on the virtual bus (test above); through the byte-by-byte
            # SLCAN parser a sync may outlast its wall-time wait on a loaded machine, so a batch can
            # arrive one poll late — never lost (the totals above are exact)
            assert sum(b.counter.size for b in during) >= 1900
            assert gateway.flags == 0  # no overrun, no bus error
        finally:
            board.close()
        assert not gateway.is_open
    finally:
        registry.unregister(name)
        gateway.close()


def test_bus_off_gives_instrument_timeout_within_the_driver_timeout_and_recovers(rig):
    clock, device, bridge, channel = rig
    board = AcsBoard(open_can_serial(f"can://virtual/{channel}", 0.5, clock), timeout_s=0.5)
    try:
        assert board.identify()["serial"] == "SIM-0001"  # default node 0x10 = the bridge's 16
        bridge.inject("bus_off")
        t0, wall0 = clock.now(), time.monotonic()
        with pytest.raises(InstrumentTimeout, match="SENSOR_POWER within 0.5 s"):
            board.sensor_power(True)
        assert clock.now() - t0 == pytest.approx(0.5)  # one attempt: exactly the timeout of run time
        assert time.monotonic() - wall0 < 2.0
        t0 = clock.now()
        with pytest.raises(InstrumentTimeout, match=r"IDENTIFY within 0.5 s \(3 attempt"):
            board.identify()
        assert clock.now() - t0 == pytest.approx(1.5)
        bridge.clear_faults()
        cfg = board.get_config()
        assert cfg["sensor_power"] is False  # the command sent while bus-off never reached the board
    finally:
        board.close()


def test_output_data_rate_beyond_the_can_bandwidth_is_refused(rig):
    clock, device, bridge, channel = rig
    board = AcsBoard(open_can_serial(f"can://virtual/{channel}?node=16", 0.5, clock), timeout_s=0.5)
    try:
        with pytest.raises(ValueError, match=r"1\.\.763 Hz"):
            board.set_odr(764)  # the driver knows the CAN link: 500 kbit/s / 655 bit per 38-byte frame = 763.4 Hz
        with pytest.raises(ProtocolError, match="SET_ODR: BAD_VALUE"):
            board._exchange(board.description.commands["set_odr"], struct.pack("<H", 764))  # and the board refuses it too
        board.set_odr(763)
        board.sensor_power(True)
        _, batches = _stream(board, clock, 5.0)
        _check_contiguous(batches, 763 * 5, 763.0)
    finally:
        board.close()
    # at 1 Mbit/s the link carries 1526 Hz: the board's own 1000 Hz limit applies
    clock2 = VirtualClock()
    channel2 = _channel()
    bridge2 = CanSerialBridge(_board_sim(clock2), channel2, node=16, bitrate=1_000_000)
    port = CanSerialPort(can.Bus(interface="virtual", channel=channel2, receive_own_messages=False), 16,
                         bitrate=1_000_000, timeout=0.5, clock=clock2)
    board2 = AcsBoard(port, timeout_s=0.5)
    try:
        board2.set_odr(1000)
        with pytest.raises(ProtocolError, match="BAD_VALUE"):
            board2.set_odr(1001)
        assert board2.get_config()["odr_hz"] == 1000
    finally:
        board2.close()
        bridge2.close()


def test_error_frames_are_counted_and_dropped_frames_are_caught_by_the_crc(rig):
    clock, device, bridge, channel = rig
    board = AcsBoard(open_can_serial(f"can://virtual/{channel}?node=16", 0.5, clock), timeout_s=0.5)
    try:
        board.sensor_power(True)
        bridge.inject("error_frames", count=5)
        _, batches = _stream(board, clock, 2.0)
        _check_contiguous(batches, 200, 100.0)
        assert board.port.error_frames == 5
        board.start_stream()
        bridge.inject("drop", p=0.2)  # after the ACK: a dropped ACK would be a timeout
        clock.sleep(2.0)
        lossy = board.poll()
        bridge.clear_faults()
        assert bridge.frames_dropped > 0
        assert lossy.counter.size < 200
        assert lossy.dropped_frames + lossy.crc_errors + lossy.garbage_bytes > 0
        clock.sleep(2.0)
        board.stop_stream()
        clean = board.poll()
        assert clean.counter.size >= 199 and np.all(np.diff(clean.counter.astype(int)) % 65536 == 1)
        with pytest.raises(ValueError, match="unknown CAN fault"):
            bridge.inject("melt")
        with pytest.raises(ValueError, match="unknown parameter"):
            bridge.inject("drop", q=1)
    finally:
        board.close()


def test_wall_clock_read_waits_the_timeout_in_wall_time_and_link_errors_become_instrument_errors():
    clock = WallClock()
    channel = _channel()
    bridge = CanSerialBridge(_board_sim(clock), channel)
    port = open_can_serial(f"can://virtual/{channel}", 0.2)  # no clock: waits in wall time
    try:
        board = AcsBoard(port, timeout_s=0.2)
        assert board.get_config()["odr_hz"] == 100
        bridge.inject("bus_off")
        t0 = time.monotonic()
        assert port.read(1) == b""
        assert 0.18 <= time.monotonic() - t0 < 1.0
        bridge.clear_faults()
        port.bus.shutdown()  # the adapter vanishes under the open port
        with pytest.raises(InstrumentError, match="writing IDENTIFY failed"):
            board.identify()
    finally:
        port.own_bus = False
        port.close()
        bridge.close()
    with pytest.raises(InstrumentError):
        board.identify()  # closed port: PortNotOpenError is a SerialException too


def test_url_forms_ids_and_open_errors():
    u, node, bitrate = parse_can_serial_url("can://virtual/chan")
    assert (u.interface, u.channel, node, bitrate) == ("virtual", "chan", 16, 500_000)
    assert parse_can_serial_url("can://virtual/chan?node=1")[1] == 1  # explicit node 1 is kept
    u, node, bitrate = parse_can_serial_url("can://slcan/sim://gw?bitrate=250000&node=3")
    assert (u.channel, node, bitrate) == ("sim://gw", 3, 250_000)
    assert can_ids(16) == (0x310, 0x390) and can_ids(127) == (0x37F, 0x3FF)
    with pytest.raises(InstrumentError, match="unknown option"):
        open_can_serial("can://virtual/chan?tx_id=5")
    with pytest.raises(InstrumentError, match="node 0 outside"):
        open_can_serial("can://virtual/chan?node=0")
    with pytest.raises(InstrumentError, match="cannot open CAN bus"):
        open_can_serial(f"can://slcan/sim://missing-{os.getpid()}")


def test_bandwidth_figures():
    # SOF 1 + id 11 + RTR/IDE/r0 3 + DLC 4 + 64 data + CRC 15 + delimiters/ACK 3 + EOF 7 + IFS 3 = 111 bits,
    # and at most one stuff bit per 4 bits of the 98 stuffed bits (SOF..CRC): 24 -> 135
    assert frame_bits(8) == 111 + 24
    assert frame_bits(6) == 95 + 20
    assert chunk_bits(38) == 4 * 135 + 115  # a data frame travels in 5 CAN frames
    assert max_odr_hz(500_000) == 763 and max_odr_hz(250_000) == 381 and max_odr_hz(125_000) == 190
    assert max_odr_hz(1_000_000) == 1000  # MPU-6000 limit; the link would carry 1526 Hz
    assert uart_equivalent_baud(500_000) // 10 // proto.DATA_FRAME_LEN == 763


class _Loopback:
    """A serial device that sends back every byte it receives, in order."""

    def __init__(self, clock):
        self.clock = clock
        self.received = bytearray()
        self._out = bytearray()

    def receive(self, data: bytes) -> None:
        self.received += data
        self._out += data

    def take_output(self, t_s: float, max_bytes: int | None = None) -> bytes:
        k = len(self._out) if max_bytes is None else min(max_bytes, len(self._out))
        data = bytes(self._out[:k])
        del self._out[:k]
        return data

    def pending_bytes(self, t_s: float) -> int:
        return len(self._out)

    def next_output_time(self) -> float | None:
        return self.clock.now() if self._out else None

    def set_baudrate(self, baudrate: int) -> None:
        self.baudrate = baudrate

    def discard_input(self) -> None:
        pass


@pytest.fixture(scope="module")
def loop_rig():
    clock = VirtualClock()
    channel = _channel()
    device = _Loopback(clock)
    bridge = CanSerialBridge(device, channel, node=42, limit_link=False)
    port = CanSerialPort(can.Bus(interface="virtual", channel=channel, receive_own_messages=False), 42,
                         timeout=0.5, clock=clock)
    sniffer = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    yield device, bridge, port, sniffer
    port.close()
    sniffer.shutdown()
    bridge.close()
    assert bridge.error is None


def _sniffed(sniffer: can.BusABC) -> list[can.Message]:
    out = []
    while (msg := sniffer.recv(timeout=0)) is not None:
        out.append(msg)
    return out


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=300))
def test_any_byte_string_round_trips_through_the_can_tunnel_in_order(loop_rig, data):
    device, bridge, port, sniffer = loop_rig
    device.received.clear()
    _sniffed(sniffer)
    assert port.write(data) == len(data)
    assert port.read(len(data)) == data
    assert bytes(device.received) == data
    frames = _sniffed(sniffer)
    to_board = [m for m in frames if m.arbitration_id == 0x300 + 42]
    to_host = [m for m in frames if m.arbitration_id == 0x380 + 42 and not m.is_remote_frame and m.dlc > 0]
    # a read that waits on the virtual clock syncs: RTR on 0x380 + node, answered by a zero-length frame
    assert all(m.dlc == 0 for m in frames if m.arbitration_id == 0x380 + 42 and m.is_remote_frame)
    assert len(to_board) == math.ceil(len(data) / 8)
    for sent in (to_board, to_host):
        assert b"".join(bytes(m.data) for m in sent) == data
        assert all(m.dlc == len(m.data) and 1 <= m.dlc <= 8 and not m.is_extended_id for m in sent)
    assert all(m.dlc == 8 for m in to_board[:-1])  # one write: only its last frame may be short
    assert port.in_waiting == 0


def test_lab_config_selects_the_can_transport_for_the_board(tmp_path):
    """`sim: {transport: can}` puts the simulated board on a CAN bus; the lab opens it by URL."""
    from bench.config import load_config
    from bench.lab import open_lab
    from tests.conftest import SIM_CONFIG

    text = SIM_CONFIG.read_text().replace("      backend: acs_board\n", "      backend: acs_board\n      transport: can\n")
    text = text.replace("sensor_model: sensors/", f"sensor_model: {SIM_CONFIG.parent}/sensors/")
    cfg = tmp_path / "can.yaml"
    cfg.write_text(text)
    lab = open_lab(load_config(cfg), ["acs_board"], sim=True, realtime=False)
    try:
        assert lab.ports["acs_board"].startswith("can://virtual/") and lab.ports["acs_board"].endswith("node=16")
        board = lab.instruments["acs_board"]
        board.sensor_power(True)
        board.start_stream()
        n = 0
        for _ in range(10):
            lab.clock.sleep(1.0)
            n += board.poll().counter.size
        board.stop_stream()
        assert n == 1000  # 10 s at 100 Hz, nothing lost on the bus
    finally:
        lab.close()
