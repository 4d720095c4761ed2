"""Golden exchanges of GRBL 1.1h as the firmware ships (docs/golden/grbl.md).

The literals below are the table's bytes (checked: :func:`test_rows_are_the_rows_of_the_document`)
and each exchange is one the real firmware had (:func:`test_rows_are_exchanges_of_the_firmware`,
in docs/golden/grbl-transcripts/). Nothing is produced by the project's encoders and no driver or
simulator constant is imported for the expected bytes.

(a) driver: ``drivers.stepper_bench`` / ``drivers.grbl`` against a scripted port;
(b) simulator: ``bench.sim.stepper_bench.StepperBenchSim`` reached raw through ``sim://``.
"""

from __future__ import annotations

import itertools
import re
from pathlib import Path

import pytest
import serial

from bench.clock import VirtualClock
from bench.config import load_config
from bench.sim import registry
from bench.sim.factory import build_devices
from drivers import grbl
from drivers.errors import DeviceFault, ProtocolError
from drivers.stepper_bench import StepperBench
from tests.conftest import ROOT
from tests.golden.expected_exchange import expected_exchange
from tests.golden.grbl_transcript import all_transcripts

DOC = Path(__file__).resolve().parents[2] / "docs" / "golden" / "grbl.md"
TIMEOUT_S = 0.3
MSG_UNLOCK = b"[MSG:'$H'|'$X' to unlock]\r\n"
WELCOME = b"\r\nGrbl 1.1h ['$' for help]\r\n"
LONG = b"$J=G91G21X" + b"1" * 90 + b"F60\n"

ROWS: dict[str, tuple[bytes, bytes]] = {
    "G1": (b"\n", b"ok\r\n"),
    "G2": (b"$I\n", b"[VER:1.1h.20190830:STEPPER_BENCH:EC2-01]\r\n[OPT:V,15,128]\r\nok\r\n"),
    "G3": (b"$I\n", b"[VER:1.1h.20190830:]\r\n[OPT:V,15,128]\r\nok\r\n"),
    "G4": (b"?", b"<Idle|MPos:0.000,0.000,0.000|FS:0,0|Pn:PXYZRHS|WCO:0.000,0.000,0.000>\r\n"),
    "G5": (b"$J=G91G21X10.000F60.000\n", b"ok\r\n"),
    "G6": (b"?", b"<Jog|MPos:0.182,0.000,0.000|FS:60,0|Pn:PXYZRHS>\r\n"),
    "G7": (b"\x85", b""),
    "G8": (b"!", b""),
    "G9": (b"~", b""),
    "G10": (b"\x18", WELCOME),
    "G11": (b"\x18", b"ALARM:3\r\n" + WELCOME + MSG_UNLOCK),
    "G12": (b"$X\n", b"[MSG:Caution: Unlocked]\r\nok\r\n"),
    "G13": (b"$WARP\n", b"error:2\r\n"),
    "G14": (b"$RUN\n", b"error:3\r\n"),
    "G15": (b"$J=G91G21X1.000\n", b"error:22\r\n"),
    "G16": (b"$J=G91G1X1.000F60.000\n", b"error:16\r\n"),
    "G17": (LONG, b"error:11\r\n"),
    "G18": (b"$I\n", b"error:8\r\n"),
    "G19": (b"G1X1F60\n", b"error:9\r\n"),
    "G20": (b"$J=G91G21X1.000F60.000\n", b"error:8\r\n"),
    "G21": (b"", b"error:7\r\n$0=10\r\n"),
    "G22": (b"\r\n", b"ok\r\nok\r\n"),
}


def _doc_bytes(text: str) -> bytes:
    """A table cell's literal: ``<CR>``/``<LF>`` and a lone ``0x18`` as bytes, ``\\|`` as ``|``."""
    if re.fullmatch(r"0x[0-9A-F]{2}", text):
        return bytes([int(text, 16)])
    return text.replace("\\|", "|").replace("<CR>", "\r").replace("<LF>", "\n").encode("ascii")


