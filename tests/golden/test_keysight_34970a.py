"""Golden exchanges of the Keysight (Agilent/HP) 34970A/34972A data logger (docs/golden/keysight-34970a.md).

The byte strings are transcribed from the documents cited in docs/golden/keysight-34970a.md
(34970A/34972A User's Guide, SCPI-1999 / IEEE 488.2 error-queue form, and the secondary sources
named there); nothing is produced by the project's encoders and no driver or simulator constant
is imported. Line ends are written out: RS-232 answers end with CR LF, LAN answers with LF.

(a) driver: ``drivers.thermocouple_reader.ThermocoupleReader`` against a scripted port that
    expects exactly the request bytes and answers exactly the response bytes;
(b) simulator: ``bench.sim.thermocouple_reader.ThermocoupleReaderSim`` (ideal logger: readings
    equal the true temperature) reached raw through ``sim://``, chamber at the 20 °C room.
"""

from __future__ import annotations

import itertools
import re
from pathlib import Path

import pytest
import serial

from bench.clock import VirtualClock
from bench.sim import registry
from bench.sim.thermocouple_reader import ThermocoupleReaderSim
from bench.sim.world import World, WorldParams
from drivers.errors import DeviceFault, InstrumentTimeout
from drivers.thermocouple_reader import ThermocoupleReader
from tests.golden.doc_table import exchange_rows
from tests.golden.expected_exchange import expected_exchange

DOC = Path(__file__).resolve().parents[2] / "docs" / "golden" / "keysight-34970a.md"
TIMEOUT_S = 0.3  # driver and raw-port read timeout (s; virtual time for the simulator)
ROOM_C = 20.0  # world ambient: chamber, mount and the logger's terminals (°C)

# ---- rows (docs/golden/keysight-34970a.md) -------------------------------------------------------
IDN_34970A = (b"*IDN?\n", b"HEWLETT-PACKARD,34970A,0,13-2-2\r\n")  # K1, RS-232
IDN_34972A = (b"*IDN?\n", b"Agilent Technologies,34972A,MY49018071,1.16-1.12-02-02\n")  # K2, LAN
NO_ERROR = (b"SYST:ERR?\n", b'+0,"No error"\r\n')  # K4
CONFIGURE_101_103_K = [  # K3: type K on 101..103, deg C, internal reference, open-TC check, scan list
    (b"*CLS\n", None),
    (b"CONF:TEMP TC,K,(@101,102,103)\n", None),
    (b"UNIT:TEMP C,(@101,102,103)\n", None),
    (b"SENS:TEMP:TRAN:TC:RJUN:TYPE INT,(@101,102,103)\n", None),
    (b"SENS:TEMP:TRAN:TC:CHEC ON,(@101,102,103)\n", None),
    (b"ROUT:SCAN (@101,102,103)\n", None),
]
READ_3 = (b"READ?\n", b"+2.12345678E+01,+9.90000000E+37,-1.25000000E+00\r\n")  # K6: 2nd channel open
READ_NEG_OVERLOAD = (b"READ?\n", b"+2.12345678E+01,-9.90000000E+37,+2.20000000E+01\r\n")  # K7
UNDEFINED_HEADER = (b"SYST:ERR?\n", b'-113,"Undefined header"\r\n')  # K5
RJUN_101 = (b"SENS:TEMP:TRAN:TC:RJUN? (@101)\n", b"+2.35000000E+01\r\n")  # K9
INIT, FETCH = b"INIT\n", b"FETC?\n"  # K8
ROWS: dict[str, tuple[list[bytes], list[bytes]]] = {  # row: (host -> logger, logger -> host), each line once, in order
    "K1": ([IDN_34970A[0]], [IDN_34970A[1]]),
    "K2": ([IDN_34972A[0]], [IDN_34972A[1]]),
    "K3": ([request for request, _ in CONFIGURE_101_103_K], []),
    "K4": ([NO_ERROR[0]], [NO_ERROR[1]]),
    "K5": ([UNDEFINED_HEADER[0]], [UNDEFINED_HEADER[1], NO_ERROR[1]]),
    "K6": ([READ_3[0]], [READ_3[1]]),
    "K7": ([READ_NEG_OVERLOAD[0]], [READ_NEG_OVERLOAD[1]]),
    "K8": ([INIT, FETCH], []),  # the answer is a format (READ_RE), not bytes
    "K9": ([RJUN_101[0]], [RJUN_101[1]]),
}
# reply format SD.DDDDDDDDESDD (S sign, D digit), comma-separated in scan order; RS-232 ends CR LF
READING = rb"[+-][0-9]\.[0-9]{8}E[+-][0-9]{2}"
READ_RE = re.compile(rb"^(" + READING + rb")((?:," + READING + rb")*)\r\n$")
IDN_RE = re.compile(rb"^[^,\r\n]+,34970A,[^,\r\n]+,[^,\r\n]+\r\n$")


