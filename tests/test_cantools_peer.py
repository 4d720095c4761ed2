"""A third-party peer reads the simulated rate table: python-can captures the bus, cantools decodes it
with the hand-written DBC docs/golden/rate_table.dbc (from the EDS mapping and CiA 301, not from our
code), and the decoded signals must match the commanded physics.

Units: the DBC decodes in the EDS units (counts, counts/s); 1 count = 0.001 deg (docs/rate-table.md).
"""

from __future__ import annotations

import pytest

cantools = pytest.importorskip("cantools", reason="cantools is not installed (it is in the test extras: pip install -e '.[test]')")

from bench.clock import VirtualClock  # noqa: E402
from bench.sim.rate_table import RateTableSim  # noqa: E402
from drivers.rate_table import RateTable  # noqa: E402
from tests.conftest import ROOT  # noqa: E402
from tests.golden.canbus import Capture, unique_channel  # noqa: E402

DBC = ROOT / "docs" / "golden" / "rate_table.dbc"
COUNTS_PER_DEG = 1000  # docs/rate-table.md: 1 count = 0.001 deg
OE_MASK, OE_VALUE = 0x006F, 0x0027  # CiA 402 OPERATION ENABLED (docs/golden/cia301-402.md)
SOD_MASK, SOD_VALUE = 0x004F, 0x0040  # SWITCH ON DISABLED
TARGET_REACHED = 1 << 10
PDO_IDS = {0x080, 0x181, 0x281, 0x182, 0x282}  # SYNC and the TPDOs of nodes 1 and 2 (pre-defined set)


@pytest.fixture
def rig():
    """(driver, simulator, capture, clock, DBC) on one virtual bus; the capture listens from the start."""
    channel = unique_channel("cantools-peer")
    cap = Capture(channel)
    clock = VirtualClock()
    sim = RateTableSim(clock, bus=channel)
    drv = RateTable.open(f"can://virtual/{channel}?node=1", timeout_s=0.5, clock=clock)
    yield drv, sim, cap, clock, cantools.database.load_file(str(DBC))
    drv.close()
    sim.close()
    cap.close()


def _decode(db, frames) -> dict[str, dict]:
    """{message name: decoded signals} of captured frames (every frame must be in the DBC, full length)."""
    out = {}
    for cob, data in frames:
        message = db.get_message_by_frame_id(cob)
        assert len(data) == message.length, f"{message.name}: {len(data)} bytes, DBC says {message.length}"
        out[message.name] = db.decode_message(cob, data)
    return out


def test_cantools_decodes_the_tpdos_of_a_spinning_tilted_table(rig):
    drv, sim, cap, clock, db = rig
    drv.tilt(-36.4)  # NPSAT1 tilt (docs/rate-table.md)
    clock.sleep(10.0)  # 36.4 deg at the EDS defaults (10 deg/s, 10 deg/s^2) takes 4.64 s
    t0 = clock.now()
    drv.set_rate(5.0, accel_dps2=10.0)  # deg/s, deg/s^2: the ramp lasts 0.5 s
    clock.sleep(3.0)
    # the drives power up PRE-OPERATIONAL: open() started them (CiA 301 NMT), so a poll is one SYNC
    assert cap.wait_for({0x000}, since=0, count=2) == [(0x000, b"\x01\x01"), (0x000, b"\x01\x02")]
    mark = cap.mark()
    reading = drv.monitor()
    frames = cap.wait_for(PDO_IDS, since=mark, count=5)
    assert frames[0] == (0x080, b"")  # the driver's SYNC, as the DBC has it (no data)
    got = _decode(db, frames)
    assert set(got) == {"SYNC", "TPDO1_rotation", "TPDO2_rotation", "TPDO1_tilt", "TPDO2_tilt"}
    rot1, rot2, tilt1, tilt2 = got["TPDO1_rotation"], got["TPDO2_rotation"], got["TPDO1_tilt"], got["TPDO2_tilt"]
    # physics: constant acceleration a for v/a seconds, then constant rate v
    v, a, t = 5.0, 10.0, clock.now() - t0
    angle_deg = v * t - v * v / (2 * a)
    assert rot2["velocity_actual"] == v * COUNTS_PER_DEG
    assert rot1["position_actual"] == round(angle_deg * COUNTS_PER_DEG)
    assert rot1["statusword"] & OE_MASK == OE_VALUE and rot1["statusword"] & TARGET_REACHED
    assert tilt1["position_actual"] == -36400 and tilt2["velocity_actual"] == 0
    assert tilt1["statusword"] & OE_MASK == OE_VALUE and tilt1["statusword"] & TARGET_REACHED
    # the driver read the same frames
    assert reading["angle"] == rot1["position_actual"] / COUNTS_PER_DEG
    assert reading["rate"] == rot2["velocity_actual"] / COUNTS_PER_DEG
    assert reading["tilt"] == tilt1["position_actual"] / COUNTS_PER_DEG
    assert (reading["statusword"], reading["tilt_statusword"]) == (rot1["statusword"], tilt1["statusword"])


def test_cantools_decodes_boot_up_heartbeat_and_emcy(rig):
    drv, sim, cap, clock, db = rig
    boot = _decode(db, cap.wait_for({0x701, 0x702}, count=2))
    assert boot["heartbeat_rotation"]["nmt_state"] == "BOOT_UP" and boot["heartbeat_tilt"]["nmt_state"] == "BOOT_UP"
    mark = cap.mark()
    sim.inject("fault", axis="tilt", code=0x2310)  # continuous over-current
    emcy = _decode(db, cap.wait_for({0x082}, since=mark))["EMCY_tilt"]
    assert (emcy["error_code"], emcy["error_register"], emcy["manufacturer_field"]) == (0x2310, 0x03, 0)
    assert drv.read()["tilt_state"] == "FAULT"
    mark = cap.mark()
    clock.sleep(1.0)
    drv.monitor()
    tilt1 = _decode(db, cap.wait_for({0x182}, since=mark))["TPDO1_tilt"]
    assert tilt1["statusword"] & 0x004F == 0x0008  # CiA 402 FAULT
