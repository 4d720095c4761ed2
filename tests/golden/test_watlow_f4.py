"""Golden Modbus exchanges of the Watlow F4 (docs/golden/watlow-f4.md), both transports.

The rows are literal hex transcribed from the documents listed in docs/golden/watlow-f4.md
(Modbus Application Protocol V1.1b3, Modbus over Serial Line V1.02, Modbus TCP implementation guide,
Watlow Controls Communications Guide, ESPEC ChamberConnectLibrary); nothing here is computed by the
project's encoders, and no register constant of the driver is imported. Each row is checked

(a) against the driver: a fake peer (RTU: a serial device behind ``sim://``; TCP: a socket on
    127.0.0.1) expects exactly the request bytes and answers exactly the response bytes, in the
    style of PyMeasure's ``expected_protocol``; the decoded value or the typed error is asserted;
(b) against the simulators: the request is sent raw (TCP socket; RTU through the ``sim://`` serial
    port) and the exact response bytes are asserted for a simulator state set by the test.
"""

from __future__ import annotations

import itertools
import re
import socket
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import pytest
import serial

from bench.clock import VirtualClock
from bench.errors import ProtocolError
from bench.sim import registry
from bench.sim.chamber import Chamber, ChamberParams
from bench.sim.watlow_f4_rtu import WatlowF4RtuSim
from bench.sim.watlow_f4_server import WatlowF4Server
from drivers.watlow_f4 import WatlowF4

DOC = Path(__file__).resolve().parents[2] / "docs" / "golden" / "watlow-f4.md"
TIMEOUT_S = 0.3  # driver answer timeout (s)
PEER_WAIT_S = 5.0  # longest wall-clock wait of the fake TCP peer for a request (s)
NO_ANSWER_S = 0.3  # how long a raw client listens for an answer that must not come (s)
AMBIENT_C = 25.6  # chamber temperature and set point of the simulator state (°C)
_names = itertools.count()


@dataclass(frozen=True)
class Row:
    """One golden exchange; ``None`` response = the peer stays silent; ``None`` request = n/a."""

    rtu_request: str
    rtu_response: str | None
    tcp_request: str | None
    tcp_response: str | None


ROWS: dict[str, Row] = {
    "G1": Row("01 03 00 64 00 01 C5 D5", "01 03 02 01 00 B9 D4",
              "00 01 00 00 00 06 01 03 00 64 00 01", "00 01 00 00 00 05 01 03 02 01 00"),
    "G2": Row("01 03 01 2C 00 01 44 3F", "01 03 02 FF 85 38 17",
              "00 01 00 00 00 06 01 03 01 2C 00 01", "00 01 00 00 00 05 01 03 02 FF 85"),
    "G3": Row("01 06 01 2C 01 63 08 46", "01 06 01 2C 01 63 08 46",
              "00 01 00 00 00 06 01 06 01 2C 01 63", "00 01 00 00 00 06 01 06 01 2C 01 63"),
    "G4": Row("01 03 02 5E 00 01 E4 60", "01 03 02 00 01 79 84",
              "00 01 00 00 00 06 01 03 02 5E 00 01", "00 01 00 00 00 05 01 03 02 00 01"),
    "G5": Row("01 03 03 85 00 01 95 A7", "01 03 02 00 01 79 84",
              "00 01 00 00 00 06 01 03 03 85 00 01", "00 01 00 00 00 05 01 03 02 00 01"),
    "G6": Row("01 03 00 C8 00 01 05 F4", "01 03 02 00 01 79 84",
              "00 01 00 00 00 06 01 03 00 C8 00 01", "00 01 00 00 00 05 01 03 02 00 01"),
    "G7": Row("01 03 00 67 00 01 35 D5", "01 03 02 27 10 A2 78",
              "00 01 00 00 00 06 01 03 00 67 00 01", "00 01 00 00 00 05 01 03 02 27 10"),
    "G8": Row("01 02 00 01 00 02 A8 0B", "01 82 01 81 60",
              "00 01 00 00 00 06 01 02 00 01 00 02", "00 01 00 00 00 03 01 82 01"),
    "G9": Row("01 03 00 64 00 01 C5 D5", "01 83 01 80 F0",
              "00 01 00 00 00 06 01 03 00 64 00 01", "00 01 00 00 00 03 01 83 01"),
    "G10": Row("01 03 00 65 00 01 94 15", "01 83 02 C0 F1",
               "00 01 00 00 00 06 01 03 00 65 00 01", "00 01 00 00 00 03 01 83 02"),
    "G11": Row("01 06 00 64 00 05 08 16", "01 86 02 C3 A1",
               "00 01 00 00 00 06 01 06 00 64 00 05", "00 01 00 00 00 03 01 86 02"),
    "G12": Row("01 06 00 2D 00 01 D8 03", "01 86 02 C3 A1",
               "00 01 00 00 00 06 01 06 00 2D 00 01", "00 01 00 00 00 03 01 86 02"),
    "G13": Row("01 06 01 2C 07 D0 4A 53", "01 86 03 02 61",
               "00 01 00 00 00 06 01 06 01 2C 07 D0", "00 01 00 00 00 03 01 86 03"),
    "G14": Row("01 10 01 2C 00 01 02 01 63 F0 85", "01 10 01 2C 00 01 C1 FC",
               "00 01 00 00 00 09 01 10 01 2C 00 01 02 01 63", "00 01 00 00 00 06 01 10 01 2C 00 01"),
    "G15": Row("01 06 00 2D 00 01 D8 C3", None, None, None),
    "G16": Row("02 03 00 64 00 01 C5 E6", None, "00 01 00 00 00 06 02 03 00 64 00 01", None),
    "A1": Row("01 03 00 6B 00 03 74 17", "01 03 06 02 2B 00 00 00 64 05 7A",
              "00 01 00 00 00 06 01 03 00 6B 00 03", "00 01 00 00 00 09 01 03 06 02 2B 00 00 00 64"),
    "A2": Row("01 06 00 01 00 03 98 0B", "01 06 00 01 00 03 98 0B",
              "00 01 00 00 00 06 01 06 00 01 00 03", "00 01 00 00 00 06 01 06 00 01 00 03"),
    "A3": Row("01 03 00 00 00 01 84 0A", "01 03 02 03 DC B9 2D",
              "00 01 00 00 00 06 01 03 00 00 00 01", "00 01 00 00 00 05 01 03 02 03 DC"),
    "A4": Row("09 06 00 07 00 C8 38 D5", "09 06 00 07 00 C8 38 D5",
              "00 01 00 00 00 06 09 06 00 07 00 C8", "00 01 00 00 00 06 09 06 00 07 00 C8"),
    "A5": Row("01 06 00 07 2E E0 24 23", "01 86 03 02 61",
              "00 01 00 00 00 06 01 06 00 07 2E E0", "00 01 00 00 00 03 01 86 03"),
}


