"""Golden exchanges of the Pfeiffer TPG 26x gauge controller (docs/golden/tpg26x.md).

The byte strings are transcribed from the documents cited in docs/golden/tpg26x.md (Pfeiffer
BG 5195 BEN/A "TPG 261" operating instructions pp. 65-75, INFICON VGC401 manual p. 63 for ERR,
PyExpLabSys for UNI/TID); nothing is produced by the project's encoders and no constant of the
driver or simulator is imported. Control characters are written out: ACK 0x06, NAK 0x15,
ENQ 0x05, ETX 0x03, CR 0x0D, LF 0x0A.

(a) driver: ``drivers.tpg261.Tpg261`` against a scripted port that expects exactly the request
    bytes and answers exactly the response bytes (tests/golden/expected_exchange.py);
(b) simulator: ``bench.sim.tpg261.Tpg261Sim`` reached raw through ``sim://``, with the chamber
    state known (atmosphere at start) or faults injected.
"""

from __future__ import annotations

import itertools
import re
from contextlib import contextmanager
from pathlib import Path

import pytest
import serial

from bench.clock import VirtualClock
from bench.sim import registry
from bench.sim.chamber import Chamber, ChamberParams
from bench.sim.tpg261 import Tpg261Sim
from drivers.errors import DeviceFault, InstrumentTimeout, ProtocolError
from drivers.tpg261 import Tpg261
from tests.golden.doc_table import exchange_rows
from tests.golden.expected_exchange import expected_exchange

DOC = Path(__file__).resolve().parents[2] / "docs" / "golden" / "tpg26x.md"
TIMEOUT_S = 0.3  # driver and raw-port read timeout (s; virtual time for the simulator)
MBAR_TO_TORR = 0.750061683  # 1 mbar = 0.750062 Torr (exact: 76000/101325)