def _doc_rows() -> dict[str, list[str]]:
    rows = {}
    for line in DOC.read_text(encoding="utf-8").splitlines():
        m = re.match(r"^\| (G\d+) \| [^|]+ \| (.*)$", line)
        if m:
            cells = re.split(r"(?<!\\)\|", m.group(2))
            rows[m.group(1)] = [re.findall(r"`([^`]*)`", c) for c in cells[:2]]
    return rows


def _doc_table(title: str) -> dict[int, tuple[str, str]]:
    text = DOC.read_text(encoding="utf-8").split(f"## {title}")[1].split("\n## ")[0]
    return {int(c): (m, d) for c, m, d in re.findall(r"^\| (\d+) \| (.+?) \| (.+?) \|$", text, re.M)}


def test_rows_are_the_rows_of_the_document():
    doc = _doc_rows()
    assert set(doc) == set(ROWS)
    for key, (request, answer) in ROWS.items():
        req_cells, ans_cells = doc[key]
        req = b"".join(_doc_bytes(t) for t in req_cells)
        assert req == request, key
        ans = b"".join(_doc_bytes(t) for t in ans_cells)
        assert answer.startswith(ans) or ans.startswith(answer) if key == "G21" else ans == answer, key


def test_error_and_alarm_tables_are_grbls():
    """The driver's tables are the document's (GRBL's doc/csv files, transcribed)."""
    assert _doc_table("GRBL 1.1 error codes") == grbl.ERRORS
    assert _doc_table("GRBL 1.1 alarm codes") == grbl.ALARMS


def _firmware_units():
    """(host unit, firmware bytes after it) of every transcript; and the power-up outputs."""
    from tests.golden.grbl_replay import exchanges

    units, boots = [], []
    for tr in all_transcripts():
        boot, exs = exchanges(tr)
        boots.append(boot)
        units += [(ex.host, ex.firmware) for ex in exs]
    return units, boots


def test_rows_are_exchanges_of_the_firmware():
    """Each row happened: its request was followed by its answer in a transcript of the firmware."""
    units, boots = _firmware_units()
    for key, (request, answer) in ROWS.items():
        if key == "G21":
            assert any(b.startswith(answer) and b.endswith(WELCOME) for b in boots), key
        elif key == "G11":
            assert any(h == request and f.replace(b"\r\n", b"\n") == answer.replace(b"\r\n", b"\n") for h, f in units), key
        else:
            assert any(h == request and f == answer for h, f in units), key


# ---- (a) the driver ----------------------------------------------------------------------------------
def test_driver_reads_the_bench_and_a_plain_grbl():
    with expected_exchange([ROWS["G2"]], baudrate=115200) as port:
        version, build, options = grbl.parse_build_info(grbl.GrblChannel(port, TIMEOUT_S, "b").transact("$I"))
    assert (version, build, options) == ("1.1h.20190830", "STEPPER_BENCH:EC2-01", "V,15,128")
    with expected_exchange([ROWS["G3"]], baudrate=115200) as port:
        assert grbl.parse_build_info(grbl.GrblChannel(port, TIMEOUT_S, "b").transact("$I"))[1] == ""


def test_driver_status_from_the_realtime_report():
    with expected_exchange([ROWS["G4"], ROWS["G6"]], baudrate=115200) as port:
        bench = StepperBench(port, timeout_s=TIMEOUT_S)
        assert bench.status() == {"state": "Idle", "angle_deg": 0.0, "position_deg": 0.0, "rate_dps": 0.0}
        bench._turning, bench._rate_dps, bench._queued_to = False, 1.0, 30.0
        s = bench.status()
    assert s["state"] == "Jog" and s["angle_deg"] == pytest.approx(0.182) and s["rate_dps"] == 1.0


@pytest.mark.parametrize("row, meaning", [("G13", "Bad number format"), ("G14", "Invalid statement"),
                                          ("G15", "Undefined feed rate"), ("G16", "Invalid jog command"),
                                          ("G17", "Line overflow"), ("G18", "Not idle"), ("G19", "G-code lock")])
def test_driver_errors_carry_grbls_meaning(row, meaning):
    request, answer = ROWS[row]
    with expected_exchange([(request, answer)], baudrate=115200) as port:
        with pytest.raises(ProtocolError, match=re.escape(f"{answer.strip().decode()} ({meaning}")):
            grbl.GrblChannel(port, TIMEOUT_S, "b").transact(request.decode().rstrip("\n"))