def h(text: str) -> bytes:
    """The bytes of a hex literal of the table."""
    return bytes.fromhex(text)


def test_rows_are_the_rows_of_the_document():
    """The literals above and the table of docs/golden/watlow-f4.md are the same bytes."""
    lines = {m.group(1): m.group(0) for m in re.finditer(r"^\| ([GA]\d+) \|.*$", DOC.read_text(encoding="utf-8"), re.M)}
    assert set(lines) == set(ROWS)
    for key, row in ROWS.items():
        in_doc = [b for b in re.findall(r"`([^`]*)`", lines[key]) if re.fullmatch(r"[0-9A-F]{2}( [0-9A-F]{2})*", b)]
        assert in_doc == [x for x in (row.rtu_request, row.rtu_response, row.tcp_request, row.tcp_response) if x], key


# ---- (a) the driver against a fake peer -----------------------------------------------------------
class ExpectedSerialPeer:
    """A serial device (``sim://``) that expects exactly ``pairs[i][0]`` and then answers ``pairs[i][1]``."""

    def __init__(self, pairs: list[tuple[bytes, bytes | None]]):
        self.clock = VirtualClock()
        self.pairs = pairs
        self.pos = 0
        self.received: list[bytes] = []
        self._pending = bytearray()
        self._out = bytearray()

    def receive(self, data: bytes) -> None:
        self._pending += data
        if self.pos < len(self.pairs) and bytes(self._pending) == self.pairs[self.pos][0]:
            self.received.append(bytes(self._pending))
            self._out += self.pairs[self.pos][1] or b""
            self._pending.clear()
            self.pos += 1

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
        pass

    def discard_input(self) -> None:
        pass

    def check(self) -> None:
        assert bytes(self._pending) == b"", f"unexpected request bytes {bytes(self._pending).hex(' ')}"
        assert self.received == [p[0] for p in self.pairs]