def _format_regex(form: str) -> bytes:
    """A reading format as the 34401A guide writes it (S sign, D digit, the rest literal) as a regular
    expression, repeats counted: ``SD.DDE`` -> ``[+-][0-9]\\.[0-9]{2}E``."""
    tokens = [{"S": "[+-]", "D": "[0-9]"}.get(c, re.escape(c)) for c in form]
    groups = [(tok, len(list(run))) for tok, run in itertools.groupby(tokens)]
    return "".join(tok if n == 1 else f"{tok}{{{n}}}" for tok, n in groups).encode()


def test_rows_are_the_rows_of_the_document():
    """The literals above and the table of docs/golden/keysight-34970a.md are the same bytes, row by
    row; the reading format the simulator tests match is the document's SD.DDDDDDDDESDD."""
    assert exchange_rows(DOC, r"K\d+") == ROWS
    forms = set(re.findall(r"\b[SD.E]*D\.D+E[SD]+\b", DOC.read_text(encoding="utf-8")))
    assert {_format_regex(form) for form in forms} == {READING}, forms


# ---- (a) driver ------------------------------------------------------------------------------
def test_driver_identifies_a_34970a_on_rs232():
    with expected_exchange([IDN_34970A], baudrate=57600) as port:
        ident = ThermocoupleReader(port, timeout_s=TIMEOUT_S).identify()
    assert ident == {"vendor": "HEWLETT-PACKARD", "model": "34970A", "serial": "0", "firmware": "13-2-2"}


def test_driver_identifies_a_34972a_on_lan():
    with expected_exchange([IDN_34972A]) as port:
        ident = ThermocoupleReader(port, timeout_s=TIMEOUT_S).identify()
    assert ident["model"] == "34972A" and ident["serial"] == "MY49018071"


def test_driver_configures_and_reads_a_scan():
    """K3, K4, K6: configure 101..103 for type K, no error queued; one scan with an open TC."""
    with expected_exchange(CONFIGURE_101_103_K + [NO_ERROR, READ_3], baudrate=57600) as port:
        logger = ThermocoupleReader(port, timeout_s=TIMEOUT_S)
        logger.configure([101, 102, 103], "K")
        scan = logger.read()
    assert scan.temps_c[101] == pytest.approx(21.2345678, abs=1e-9)  # degC
    assert scan.temps_c[102] is None and scan.open_channels == [102]  # +9.9E+37: open thermocouple
    assert scan.temps_c[103] == pytest.approx(-1.25, abs=1e-9)


def test_driver_negative_overload_is_not_a_temperature():
    """K7: -9.90000000E+37 is an overload too, never a temperature of -9.9e37 degC."""
    with expected_exchange(CONFIGURE_101_103_K + [NO_ERROR, READ_NEG_OVERLOAD], baudrate=57600) as port:
        logger = ThermocoupleReader(port, timeout_s=TIMEOUT_S)
        logger.configure([101, 102, 103], "K")
        scan = logger.read()
    assert scan.temps_c[102] is None and scan.temps_c[103] == pytest.approx(22.0)


def test_driver_reports_the_queued_error():
    """K5: an error in the queue after configuring is a DeviceFault quoting it; the queue is drained."""
    with expected_exchange(CONFIGURE_101_103_K + [UNDEFINED_HEADER, NO_ERROR], baudrate=57600) as port:
        logger = ThermocoupleReader(port, timeout_s=TIMEOUT_S)
        with pytest.raises(DeviceFault, match='-113,"Undefined header"'):
            logger.configure([101, 102, 103], "K")