# ---- rows (docs/golden/tpg26x.md) ------------------------------------------------------------
ACK_LINE = b"\x06\r\n"  # T-ACK: <ACK><CR><LF>, p. 67-68
NAK_LINE = b"\x15\r\n"  # T-NAK: <NAK><CR><LF>, p. 68
ENQ = b"\x05"  # p. 67
ETX = b"\x03"  # p. 67
POWER_UP_LINE = b"0,7.6000E+02,5,2.0000E-02\r\n"  # T1: x,sx.xxxxEsxx,y,sy.yyyyEsyy<CR><LF>, p. 65, 72
UNI_TORR, UNI_MBAR, UNI_BAD, UNI = b"UNI,1\r\n", b"UNI,0\r\n", b"UNI,7\r\n", b"UNI\r\n"  # T3, T12, T20, T4
TORR, MBAR = b"1\r\n", b"0\r\n"  # the unit codes (PyExpLabSys): T3/T4, T12
PR1, PR2 = b"PR1\r\n", b"PR2\r\n"  # T5 (p. 71); PR2 in the simulator for T10
PR1_SPACED, PR_ETX_1 = b"P R 1\r\n", b"PR\x031\r\n"  # T18, T19 (p. 67)
XYZ, ERR = b"XYZ\r\n", b"ERR\r\n"  # T13
ERR_NONE, ERR_SYNTAX, ERR_PARAMETER = b"0000\r\n", b"0001\r\n", b"0010\r\n"  # the ERROR word, VGC401 p. 63: T16, T13, T20
TID, TID_PKR = b"TID\r\n", b"PKR,noSEn\r\n"  # T14
PNR, PNR_FIRMWARE = b"PNR\r\n", b"302-510-A\r\n"  # T15
RES, RES_NONE = b"RES\r\n", b"0\r\n"  # T17 (p. 75)
PR1_MBAR_1000 = b"0,1.0000E+03\r\n"  # T12
OPEN_SCRIPT = [  # T2-T4: what the driver does at open
    (ETX, None),  # T2 <ETX>: clears the input buffer, ends the power-up stream (p. 65, 67)
    (UNI_TORR, ACK_LINE), (ENQ, TORR),  # T3 set Torr
    (UNI, ACK_LINE), (ENQ, TORR),  # T4 read back
]
# PR1 answers x,sx.xxxxEsxx (p. 71), one per status x, and what the driver must make of them
PR1_ANSWERS = [
    ("T5", b"0,1.0000E-03\r\n", 1.0e-3, 0),  # measurement data okay
    ("T6", b"1,3.8000E-09\r\n", 3.8e-9, 1),  # underrange: the range end, pressure at most that
]
PR1_FAULTS = [
    ("T7", b"2,1.1000E+03\r\n", "overrange"),
    ("T8", b"3,0.0000E+00\r\n", "sensor error"),
    ("T9", b"4,0.0000E+00\r\n", "sensor off"),
    ("T10", b"5,2.0000E-2\r\n", "no sensor"),  # literal of p. 71: "(output: 5,2.0000E-2 [mbar])"
    ("T11", b"6,0.0000E+00\r\n", "identification error"),
]
ROWS: dict[str, tuple[list[bytes], list[bytes]]] = {  # row: (host -> unit, unit -> host), each line once, in order
    "T1": ([], [POWER_UP_LINE]),
    "T2": ([ETX], []),
    "T3": ([UNI_TORR, ENQ], [ACK_LINE, TORR]),
    "T4": ([UNI, ENQ], [ACK_LINE, TORR]),
    **{row: ([PR1, ENQ], [ACK_LINE, answer]) for row, answer, _, _ in PR1_ANSWERS},
    **{row: ([PR1, ENQ], [answer]) for row, answer, _ in PR1_FAULTS},
    "T12": ([UNI_MBAR, ENQ, UNI, PR1], [ACK_LINE, MBAR, PR1_MBAR_1000]),
    "T13": ([XYZ, ERR, ENQ], [NAK_LINE, ACK_LINE, ERR_SYNTAX, ERR_NONE]),
    "T14": ([TID, ENQ], [ACK_LINE, TID_PKR]),
    "T15": ([PNR, ENQ], [ACK_LINE, PNR_FIRMWARE]),
    "T16": ([ENQ], [ERR_NONE]),
    "T17": ([RES, ENQ], [ACK_LINE, RES_NONE]),
    "T18": ([PR1_SPACED], [ACK_LINE]),
    "T19": ([PR_ETX_1], [NAK_LINE]),
    "T20": ([UNI_BAD, ERR, ENQ], [NAK_LINE, ACK_LINE, ERR_PARAMETER]),
}
# regexes transcribed from the formats of p. 71-72 (s: sign; PKR is logarithmic: decimals 3, 4 are 0)
PR_RE = re.compile(rb"^([0-6]),([+ -]?)([0-9]\.[0-9]{2}00E[+-][0-9]{2})\r\n$")
PRX_RE = re.compile(rb"^[0-6],[+ -]?[0-9]\.[0-9]{4}E[+-][0-9]{2},[0-6],[+ -]?[0-9]\.[0-9]{4}E[+-][0-9]{2}\r\n$")


def pr1(answer: bytes) -> list[tuple[bytes, bytes | None]]:
    """PR1 request, ACK, ENQ, ``answer`` (p. 67-68, 71)."""
    return [(PR1, ACK_LINE), (ENQ, answer)]


def test_rows_are_the_rows_of_the_document():
    """The literals above and the table of docs/golden/tpg26x.md are the same bytes, row by row."""
    assert exchange_rows(DOC, r"T\d+") == ROWS
    # the PR1 answer format the simulator tests match: the document's expression, with groups added
    (doc_format,) = re.findall(r"`PR1` → `([^`]+)`", DOC.read_text(encoding="utf-8"))
    assert PR_RE.pattern.replace(b"(", b"").replace(b")", b"") == doc_format.replace("<CR><LF>", r"\r\n").encode()