class ExpectedTcpPeer:
    """A Modbus/TCP peer on 127.0.0.1 that expects exactly each request and answers each response."""

    def __init__(self, pairs: list[tuple[bytes, bytes | None]]):
        self.pairs = pairs
        self.received: list[bytes] = []
        self.error = ""
        self._listener = socket.create_server(("127.0.0.1", 0))
        self._listener.settimeout(PEER_WAIT_S)
        self.port = self._listener.getsockname()[1]
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        try:
            conn, _ = self._listener.accept()
        except OSError as exc:
            self.error = f"no connection: {exc}"
            return
        with conn:
            conn.settimeout(PEER_WAIT_S)
            for request, response in self.pairs:
                got = b""
                try:
                    while len(got) < len(request):
                        chunk = conn.recv(len(request) - len(got))
                        if not chunk:
                            break
                        got += chunk
                except OSError as exc:
                    self.error = f"while waiting for {request.hex(' ')}: {exc}"
                self.received.append(got)
                if got != request:
                    return
                if response is not None:
                    conn.sendall(response)

    def check(self) -> None:
        self._thread.join(PEER_WAIT_S)
        self._listener.close()
        assert not self.error, self.error
        assert self.received == [p[0] for p in self.pairs]


@contextmanager
def expected_protocol(transport: str, pairs: list[tuple[bytes, bytes | None]], unit: int = 1):
    """A :class:`WatlowF4` whose only peer expects ``pairs`` (request, response) on ``transport``;
    on exit, asserts that exactly the requests were sent and that the driver's traffic hook saw
    the same bytes."""
    seen: list[tuple[str, bytes]] = []
    query = f"?unit={unit}" if unit != 1 else ""
    if transport == "rtu":
        peer: Any = ExpectedSerialPeer(pairs)
        name = f"golden-f4-{next(_names)}"
        url = f"modbus-rtu://{registry.register(name, peer)}{query}"
    else:
        peer = ExpectedTcpPeer(pairs)
        name = ""
        url = f"modbus-tcp://127.0.0.1:{peer.port}{query}"
    driver = WatlowF4.open(url, timeout_s=TIMEOUT_S, check=False, on_traffic=lambda d, _n, raw: seen.append((d, raw)))
    try:
        yield driver
    finally:
        driver.close()
        if name:
            registry.unregister(name)
    peer.check()
    assert [raw for d, raw in seen if d == "command"] == [p[0] for p in pairs]
    assert [raw for d, raw in seen if d == "reply"] == [p[1] for p in pairs if p[1] is not None]


# row -> (what the driver does, the value it must return or (exception type, message pattern), unit)
DRIVER_ROWS: dict[str, tuple[Callable[[WatlowF4], Any], Any, int]] = {
    "G1": (lambda d: d.read_air_temp_c(), 25.6, 1),
    "G2": (lambda d: d.read_set_point_c(), -12.3, 1),
    "G3": (lambda d: d.write("set_point_1", 35.5, verify=False), None, 1),
    "G4": (lambda d: d.read("decimals_1"), 1, 1),
    "G5": (lambda d: d.read("temp_unit"), 1, 1),
    "G6": (lambda d: d.read_run_state(), 1, 1),
    "G7": (lambda d: d.read("output_a"), 100.0, 1),
    "G9": (lambda d: d.read_air_temp_c(), (ProtocolError, r"exception 1 \(illegal function\) reading register 100"), 1),
    "G10": (lambda d: d.read_raw(101), (ProtocolError, r"exception 2 \(illegal data address\) reading register 101"), 1),
    "G11": (lambda d: d.write_raw(100, 5), (ProtocolError, r"exception 2 \(illegal data address\) writing 5 to register 100"), 1),
    "G12": (lambda d: d.write_raw(45, 1), (ProtocolError, r"exception 2 \(illegal data address\) writing 1 to register 45"), 1),
    "G13": (lambda d: d.set_set_point_c(200.0), (ProtocolError, r"exception 3 \(illegal data value\) writing 2000 to register 300"), 1),
    "A1": (lambda d: d.read_raw(0x6B, 3), [555, 0, 100], 1),
    "A2": (lambda d: d.write_raw(1, 3), None, 1),
    "A3": (lambda d: d.read_raw(0), [988], 1),
    "A4": (lambda d: d.write_raw(7, 200), None, 9),
    "A5": (lambda d: d.write_raw(7, 12000), (ProtocolError, r"exception 3 \(illegal data value\) writing 12000 to register 7"), 1),
}


@pytest.mark.parametrize("transport", ["rtu", "tcp"])
@pytest.mark.parametrize("key", sorted(DRIVER_ROWS))
def test_driver_sends_and_decodes_the_golden_exchange(key: str, transport: str):
    action, expected, unit = DRIVER_ROWS[key]
    row = ROWS[key]
    req, resp = (row.rtu_request, row.rtu_response) if transport == "rtu" else (row.tcp_request, row.tcp_response)
    with expected_protocol(transport, [(h(req), h(resp))], unit=unit) as driver:
        if isinstance(expected, tuple):
            with pytest.raises(expected[0], match=expected[1]):
                action(driver)
        else:
            value = action(driver)
            if isinstance(expected, float):
                assert value == pytest.approx(expected, abs=1e-9)
            else:
                assert value == expected