def test_driver_pushed_alarm_is_a_device_fault_and_stays_in_step():
    """G11's lines arriving before the answer to a line: DeviceFault naming ALARM:3, then in step."""
    with expected_exchange([(b"$J=G91G21X1.000F60.000\n", ROWS["G11"][1] + ROWS["G20"][1]), ROWS["G12"]],
                           baudrate=115200) as port:
        ch = grbl.GrblChannel(port, TIMEOUT_S, "b")
        with pytest.raises(DeviceFault, match=r"ALARM:3 \(Abort during cycle"):
            ch.transact("$J=G91G21X1.000F60.000")
        assert ch.transact("$X") == ["[MSG:Caution: Unlocked]"]


# ---- (b) the simulator -------------------------------------------------------------------------------
_names = itertools.count()


@pytest.fixture
def sim():
    """The bench simulator of configs/sim.yaml, its EEPROM as the transcripts' bench, grbl-sim's pins."""
    clock = VirtualClock()
    config = load_config(ROOT / "configs" / "sim.yaml")
    dev = build_devices(config, clock, ["stepper_bench"])["stepper_bench"].device
    dev.pins = "PXYZRHS"
    dev.eeprom.build_info = "STEPPER_BENCH:EC2-01"
    name = f"golden.grbl.{next(_names)}"
    url = registry.register(name, dev)
    port = serial.serial_for_url(url, baudrate=115200, timeout=TIMEOUT_S)
    yield dev, clock, port
    port.close()
    registry.unregister(name)


def ask(port, request: bytes, n: int = 4096) -> bytes:
    port.write(request)
    return port.read(n)


@pytest.mark.parametrize("row", ["G1", "G2", "G4", "G5", "G13", "G14", "G15", "G16", "G17", "G22"])
def test_sim_answers_the_row(sim, row):
    dev, clock, port = sim
    request, answer = ROWS[row]
    assert ask(port, request) == answer


def test_sim_rows_while_jogging_and_in_alarm(sim):
    dev, clock, port = sim
    assert ask(port, ROWS["G5"][0]) == b"ok\r\n"
    clock.sleep(1.0)
    assert ask(port, ROWS["G18"][0]) == ROWS["G18"][1]
    assert ask(port, ROWS["G19"][0]) == ROWS["G19"][1]
    port.timeout = 1.0  # the welcome message comes 500 ms after ALARM:3
    assert ask(port, ROWS["G11"][0]) == ROWS["G11"][1]
    port.timeout = TIMEOUT_S
    assert ask(port, ROWS["G20"][0]) == ROWS["G20"][1]
    assert ask(port, ROWS["G12"][0]) == ROWS["G12"][1]
    assert ask(port, ROWS["G10"][0]) == ROWS["G10"][1]


def test_sim_holds_lines_in_a_hold_at_rest(sim):
    dev, clock, port = sim
    assert ask(port, ROWS["G8"][0]) == b""
    assert ask(port, b"?").startswith(b"<Hold:0|")
    assert ask(port, b"$I\n") == b""  # held
    assert ask(port, ROWS["G9"][0]).endswith(b"ok\r\n")  # answered on resume


def test_sim_jog_cancel_stops_and_flushes(sim):
    dev, clock, port = sim
    for _ in range(3):
        assert ask(port, ROWS["G5"][0]) == b"ok\r\n"
    clock.sleep(2.0)
    assert ask(port, ROWS["G7"][0]) == b""
    clock.sleep(1.0)
    idle = ask(port, b"?")
    assert idle.startswith(b"<Idle|MPos:")
    clock.sleep(10.0)
    assert ask(port, b"?").split(b"|")[1] == idle.split(b"|")[1]  # nothing queued moves on


def test_sim_blank_eeprom_power_up(sim):
    """G21: a freshly flashed board restores and lists its defaults before the welcome message."""
    from bench.sim.stepper_bench import StepperBenchSim

    fresh = StepperBenchSim(VirtualClock(), None, None)
    out = fresh.take_output(0.0)
    assert out.startswith(ROWS["G21"][1]) and out.endswith(WELCOME) and out.count(b"\r\n$") == 34