# ---- (a) driver ------------------------------------------------------------------------------
@contextmanager
def opened_gauge(monkeypatch, script, pushed: bytes = POWER_UP_LINE):
    """The driver opened on a scripted port: power-up stream T1 waiting, open sequence T2-T4,
    then ``script``; the whole script must be played."""
    with expected_exchange(OPEN_SCRIPT + list(script), pushed=pushed) as port:
        monkeypatch.setattr("drivers.tpg261.open_serial", lambda url, baudrate, timeout_s: port)
        yield Tpg261.open("golden://tpg", timeout_s=TIMEOUT_S)


def test_open_ends_the_power_up_stream_and_sets_torr(monkeypatch):
    with opened_gauge(monkeypatch, []) as gauge:
        assert gauge.unit == 1


@pytest.mark.parametrize("row, answer, torr, status", PR1_ANSWERS, ids=[r[0] for r in PR1_ANSWERS])
def test_driver_decodes_pr1(monkeypatch, row, answer, torr, status):
    with opened_gauge(monkeypatch, pr1(answer)) as gauge:
        reading = gauge.read_pressure()
    assert reading.status == status
    assert reading.torr == pytest.approx(torr, rel=1e-12)


@pytest.mark.parametrize("row, answer, meaning", PR1_FAULTS, ids=[r[0] for r in PR1_FAULTS])
def test_driver_turns_gauge_status_into_device_fault(monkeypatch, row, answer, meaning):
    with opened_gauge(monkeypatch, pr1(answer)) as gauge:
        with pytest.raises(DeviceFault, match=meaning):
            gauge.read_pressure_torr()


def test_driver_converts_mbar_to_torr(monkeypatch):
    """T12: in mbar (UNI,0), 1.0000E+03 mbar is 750.06 Torr."""
    script = [(UNI_MBAR, ACK_LINE), (ENQ, MBAR), (UNI, ACK_LINE), (ENQ, MBAR), *pr1(PR1_MBAR_1000)]
    with opened_gauge(monkeypatch, script) as gauge:
        gauge.set_units(0)
        assert gauge.read_pressure_torr() == pytest.approx(1000.0 * MBAR_TO_TORR, rel=1e-9)


def test_driver_nak_is_protocol_error_with_the_error_word(monkeypatch):
    """T13: unknown mnemonic -> NAK (p. 68); ERR -> 0001 syntax error (VGC401 p. 63)."""
    script = [(XYZ, NAK_LINE), (ERR, ACK_LINE), (ENQ, ERR_SYNTAX)]
    with opened_gauge(monkeypatch, script) as gauge:
        with pytest.raises(ProtocolError, match=r"NAK.*'XYZ'.*0001"):
            gauge.command("XYZ")


def test_driver_identifies_gauge_and_firmware(monkeypatch):
    """T15 PNR -> the program number; T14 TID -> PKR,noSEn."""
    script = [(PNR, ACK_LINE), (ENQ, PNR_FIRMWARE), (TID, ACK_LINE), (ENQ, TID_PKR)]
    with opened_gauge(monkeypatch, script) as gauge:
        ident = gauge.identify()
    assert ident["firmware"] == "302-510-A" and ident["gauges"] == "PKR,noSEn"


def test_driver_silent_gauge_is_timeout(monkeypatch):
    """No ACK at all (gauge off, cable out): InstrumentTimeout, not a hang."""
    with opened_gauge(monkeypatch, [(PR1, None)]) as gauge:
        with pytest.raises(InstrumentTimeout):
            gauge.read_pressure_torr()


# ---- (b) simulator -------------------------------------------------------------------------------
_names = itertools.count()


@pytest.fixture
def sim():
    """A TPG 261 simulator on a virtual clock, chamber at atmosphere (760 Torr), and a raw port."""
    clock = VirtualClock()
    chamber = Chamber(ChamberParams())
    dev = Tpg261Sim(clock, chamber)
    name = f"golden.tpg.{next(_names)}"
    url = registry.register(name, dev)
    port = serial.serial_for_url(url, baudrate=9600, timeout=TIMEOUT_S)
    yield dev, clock, port
    port.close()
    registry.unregister(name)


def line(port) -> bytes:
    """One answer line (up to LF) or what came before the timeout."""
    return port.read_until(b"\n")