def test_driver_reads_the_reference_junction():
    with expected_exchange([RJUN_101], baudrate=57600) as port:
        assert ThermocoupleReader(port, timeout_s=TIMEOUT_S).reference_junction_c(101) == pytest.approx(23.5)


def test_driver_silent_logger_is_timeout():
    with expected_exchange([(b"*IDN?\n", None)], baudrate=57600) as port:
        with pytest.raises(InstrumentTimeout):
            ThermocoupleReader(port, timeout_s=TIMEOUT_S).identify()


# ---- (b) simulator -------------------------------------------------------------------------------
_names = itertools.count()


@pytest.fixture
def sim():
    """An ideal 34970A simulator on a virtual clock in a 20 degC world, and a raw port to it."""
    clock = VirtualClock()
    dev = ThermocoupleReaderSim(clock, World(WorldParams(ambient_temp_c=ROOM_C)), serial_number="SIM-0003")
    name = f"golden.34970a.{next(_names)}"
    url = registry.register(name, dev)
    port = serial.serial_for_url(url, baudrate=57600, timeout=TIMEOUT_S)
    yield dev, port
    port.close()
    registry.unregister(name)


def configure(port) -> None:
    for request, _ in CONFIGURE_101_103_K:
        port.write(request)
    port.write(NO_ERROR[0])
    assert port.read_until(b"\n") == NO_ERROR[1]


def test_sim_identifies_as_a_34970a(sim):
    dev, port = sim
    port.write(IDN_34970A[0])
    assert IDN_RE.match(port.read_until(b"\n"))


def test_sim_scan_values_and_format(sim):
    """K3/K4/K6: after configuring, READ? gives 3 readings in SD.DDDDDDDDESDD, at the 20 degC mount."""
    dev, port = sim
    configure(port)
    port.write(READ_3[0])
    answer = port.read_until(b"\n")
    m = READ_RE.match(answer)
    assert m, answer
    values = [float(v) for v in answer.strip().split(b",")]
    assert values == pytest.approx([ROOM_C] * 3, abs=1e-6)


def test_sim_open_thermocouple_reads_the_overload_value(sim):
    """K6: open thermocouple with the check on reads exactly +9.90000000E+37."""
    dev, port = sim
    dev.inject("open", 102)
    configure(port)
    port.write(READ_3[0])
    answer = port.read_until(b"\n")
    assert READ_RE.match(answer) and answer.split(b",")[1] == b"+9.90000000E+37"


def test_sim_init_fetch(sim):
    """K8: INIT takes a scan into memory, FETC? returns it in the READ? format."""
    dev, port = sim
    configure(port)
    port.write(INIT)
    port.write(FETCH)
    answer = port.read_until(b"\n")
    assert READ_RE.match(answer) and float(answer.split(b",")[0]) == pytest.approx(ROOM_C, abs=1e-6)


def test_sim_error_queue(sim):
    """K5/K4: an unknown header queues -113,"Undefined header"; read out, the queue says +0,"No error"."""
    dev, port = sim
    port.write(b"MEAS:WARP?\n")
    port.write(UNDEFINED_HEADER[0])
    assert port.read_until(b"\n") == UNDEFINED_HEADER[1]
    port.write(NO_ERROR[0])
    assert port.read_until(b"\n") == NO_ERROR[1]


def test_sim_reference_junction_is_the_room(sim):
    """K9: the ideal logger's reference junction reads the 20 degC room, in the reading format."""
    dev, port = sim
    port.write(RJUN_101[0])
    answer = port.read_until(b"\n")
    assert re.fullmatch(READING + rb"\r\n", answer) and float(answer) == pytest.approx(ROOM_C, abs=1e-9)


def test_sim_lan_interface_ends_answers_with_lf(sim):
    """K2: the same instrument on its LAN socket answers with LF only (and the serial side keeps
    its own pending answer)."""
    dev, port = sim
    port.write(IDN_34970A[0])  # RS-232 answer left unread
    lan = dev.exchange(b"*IDN?\n", b"\n")
    assert lan.endswith(b"\n") and not lan.endswith(b"\r\n") and b",34970A," in lan
    assert IDN_RE.match(port.read_until(b"\n"))