# ---- (b) the simulators against the raw requests --------------------------------------------------
def _state_default(clock, chamber, sim) -> None:
    pass


# row -> (simulator state before the request, check of the chamber after it)
SIM_ROWS: dict[str, tuple[Callable[..., None], Callable[[Chamber], bool]]] = {
    "G1": (_state_default, lambda c: True),
    "G2": (lambda clock, chamber, sim: chamber.command_set_point(clock.now(), -12.3), lambda c: c.set_point_c == -12.3),
    "G3": (_state_default, lambda c: c.set_point_c == 35.5),
    "G4": (_state_default, lambda c: True),
    "G5": (_state_default, lambda c: True),
    "G6": (_state_default, lambda c: True),
    "G7": (lambda clock, chamber, sim: (chamber.command_set_point(clock.now(), 60.0), clock.sleep(1.0)), lambda c: True),
    "G8": (_state_default, lambda c: True),
    "G9": (lambda clock, chamber, sim: sim.inject("exception", code=1), lambda c: True),
    "G10": (_state_default, lambda c: True),
    "G11": (_state_default, lambda c: True),
    "G12": (_state_default, lambda c: True),
    "G13": (_state_default, lambda c: c.set_point_c == AMBIENT_C),
    "G14": (_state_default, lambda c: c.set_point_c == 35.5),
    "G15": (_state_default, lambda c: True),
    "G16": (_state_default, lambda c: True),
}


def _chamber() -> Chamber:
    return Chamber(ChamberParams(), ambient_temp_c=AMBIENT_C)


def _tcp_exchange(port: int, request: bytes) -> bytes:
    """Send ``request`` raw and return the answer ADU (MBAP length field read), b"" if none comes."""
    with socket.create_connection(("127.0.0.1", port), timeout=NO_ANSWER_S) as s:
        s.sendall(request)
        buf = b""
        try:
            while len(buf) < 6 or len(buf) < 6 + int.from_bytes(buf[4:6], "big"):
                chunk = s.recv(256)
                if not chunk:
                    break
                buf += chunk
        except TimeoutError:
            pass
        return buf


@pytest.mark.parametrize("key", sorted(SIM_ROWS))
def test_rtu_simulator_answers_the_golden_bytes(key: str):
    setup, after = SIM_ROWS[key]
    row = ROWS[key]
    clock, chamber = VirtualClock(), _chamber()
    sim = WatlowF4RtuSim(clock, chamber)
    setup(clock, chamber, sim)
    name = f"golden-f4-sim-{next(_names)}"
    port = serial.serial_for_url(registry.register(name, sim), baudrate=9600, timeout=NO_ANSWER_S)
    try:
        port.write(h(row.rtu_request))
        answer = port.read(256)  # everything the simulator sends within the timeout (virtual time)
    finally:
        port.close()
        registry.unregister(name)
    assert answer == (h(row.rtu_response) if row.rtu_response else b""), answer.hex(" ")
    assert after(chamber)


@pytest.mark.parametrize("key", sorted(k for k in SIM_ROWS if ROWS[k].tcp_request))
def test_tcp_simulator_answers_the_golden_bytes(key: str):
    setup, after = SIM_ROWS[key]
    row = ROWS[key]
    clock, chamber = VirtualClock(), _chamber()
    with WatlowF4Server(clock, chamber) as sim:
        setup(clock, chamber, sim)
        answer = _tcp_exchange(sim.port, h(row.tcp_request))
    assert answer == (h(row.tcp_response) if row.tcp_response else b""), answer.hex(" ")
    assert after(chamber)


def test_rtu_simulator_takes_a_frame_split_across_writes_and_drops_it_after_a_gap():
    """SL §2.5.1.1: bytes of one frame may come in pieces; silence > 3.5 characters ends a frame."""
    row = ROWS["G1"]
    clock = VirtualClock()
    sim = WatlowF4RtuSim(clock, _chamber())
    req = h(row.rtu_request)
    sim.receive(req[:3])
    sim.receive(req[3:])
    assert sim.take_output(clock.now()) == h(row.rtu_response)
    sim.receive(req[:3])
    clock.sleep(0.01)  # 10 ms > 3.5 characters at 9600 bit/s (4 ms)
    sim.receive(req[3:])
    assert sim.take_output(clock.now()) == b""
    clock.sleep(0.01)  # the master keeps 3.5 characters of silence before its next frame
    sim.receive(req)
    assert sim.take_output(clock.now()) == h(row.rtu_response)