def ask(port, mnemonic: bytes) -> bytes:
    """``mnemonic`` must be acknowledged (p. 67); return the data line after ENQ."""
    port.write(mnemonic)
    assert line(port) == ACK_LINE
    port.write(ENQ)
    return line(port)


def test_sim_streams_both_channels_after_power_up_until_the_first_character(sim):
    dev, clock, port = sim
    clock.sleep(2.5)
    lines = [line(port), line(port)]
    assert all(PRX_RE.match(x) for x in lines), lines  # T1, p. 65 and 72
    port.write(ETX)  # T2: the first character stops the stream
    clock.sleep(3.0)
    assert port.read(64) == b""


def test_sim_pr1_at_atmosphere(sim):
    """T5 form: ACK, then x,sx.xxxxEsxx with the PKR's zero 3rd/4th decimals; 760 Torr."""
    dev, clock, port = sim
    m = PR_RE.match(ask(port, PR1))
    assert m and m[1] == b"0"
    assert float(m[3]) == pytest.approx(760.0, rel=5e-3)
    port.write(ENQ)  # ENQ again reads out again (p. 67)
    assert PR_RE.match(line(port))


def test_sim_pr1_in_mbar(sim):
    dev, clock, port = sim
    port.write(UNI_MBAR)
    assert line(port) == ACK_LINE
    m = PR_RE.match(ask(port, PR1))
    assert m and float(m[3]) == pytest.approx(760.0 / MBAR_TO_TORR, rel=5e-3)
    assert ask(port, UNI) == MBAR


@pytest.mark.parametrize("status", [b"3", b"4", b"5", b"6"])
def test_sim_pr1_status_codes(sim, status):
    """T8-T11: status digits 3..6 (p. 71)."""
    dev, clock, port = sim
    dev.inject("sensor_error", status=int(status))
    m = PR_RE.match(ask(port, PR1))
    assert m and m[1] == status


def test_sim_underrange(sim):
    """T6: below the PKR's range the status is 1."""
    dev, clock, port = sim
    dev.inject("stuck", torr=1e-13)
    m = PR_RE.match(ask(port, PR1))
    assert m and m[1] == b"1"


def test_sim_pr2_no_sensor(sim):
    """T10: the TPG 261 has no gauge 2: status 5, value 2.0000E-2 (p. 71)."""
    dev, clock, port = sim
    answer = ask(port, PR2)
    assert answer.startswith(b"5,") and float(answer[2:]) == pytest.approx(2.0e-2)


def test_sim_nak_and_error_word(sim):
    """T13 unknown mnemonic -> NAK, ERR -> 0001, read-out clears it; T20 bad parameter -> 0010."""
    dev, clock, port = sim
    port.write(XYZ)
    assert line(port) == NAK_LINE
    assert ask(port, ERR) == ERR_SYNTAX
    port.write(ENQ)
    assert line(port) == ERR_NONE  # "The ERROR word is cancelled when read out" (VGC401 p. 63)
    port.write(UNI_BAD)
    assert line(port) == NAK_LINE
    assert ask(port, ERR) == ERR_PARAMETER


def test_sim_enq_without_request_sends_the_error_word(sim):
    """T16: "If <ENQ> is received without a valid request, the ERROR word is transmitted" (p. 67)."""
    dev, clock, port = sim
    port.write(ENQ)
    assert line(port) == ERR_NONE


def test_sim_etx_clears_input_and_spaces_are_ignored(sim):
    """T18/T19 (p. 67): ``PR<ETX>1`` leaves the line ``1`` (NAK); ``P R 1`` is PR1."""
    dev, clock, port = sim
    port.write(PR_ETX_1)
    assert line(port) == NAK_LINE
    port.write(PR1_SPACED)
    assert line(port) == ACK_LINE


def test_sim_identification_and_reset_list(sim):
    """T14 TID; T17 RES -> 0 (no error, p. 75)."""
    dev, clock, port = sim
    assert ask(port, TID) == TID_PKR
    assert ask(port, RES) == RES_NONE
