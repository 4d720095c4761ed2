"""Golden CAN frames of CiA 301 / CiA 402 (docs/golden/cia301-402.md) against the rate table's driver
and, separately, its simulator.

The rows below are transcribed from the document (a test checks that they agree with it); no driver
or simulator constant is imported. (a) The driver (drivers/rate_table.py) talks to a scripted node
that expects the literal request frames in order and answers with the literal responses. (b) The
simulator (bench/sim/rate_table.py) gets the literal requests on its bus and must give the literal
responses; its CiA 402 state machine is driven through the transitions of the document's tables.
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import pytest

from bench.clock import VirtualClock
from bench.sim.rate_table import RateTableSim
from drivers.errors import DeviceFault, ProtocolError
from drivers.rate_table import RateTable
from tests.golden.canbus import Capture, Emit, Exchange, Frame, ScriptedNode, frame, unique_channel

DOC = Path(__file__).resolve().parents[2] / "docs" / "golden" / "cia301-402.md"

ROWS: dict[str, Frame] = {
    "SDO-UP-REQ-1000": frame(0x601, "40 00 10 00 00 00 00 00"),
    "SDO-UP-RES-1000": frame(0x581, "43 00 10 00 92 01 02 00"),
    "SDO-UP-REQ-1001": frame(0x601, "40 01 10 00 00 00 00 00"),
    "SDO-UP-RES-1001-03": frame(0x581, "4F 01 10 00 03 00 00 00"),
    "SDO-UP-REQ-6041": frame(0x601, "40 41 60 00 00 00 00 00"),
    "SDO-UP-RES-6041-SOD": frame(0x581, "4B 41 60 00 40 02 00 00"),
    "SDO-UP-RES-6041-RTSO": frame(0x581, "4B 41 60 00 31 02 00 00"),
    "SDO-UP-RES-6041-SO": frame(0x581, "4B 41 60 00 33 02 00 00"),
    "SDO-UP-RES-6041-OE": frame(0x581, "4B 41 60 00 37 02 00 00"),
    "SDO-UP-RES-6041-FAULT": frame(0x581, "4B 41 60 00 08 02 00 00"),
    "SDO-UP-REQ-6041-N2": frame(0x602, "40 41 60 00 00 00 00 00"),
    "SDO-UP-RES-6041-SOD-N2": frame(0x582, "4B 41 60 00 40 02 00 00"),
    "SDO-DL-REQ-6060-PV": frame(0x601, "2F 60 60 00 03 00 00 00"),
    "SDO-DL-REQ-6060-PP": frame(0x601, "2F 60 60 00 01 00 00 00"),
    "SDO-DL-RES-6060": frame(0x581, "60 60 60 00 00 00 00 00"),
    "SDO-UP-REQ-6060": frame(0x601, "40 60 60 00 00 00 00 00"),
    "SDO-UP-RES-6060-PV": frame(0x581, "4F 60 60 00 03 00 00 00"),
    "SDO-DL-REQ-60FF-5000": frame(0x601, "23 FF 60 00 88 13 00 00"),
    "SDO-DL-REQ-60FF-100000": frame(0x601, "23 FF 60 00 A0 86 01 00"),
    "SDO-DL-RES-60FF": frame(0x581, "60 FF 60 00 00 00 00 00"),
    "SDO-DL-REQ-607A-90000": frame(0x601, "23 7A 60 00 90 5F 01 00"),
    "SDO-DL-RES-607A": frame(0x581, "60 7A 60 00 00 00 00 00"),
    "SDO-DL-REQ-6040-SHUTDOWN": frame(0x601, "2B 40 60 00 06 00 00 00"),
    "SDO-DL-REQ-6040-SWITCH-ON": frame(0x601, "2B 40 60 00 07 00 00 00"),
    "SDO-DL-REQ-6040-ENABLE-OPERATION": frame(0x601, "2B 40 60 00 0F 00 00 00"),
    "SDO-DL-REQ-6040-QUICK-STOP": frame(0x601, "2B 40 60 00 02 00 00 00"),
    "SDO-DL-REQ-6040-DISABLE-VOLTAGE": frame(0x601, "2B 40 60 00 00 00 00 00"),
    "SDO-DL-REQ-6040-FAULT-RESET": frame(0x601, "2B 40 60 00 80 00 00 00"),
    "SDO-DL-REQ-6040-HALT": frame(0x601, "2B 40 60 00 0F 01 00 00"),
    "SDO-DL-REQ-6040-NEW-SETPOINT": frame(0x601, "2B 40 60 00 1F 00 00 00"),
    "SDO-DL-REQ-6040-4BYTES": frame(0x601, "23 40 60 00 06 00 00 00"),
    "SDO-DL-RES-6040": frame(0x581, "60 40 60 00 00 00 00 00"),
    "SDO-DL-REQ-6040-DISABLE-VOLTAGE-N2": frame(0x602, "2B 40 60 00 00 00 00 00"),
    "SDO-DL-RES-6040-N2": frame(0x582, "60 40 60 00 00 00 00 00"),
    "SDO-DL-REQ-6041": frame(0x601, "2B 41 60 00 00 00 00 00"),
    "SDO-UP-REQ-6064": frame(0x601, "40 64 60 00 00 00 00 00"),
    "SDO-UP-RES-6064-90000": frame(0x581, "43 64 60 00 90 5F 01 00"),
    "SDO-UP-REQ-6064-N2": frame(0x602, "40 64 60 00 00 00 00 00"),
    "SDO-UP-RES-6064-0-N2": frame(0x582, "43 64 60 00 00 00 00 00"),
    "SDO-UP-REQ-606C": frame(0x601, "40 6C 60 00 00 00 00 00"),
    "SDO-UP-RES-606C-5000": frame(0x581, "43 6C 60 00 88 13 00 00"),
    "SDO-UP-RES-606C-0": frame(0x581, "43 6C 60 00 00 00 00 00"),
    "SDO-UP-REQ-606C-N2": frame(0x602, "40 6C 60 00 00 00 00 00"),
    "SDO-UP-RES-606C-0-N2": frame(0x582, "43 6C 60 00 00 00 00 00"),
    "SDO-UP-REQ-6085": frame(0x601, "40 85 60 00 00 00 00 00"),
    "SDO-UP-RES-6085-60000": frame(0x581, "43 85 60 00 60 EA 00 00"),
    "SDO-UP-REQ-603F": frame(0x601, "40 3F 60 00 00 00 00 00"),
    "SDO-UP-RES-603F-2310": frame(0x581, "4B 3F 60 00 10 23 00 00"),
    "SDO-UP-RES-603F-0": frame(0x581, "4B 3F 60 00 00 00 00 00"),
    "SDO-UP-REQ-608F-1": frame(0x601, "40 8F 60 01 00 00 00 00"),
    "SDO-UP-RES-608F-1": frame(0x581, "43 8F 60 01 40 7E 05 00"),
    "SDO-UP-REQ-608F-2": frame(0x601, "40 8F 60 02 00 00 00 00"),
    "SDO-UP-RES-608F-2": frame(0x581, "43 8F 60 02 01 00 00 00"),
    "SDO-UP-REQ-608F-3": frame(0x601, "40 8F 60 03 00 00 00 00"),
    "SDO-UP-REQ-608F-1-N2": frame(0x602, "40 8F 60 01 00 00 00 00"),
    "SDO-UP-RES-608F-1-N2": frame(0x582, "43 8F 60 01 40 7E 05 00"),
    "SDO-UP-REQ-608F-2-N2": frame(0x602, "40 8F 60 02 00 00 00 00"),
    "SDO-UP-RES-608F-2-N2": frame(0x582, "43 8F 60 02 01 00 00 00"),
    "SDO-UP-REQ-607D-1-N2": frame(0x602, "40 7D 60 01 00 00 00 00"),
    "SDO-UP-RES-607D-1-N2": frame(0x582, "43 7D 60 01 40 2B FE FF"),
    "SDO-UP-REQ-607D-2-N2": frame(0x602, "40 7D 60 02 00 00 00 00"),
    "SDO-UP-RES-607D-2-N2": frame(0x582, "43 7D 60 02 C0 D4 01 00"),
    "SDO-UP-REQ-1234": frame(0x601, "40 34 12 00 00 00 00 00"),
    "SDO-UP-REQ-1800-1": frame(0x601, "40 00 18 01 00 00 00 00"),
    "SDO-UP-RES-1800-1": frame(0x581, "43 00 18 01 81 01 00 00"),
    "SDO-UP-REQ-1800-2": frame(0x601, "40 00 18 02 00 00 00 00"),
    "SDO-UP-RES-1800-2": frame(0x581, "4F 00 18 02 01 00 00 00"),
    "SDO-UP-REQ-1A00-1": frame(0x601, "40 00 1A 01 00 00 00 00"),
    "SDO-UP-RES-1A00-1": frame(0x581, "43 00 1A 01 10 00 41 60"),
    "SDO-UP-REQ-1A00-2": frame(0x601, "40 00 1A 02 00 00 00 00"),
    "SDO-UP-RES-1A00-2": frame(0x581, "43 00 1A 02 20 00 64 60"),
    "SDO-UP-REQ-1A01-1": frame(0x601, "40 01 1A 01 00 00 00 00"),
    "SDO-UP-RES-1A01-1": frame(0x581, "43 01 1A 01 20 00 6C 60"),
    "SDO-DL-REQ-1017-100": frame(0x601, "2B 17 10 00 64 00 00 00"),
    "SDO-DL-RES-1017": frame(0x581, "60 17 10 00 00 00 00 00"),
    "SDO-ABORT-06020000": frame(0x581, "80 34 12 00 00 00 02 06"),
    "SDO-ABORT-603F-06020000": frame(0x581, "80 3F 60 00 00 00 02 06"),
    "SDO-ABORT-06090011": frame(0x581, "80 8F 60 03 11 00 09 06"),
    "SDO-ABORT-06010002": frame(0x581, "80 41 60 00 02 00 01 06"),
    "SDO-ABORT-06090031": frame(0x581, "80 FF 60 00 31 00 09 06"),
    "SDO-ABORT-06070010": frame(0x581, "80 40 60 00 10 00 07 06"),
    "NMT-START-1": frame(0x000, "01 01"),
    "NMT-START-2": frame(0x000, "01 02"),
    "NMT-STOP-1": frame(0x000, "02 01"),
    "NMT-PREOP-1": frame(0x000, "80 01"),
    "NMT-RESET-NODE-1": frame(0x000, "81 01"),
    "HB-BOOTUP-1": frame(0x701, "00"),
    "HB-BOOTUP-2": frame(0x702, "00"),
    "HB-PREOP-1": frame(0x701, "7F"),
    "HB-OPERATIONAL-1": frame(0x701, "05"),
    "HB-STOPPED-1": frame(0x701, "04"),
    "SYNC": frame(0x080, "(none)"),
    "EMCY-2310-1": frame(0x081, "10 23 03 00 00 00 00 00"),
    "EMCY-RESET-1": frame(0x081, "00 00 00 00 00 00 00 00"),
    "EMCY-8611-FAULHABER-1": frame(0x081, "11 86 20 02 00 00 00 00"),
    "TPDO1-1-PP-90DEG": frame(0x181, "37 06 90 5F 01 00"),
    "TPDO1-1-OE": frame(0x181, "37 02 00 00 00 00"),
    "TPDO2-1-5DPS": frame(0x281, "88 13 00 00"),
    "TPDO2-1-REST": frame(0x281, "00 00 00 00"),
    "TPDO1-1-SW-ONLY": frame(0x181, "37 02"),
    "TPDO1-2-SW-ONLY": frame(0x182, "40 02"),
    "TPDO1-2-REST": frame(0x182, "40 02 00 00 00 00"),
    "TPDO2-2-REST": frame(0x282, "00 00 00 00"),
}

# CiA 402 statusword states: name -> (mask, value), transcribed from the document's table.
SW_STATES: dict[str, tuple[int, int]] = {
    "NOT READY TO SWITCH ON": (0x004F, 0x0000),
    "SWITCH ON DISABLED": (0x004F, 0x0040),
    "READY TO SWITCH ON": (0x006F, 0x0021),
    "SWITCHED ON": (0x006F, 0x0023),
    "OPERATION ENABLED": (0x006F, 0x0027),
    "QUICK STOP ACTIVE": (0x006F, 0x0007),
    "FAULT REACTION ACTIVE": (0x004F, 0x000F),
    "FAULT": (0x004F, 0x0008),
}
# CiA 402 controlword commands, transcribed from the document's table.
CW_COMMANDS: dict[str, int] = {
    "SHUTDOWN": 0x0006,
    "SWITCH ON": 0x0007,
    "DISABLE OPERATION": 0x0007,
    "ENABLE OPERATION": 0x000F,
    "QUICK STOP": 0x0002,
    "DISABLE VOLTAGE": 0x0000,
    "FAULT RESET": 0x0080,
}
REMOTE = 0x0200  # statusword bit 9 (the bench drive always sets it; document, last paragraph of the state table)
SDO_TIMEOUT_S = 0.5  # the driver's timeout_s (wall s)
ANSWER_WAIT_S = 2.0  # wall s a simulator answer may take (waits end when it comes)
HEARTBEAT_WAIT_S = 1.0  # wall s for a heartbeat of the 100 ms producer


def R(row: str) -> Frame:
    return ROWS[row]


def X(request: str, *responses: str) -> Exchange:
    return Exchange(R(request), tuple(R(r) for r in responses))


# ---- the rows agree with the document ---------------------------------------------------------
def _doc_tables() -> tuple[dict[str, Frame], dict[str, tuple[int, int]], dict[str, int]]:
    text = DOC.read_text(encoding="utf-8")
    frames = {rid: frame(int(cob, 16), data.strip())
              for rid, cob, data in re.findall(r"^\| ([A-Z0-9-]+) \| (0x[0-9A-F]{3}) \| ([^|]+?) \|", text, re.M)}
    states = {name: (int(mask, 16), int(value, 16))
              for name, mask, value in re.findall(r"^\| ([A-Z ]+) \| (0x[0-9A-F]{4}) \| (0x[0-9A-F]{4}) \|$", text, re.M)}
    commands = {name: int(cw, 16) for name, cw in re.findall(r"^\| ([A-Z ]+) \| (0x[0-9A-F]{4})(?: \(rising edge of bit 7\))? \| [0-9, ]+ \|", text, re.M)}
    return frames, states, commands


def test_transcribed_rows_agree_with_the_document():
    frames, states, commands = _doc_tables()
    assert len(frames) > 90 and frames == ROWS
    assert states == SW_STATES
    assert commands == CW_COMMANDS
    # internal consistency of the document: controlword rows carry the command table's values
    for name, value in CW_COMMANDS.items():
        row = ROWS.get("SDO-DL-REQ-6040-" + name.replace(" ", "-"))
        if row is not None:
            assert int.from_bytes(row[1][4:6], "little") == value


# ---- (a) the driver against a scripted node ---------------------------------------------------
OPEN = [
    X("SDO-UP-REQ-608F-1", "SDO-UP-RES-608F-1"),
    X("SDO-UP-REQ-608F-2", "SDO-UP-RES-608F-2"),
    X("SDO-UP-REQ-608F-1-N2", "SDO-UP-RES-608F-1-N2"),
    X("SDO-UP-REQ-608F-2-N2", "SDO-UP-RES-608F-2-N2"),
    X("SDO-UP-REQ-607D-1-N2", "SDO-UP-RES-607D-1-N2"),
    X("SDO-UP-REQ-607D-2-N2", "SDO-UP-RES-607D-2-N2"),
    X("NMT-START-1"),
    X("NMT-START-2"),
]
TPDOS = ("TPDO1-1-PP-90DEG", "TPDO2-1-5DPS", "TPDO1-2-REST", "TPDO2-2-REST")
MONITOR_PP_90DEG = {"angle": 90.0, "rate": 5.0, "tilt": 0.0, "statusword": 0x0637, "tilt_statusword": 0x0240}
READ_BOTH = [
    X("SDO-UP-REQ-6041", "SDO-UP-RES-6041-OE"),
    X("SDO-UP-REQ-6064", "SDO-UP-RES-6064-90000"),
    X("SDO-UP-REQ-606C", "SDO-UP-RES-606C-5000"),
    X("SDO-UP-REQ-6041-N2", "SDO-UP-RES-6041-SOD-N2"),
    X("SDO-UP-REQ-6064-N2", "SDO-UP-RES-6064-0-N2"),
    X("SDO-UP-REQ-606C-N2", "SDO-UP-RES-606C-0-N2"),
]


def _played(node: ScriptedNode) -> None:
    """Every step was played and the host sent nothing else (the node has judged every frame sent
    before this call: the driver's call has returned, so whatever it sent is among them)."""
    assert node.wait_done(2.0), node.mismatch or f"script stopped at step {node.pos} of {len(node.script)}"
    assert node.settle(ANSWER_WAIT_S), "the node did not receive the marker frame"
    assert node.mismatch is None, node.mismatch
    assert len(node.received) == sum(isinstance(s, Exchange) for s in node.script)


@pytest.fixture
def scripted():
    """(driver, scripted node): the driver opened against the node playing OPEN."""
    channel = unique_channel("cia402-driver")
    node = ScriptedNode(channel, list(OPEN))
    traffic: list[tuple[str, str, bytes]] = []
    try:
        drv = RateTable.open(f"can://virtual/{channel}?node=1", timeout_s=SDO_TIMEOUT_S, clock=VirtualClock(),
                             on_traffic=lambda d, n, raw: traffic.append((d, n, raw)))
    except Exception:
        node.close()
        raise
    drv.traffic = traffic
    yield drv, node
    drv.close()
    node.close()


def test_driver_open_reads_resolution_and_limits(scripted):
    drv, node = scripted
    _played(node)
    sent = len(node.received)
    with pytest.raises(ValueError, match=r"-120\.\.120 deg"):  # limits from SDO-UP-RES-607D-*-N2
        drv.tilt(150.0)
    assert len(node.received) == sent  # refused before anything was sent


def test_driver_enable_sequence_and_set_velocity_send_the_documented_frames(scripted):
    drv, node = scripted
    node.extend([
        X("SDO-DL-REQ-6060-PV", "SDO-DL-RES-6060"),
        X("SDO-DL-REQ-60FF-5000", "SDO-DL-RES-60FF"),
        X("SDO-UP-REQ-6041", "SDO-UP-RES-6041-SOD"),
        X("SDO-DL-REQ-6040-SHUTDOWN", "SDO-DL-RES-6040"),
        X("SDO-UP-REQ-6041", "SDO-UP-RES-6041-RTSO"),
        X("SDO-DL-REQ-6040-SWITCH-ON", "SDO-DL-RES-6040"),
        X("SDO-UP-REQ-6041", "SDO-UP-RES-6041-SO"),
        X("SDO-DL-REQ-6040-ENABLE-OPERATION", "SDO-DL-RES-6040"),
        X("SDO-UP-REQ-6041", "SDO-UP-RES-6041-OE"),
        X("SDO-DL-REQ-6040-ENABLE-OPERATION", "SDO-DL-RES-6040"),
    ])
    assert drv.set_rate(5.0) == 5.0  # deg/s
    _played(node)


def test_driver_decodes_the_documented_sdo_answers(scripted):
    drv, node = scripted
    node.extend(READ_BOTH)
    r = drv.read()
    _played(node)
    assert (r["angle_deg"], r["rate_dps"], r["tilt_deg"], r["tilt_rate_dps"]) == (90.0, 5.0, 0.0, 0.0)
    assert (r["state"], r["tilt_state"]) == ("OPERATION ENABLED", "SWITCH ON DISABLED")
    assert (r["statusword"], r["tilt_statusword"]) == (0x0237, 0x0240)
    assert not r["target_reached"] and not r["any_fault"]


def test_driver_monitor_decodes_the_documented_tpdos_after_one_sync(scripted):
    drv, node = scripted
    node.extend([X("SYNC", *TPDOS)])
    m = drv.monitor()
    _played(node)
    assert m == MONITOR_PP_90DEG


def test_driver_starts_the_drives_when_it_opens(scripted):
    """Drives power up PRE-OPERATIONAL (CiA 301) and send PDOs only when OPERATIONAL: open() ends
    with NMT "start remote node" to both, so the first monitor() is one SYNC."""
    drv, node = scripted
    node.extend([X("SYNC", *TPDOS)])
    assert drv.monitor() == MONITOR_PP_90DEG
    _played(node)
    nmt = [(n, raw) for d, n, raw in drv.traffic if d == "command" and n.startswith("NMT")]
    assert nmt == [("NMT start node 1", bytes([0x00, 0x00]) + R("NMT-START-1")[1]),
                   ("NMT start node 2", bytes([0x00, 0x00]) + R("NMT-START-2")[1])]


def test_driver_falls_back_to_sdo_when_sync_gets_no_pdos(scripted):
    drv, node = scripted
    node.extend([X("SYNC")] + READ_BOTH)
    m = drv.monitor()
    _played(node)
    assert m == {"angle": 90.0, "rate": 5.0, "tilt": 0.0, "statusword": 0x0237, "tilt_statusword": 0x0240}


def test_driver_monitor_falls_back_to_sdo_for_a_drive_with_another_mapping(scripted):
    drv, node = scripted
    node.extend([X("SYNC", "TPDO1-1-SW-ONLY", "TPDO2-1-5DPS", "TPDO1-2-SW-ONLY", "TPDO2-2-REST")] + READ_BOTH)
    m = drv.monitor()
    _played(node)
    assert m == {"angle": 90.0, "rate": 5.0, "tilt": 0.0, "statusword": 0x0237, "tilt_statusword": 0x0240}


def test_driver_fault_reset_is_disable_voltage_then_bit_7(scripted):
    drv, node = scripted
    node.extend([
        X("SDO-DL-REQ-6040-DISABLE-VOLTAGE", "SDO-DL-RES-6040"),
        X("SDO-DL-REQ-6040-FAULT-RESET", "SDO-DL-RES-6040"),
        X("SDO-UP-REQ-6041", "SDO-UP-RES-6041-SOD"),
    ])
    drv.reset_fault("rotation")
    _played(node)


def test_driver_stop_sets_halt_on_the_enabled_axis_only(scripted):
    drv, node = scripted
    node.extend([
        X("SDO-UP-REQ-6041", "SDO-UP-RES-6041-OE"),
        X("SDO-DL-REQ-6040-HALT", "SDO-DL-RES-6040"),
        X("SDO-UP-REQ-6041-N2", "SDO-UP-RES-6041-SOD-N2"),
    ])
    drv.stop()
    _played(node)


def test_driver_safe_state_is_quick_stop_then_disable_voltage(scripted):
    drv, node = scripted
    node.extend([
        X("SDO-UP-REQ-6041", "SDO-UP-RES-6041-OE"),
        X("SDO-DL-REQ-6040-QUICK-STOP", "SDO-DL-RES-6040"),
        X("SDO-UP-REQ-606C", "SDO-UP-RES-606C-0"),
        X("SDO-UP-REQ-6085", "SDO-UP-RES-6085-60000"),
        X("SDO-DL-REQ-6040-DISABLE-VOLTAGE", "SDO-DL-RES-6040"),
        X("SDO-UP-REQ-6041-N2", "SDO-UP-RES-6041-SOD-N2"),
        X("SDO-DL-REQ-6040-DISABLE-VOLTAGE-N2", "SDO-DL-RES-6040-N2"),
    ])
    drv.safe_state()
    _played(node)


def test_driver_sdo_abort_becomes_protocol_error_with_code_and_meaning(scripted):
    drv, node = scripted
    node.extend([
        X("SDO-DL-REQ-6060-PV", "SDO-DL-RES-6060"),
        X("SDO-DL-REQ-60FF-100000", "SDO-ABORT-06090031"),
    ])
    with pytest.raises(ProtocolError, match=r"0x06090031 \(.*too high") as info:
        drv.set_rate(100.0)
    assert not isinstance(info.value, DeviceFault)
    _played(node)


@pytest.mark.parametrize("emcy, error_code_answer, code", [
    ("EMCY-8611-FAULHABER-1", "SDO-ABORT-603F-06020000", 0x8611),  # no 0x603F: the EMCY's code
    ("EMCY-2310-1", "SDO-UP-RES-603F-2310", 0x2310),  # 0x603F answers
])
def test_driver_emcy_and_fault_state_become_device_fault(scripted, emcy, error_code_answer, code):
    drv, node = scripted
    node.extend([
        Emit(R(emcy)),
        X("SDO-DL-REQ-6060-PV", "SDO-DL-RES-6060"),
        X("SDO-DL-REQ-60FF-5000", "SDO-DL-RES-60FF"),
        X("SDO-UP-REQ-6041", "SDO-UP-RES-6041-FAULT"),
        X("SDO-UP-REQ-603F", error_code_answer),
    ])
    with pytest.raises(DeviceFault, match=f"0x{code:04X}") as info:
        drv.set_rate(5.0)
    assert info.value.error_code == code
    _played(node)
    emcy_replies = [n for d, n, raw in drv.traffic if d == "reply" and raw == R(emcy)[0].to_bytes(2, "big") + R(emcy)[1]]
    assert emcy_replies and emcy_replies[0].startswith(f"EMCY 0x{int.from_bytes(R(emcy)[1][:2], 'little'):04X}")


# ---- (b) the simulator against the documented frames ------------------------------------------
@pytest.fixture
def sim_bus():
    """(capture bus, simulator, clock): the capture joins the channel before the simulator boots."""
    channel = unique_channel("cia402-sim")
    cap = Capture(channel)
    clock = VirtualClock()
    sim = RateTableSim(clock, bus=channel)
    yield cap, sim, clock
    sim.close()
    cap.close()


def _response_cob(request: Frame) -> int:
    return request[0] - 0x600 + 0x580  # SDO: request 0x600 + node, response 0x580 + node (pre-defined set)


def ask(cap: Capture, request: Frame, timeout_s: float = ANSWER_WAIT_S) -> Frame | None:
    """Send an SDO request; the drive's answer (None if there is none within ``timeout_s``)."""
    cob = _response_cob(request)
    got = cap.wait_for({cob}, since=cap.send(request), timeout_s=timeout_s)
    return got[0] if got else None


def settle(cap: Capture) -> None:
    """Wait until ``cap`` holds every frame the simulator sends in reaction to what was sent before:
    drive 2's answer to a statusword upload (drive 2 answers SDO in every state these tests leave it
    in). The simulator handles frames one at a time in the order they come (canopen's notifier
    thread), so its reactions to earlier frames are on the bus before that answer."""
    assert ask(cap, R("SDO-UP-REQ-6041-N2")) is not None, "drive 2 did not answer the statusword upload"


def state_of(cap: Capture, node: int = 1) -> str:
    """CiA 402 state of drive ``node`` from a literal statusword upload, by the document's masks."""
    req = R("SDO-UP-REQ-6041" if node == 1 else "SDO-UP-REQ-6041-N2")
    res = ask(cap, req)
    assert res is not None, "no answer to the statusword upload"
    assert res[1][:4] == bytes.fromhex("4B 41 60 00") and res[1][6:] == b"\0\0"  # 2-byte expedited answer
    sw = int.from_bytes(res[1][4:6], "little")
    assert sw & REMOTE
    names = [name for name, (mask, value) in SW_STATES.items() if sw & mask == value]
    assert len(names) == 1, f"statusword 0x{sw:04X} matches {names}"
    return names[0]


def cw(cap: Capture, command: str) -> None:
    """Write the controlword row ``SDO-DL-REQ-6040-<command>``; the answer must be the documented one."""
    assert ask(cap, R(f"SDO-DL-REQ-6040-{command}")) == R("SDO-DL-RES-6040")


def wait_heartbeat(cap: Capture, row: str, since: int) -> int:
    """Index of the first frame equal to ``row`` received from ``since`` on (fails after the wait)."""
    want = R(row)
    deadline = time.monotonic() + HEARTBEAT_WAIT_S
    while time.monotonic() < deadline:
        frames = cap.frames(since)
        if want in frames:
            return since + frames.index(want)
        cap.wait_for({want[0]}, since=since + len(frames), timeout_s=0.05)
    raise AssertionError(f"no {row} within {HEARTBEAT_WAIT_S} s; got {cap.frames(since, {want[0]})}")


def test_sim_sends_boot_up_of_both_drives_when_it_joins_the_bus(sim_bus):
    cap, _, _ = sim_bus
    assert cap.wait_for({0x701, 0x702}, count=2) == [R("HB-BOOTUP-1"), R("HB-BOOTUP-2")]


SDO_PAIRS = [
    ("SDO-UP-REQ-1000", "SDO-UP-RES-1000"),
    ("SDO-UP-REQ-608F-1", "SDO-UP-RES-608F-1"),
    ("SDO-UP-REQ-608F-2", "SDO-UP-RES-608F-2"),
    ("SDO-UP-REQ-608F-1-N2", "SDO-UP-RES-608F-1-N2"),
    ("SDO-UP-REQ-608F-2-N2", "SDO-UP-RES-608F-2-N2"),
    ("SDO-UP-REQ-607D-1-N2", "SDO-UP-RES-607D-1-N2"),
    ("SDO-UP-REQ-607D-2-N2", "SDO-UP-RES-607D-2-N2"),
    ("SDO-UP-REQ-6064-N2", "SDO-UP-RES-6064-0-N2"),
    ("SDO-UP-REQ-606C-N2", "SDO-UP-RES-606C-0-N2"),
    ("SDO-UP-REQ-6085", "SDO-UP-RES-6085-60000"),
    ("SDO-UP-REQ-603F", "SDO-UP-RES-603F-0"),
    ("SDO-UP-REQ-6060", "SDO-UP-RES-6060-PV"),
    ("SDO-DL-REQ-6060-PV", "SDO-DL-RES-6060"),
    ("SDO-DL-REQ-60FF-5000", "SDO-DL-RES-60FF"),
    ("SDO-DL-REQ-607A-90000", "SDO-DL-RES-607A"),
    ("SDO-UP-REQ-1800-1", "SDO-UP-RES-1800-1"),
    ("SDO-UP-REQ-1800-2", "SDO-UP-RES-1800-2"),
    ("SDO-UP-REQ-1A00-1", "SDO-UP-RES-1A00-1"),
    ("SDO-UP-REQ-1A00-2", "SDO-UP-RES-1A00-2"),
    ("SDO-UP-REQ-1A01-1", "SDO-UP-RES-1A01-1"),
    ("SDO-UP-REQ-1234", "SDO-ABORT-06020000"),
    ("SDO-UP-REQ-608F-3", "SDO-ABORT-06090011"),
    ("SDO-DL-REQ-6041", "SDO-ABORT-06010002"),
    ("SDO-DL-REQ-60FF-100000", "SDO-ABORT-06090031"),
    ("SDO-DL-REQ-6040-4BYTES", "SDO-ABORT-06070010"),
]


@pytest.mark.parametrize("request_row, response_row", SDO_PAIRS)
def test_sim_answers_documented_sdo_requests_with_documented_frames(sim_bus, request_row, response_row):
    cap, _, _ = sim_bus
    assert ask(cap, R(request_row)) == R(response_row)


def test_sim_nmt_states_heartbeat_sdo_and_pdo_availability(sim_bus):
    cap, _, _ = sim_bus
    assert ask(cap, R("SDO-DL-REQ-1017-100")) == R("SDO-DL-RES-1017")
    wait_heartbeat(cap, "HB-PREOP-1", cap.mark())
    tpdo_ids = {0x181, 0x281, 0x182, 0x282}
    # PRE-OPERATIONAL: SDO yes, PDO no
    mark = cap.send(R("SYNC"))
    settle(cap)
    assert cap.frames(mark, tpdo_ids) == []
    # OPERATIONAL (node 1 only): SYNC brings node 1's two TPDOs, node 2 stays silent
    mark = cap.send(R("NMT-START-1"))
    wait_heartbeat(cap, "HB-OPERATIONAL-1", mark)
    mark = cap.send(R("SYNC"))
    tpdos = cap.wait_for(tpdo_ids, since=mark, count=2)
    assert [f[0] for f in tpdos] == [0x181, 0x281]
    assert len(tpdos[0][1]) == 6 and tpdos[0][1][2:] == bytes(4)  # statusword + position 0 counts
    assert tpdos[1] == R("TPDO2-1-REST")
    sw = int.from_bytes(tpdos[0][1][:2], "little")
    assert sw & SW_STATES["SWITCH ON DISABLED"][0] == SW_STATES["SWITCH ON DISABLED"][1]
    settle(cap)
    assert cap.frames(mark, {0x182, 0x282}) == []
    # STOPPED: only NMT and heartbeat; no SDO answer, no PDO
    mark = cap.send(R("NMT-STOP-1"))
    wait_heartbeat(cap, "HB-STOPPED-1", mark)
    mark = cap.send(R("SDO-UP-REQ-6041"))
    settle(cap)
    assert cap.frames(mark, {_response_cob(R("SDO-UP-REQ-6041"))}) == []
    mark = cap.send(R("SYNC"))
    settle(cap)
    assert cap.frames(mark, tpdo_ids) == []
    # back to PRE-OPERATIONAL: SDO answered again
    mark = cap.send(R("NMT-PREOP-1"))
    wait_heartbeat(cap, "HB-PREOP-1", mark)
    assert state_of(cap) == "SWITCH ON DISABLED"
    # reset node: boot-up message, then PRE-OPERATIONAL
    mark = cap.send(R("NMT-RESET-NODE-1"))
    boot = wait_heartbeat(cap, "HB-BOOTUP-1", mark)
    wait_heartbeat(cap, "HB-PREOP-1", boot + 1)


# (controlword command row suffix, expected state): CiA 402 transitions, numbered as in the table
TRANSITIONS = [
    (None, "SWITCH ON DISABLED"),
    ("SWITCH-ON", "SWITCH ON DISABLED"),  # not a transition from SWITCH ON DISABLED
    ("ENABLE-OPERATION", "SWITCH ON DISABLED"),  # nor this
    ("SHUTDOWN", "READY TO SWITCH ON"),  # 2
    ("SWITCH-ON", "SWITCHED ON"),  # 3
    ("ENABLE-OPERATION", "OPERATION ENABLED"),  # 4
    ("SWITCH-ON", "SWITCHED ON"),  # 5 disable operation
    ("ENABLE-OPERATION", "OPERATION ENABLED"),  # 4
    ("SHUTDOWN", "READY TO SWITCH ON"),  # 8
    ("SWITCH-ON", "SWITCHED ON"),  # 3
    ("SHUTDOWN", "READY TO SWITCH ON"),  # 6
    ("DISABLE-VOLTAGE", "SWITCH ON DISABLED"),  # 7
    ("SHUTDOWN", "READY TO SWITCH ON"),  # 2
    ("QUICK-STOP", "SWITCH ON DISABLED"),  # 7
    ("SHUTDOWN", "READY TO SWITCH ON"),  # 2
    ("SWITCH-ON", "SWITCHED ON"),  # 3
    ("QUICK-STOP", "SWITCH ON DISABLED"),  # 10
    ("SHUTDOWN", "READY TO SWITCH ON"),  # 2
    ("SWITCH-ON", "SWITCHED ON"),  # 3
    ("DISABLE-VOLTAGE", "SWITCH ON DISABLED"),  # 10
    ("SHUTDOWN", "READY TO SWITCH ON"),  # 2
    ("SWITCH-ON", "SWITCHED ON"),  # 3
    ("ENABLE-OPERATION", "OPERATION ENABLED"),  # 4
    ("DISABLE-VOLTAGE", "SWITCH ON DISABLED"),  # 9
    ("SHUTDOWN", "READY TO SWITCH ON"),  # 2
    ("SWITCH-ON", "SWITCHED ON"),  # 3
    ("ENABLE-OPERATION", "OPERATION ENABLED"),  # 4
    ("QUICK-STOP", "QUICK STOP ACTIVE"),  # 11
    ("ENABLE-OPERATION", "OPERATION ENABLED"),  # 16
    ("QUICK-STOP", "QUICK STOP ACTIVE"),  # 11
    ("DISABLE-VOLTAGE", "SWITCH ON DISABLED"),  # 12
]


def test_sim_state_machine_follows_the_cia402_transitions(sim_bus):
    cap, _, _ = sim_bus
    for step, (command, expected) in enumerate(TRANSITIONS):
        if command is not None:
            cw(cap, command)
        assert state_of(cap) == expected, f"step {step}: {command} should give {expected}"
    assert state_of(cap, node=2) == "SWITCH ON DISABLED"  # the other drive was never addressed


def test_sim_fault_sends_emcy_sets_error_code_and_resets_on_bit_7(sim_bus):
    cap, sim, _ = sim_bus
    for command in ("SHUTDOWN", "SWITCH-ON", "ENABLE-OPERATION"):
        cw(cap, command)
    mark = cap.mark()
    sim.inject("fault", axis="rotation", code=0x2310)  # an internal event (transitions 13, 14)
    assert cap.wait_for({0x081}, since=mark) == [R("EMCY-2310-1")]
    assert state_of(cap) == "FAULT"
    assert ask(cap, R("SDO-UP-REQ-603F")) == R("SDO-UP-RES-603F-2310")
    assert ask(cap, R("SDO-UP-REQ-1001")) == R("SDO-UP-RES-1001-03")
    cw(cap, "ENABLE-OPERATION")
    assert state_of(cap) == "FAULT"  # no way out but a fault reset
    cw(cap, "DISABLE-VOLTAGE")
    assert state_of(cap) == "FAULT"
    mark = cap.mark()
    cw(cap, "FAULT-RESET")  # 15: rising edge of bit 7
    assert state_of(cap) == "SWITCH ON DISABLED"
    assert cap.wait_for({0x081}, since=mark) == [R("EMCY-RESET-1")]
    assert ask(cap, R("SDO-UP-REQ-603F")) == R("SDO-UP-RES-603F-0")


def _enable(cap: Capture) -> None:
    for command in ("SHUTDOWN", "SWITCH-ON", "ENABLE-OPERATION"):
        cw(cap, command)
    assert state_of(cap) == "OPERATION ENABLED"


def test_sim_profile_velocity_reports_the_documented_velocity(sim_bus):
    cap, _, clock = sim_bus
    cap.send(R("NMT-START-1"))
    assert ask(cap, R("SDO-DL-REQ-6060-PV")) == R("SDO-DL-RES-6060")
    assert ask(cap, R("SDO-DL-REQ-60FF-5000")) == R("SDO-DL-RES-60FF")
    _enable(cap)
    clock.sleep(2.0)  # 5 deg/s reached after 0.5 s at the EDS default 10 deg/s^2
    assert ask(cap, R("SDO-UP-REQ-606C")) == R("SDO-UP-RES-606C-5000")
    mark = cap.send(R("SYNC"))
    tpdo1, tpdo2 = cap.wait_for({0x181, 0x281}, since=mark, count=2)
    assert tpdo2 == R("TPDO2-1-5DPS")
    sw = int.from_bytes(tpdo1[1][:2], "little")
    assert sw & SW_STATES["OPERATION ENABLED"][0] == SW_STATES["OPERATION ENABLED"][1]


def test_sim_profile_position_reports_the_documented_tpdo1(sim_bus):
    cap, _, clock = sim_bus
    cap.send(R("NMT-START-1"))
    assert ask(cap, R("SDO-DL-REQ-6060-PP")) == R("SDO-DL-RES-6060")
    assert ask(cap, R("SDO-DL-REQ-607A-90000")) == R("SDO-DL-RES-607A")
    _enable(cap)
    cw(cap, "NEW-SETPOINT")  # bit 4 rising edge starts the move
    cw(cap, "ENABLE-OPERATION")
    clock.sleep(15.0)  # 90 deg at the EDS defaults 10 deg/s, 10 deg/s^2: 10 s
    assert ask(cap, R("SDO-UP-REQ-6064")) == R("SDO-UP-RES-6064-90000")
    mark = cap.send(R("SYNC"))
    assert cap.wait_for({0x181}, since=mark) == [R("TPDO1-1-PP-90DEG")]
