"""Thermocouple logger driver (34970A-style SCPI) against its simulator."""

from __future__ import annotations

import pytest

from bench.clock import VirtualClock
from bench.config import load_config
from bench.errors import DeviceFault, InstrumentTimeout
from bench.sim import registry
from bench.sim.factory import build_devices
from bench.sim.scpi import header_matches, parse_channel_list
from drivers.thermocouple_reader import ThermocoupleReader
from tests.conftest import ROOT


@pytest.fixture
def logger():
    config = load_config(ROOT / "configs" / "sim_rotating_bench.yaml")
    clock = VirtualClock()
    dev = build_devices(config, clock, ["thermocouples"])["thermocouples"].device
    name = f"tc_{id(dev)}"
    url = registry.register(name, dev)
    yield dev, ThermocoupleReader.open(url)
    registry.unregister(name)


def test_identify_configure_read(logger):
    dev, tc = logger
    assert tc.identify()["model"] == "34970A"
    tc.configure(list(range(101, 109)), "K")
    scan = tc.read()
    assert list(scan.temps_c) == list(range(101, 109))
    # the world's 20 degC room, within the 34970A's type-K accuracy (1.0 degC, docs/thermocouples.md)
    assert all(v == pytest.approx(20.0, abs=1.0) for v in scan.temps_c.values())
    assert scan.open_channels == []
    assert tc.reference_junction_c(101) == pytest.approx(20.0, abs=0.8)  # 34901A reference-junction accuracy


def test_open_thermocouple_is_detected(logger):
    dev, tc = logger
    dev.open_channels = {104}
    tc.configure([101, 102, 103, 104], "T")
    scan = tc.read()
    assert scan.open_channels == [104] and scan.temps_c[104] is None and scan.temps_c[103] == pytest.approx(20.0, abs=1.0)


def test_instrument_errors_surface(logger):
    dev, tc = logger
    with pytest.raises(DeviceFault, match="-222"):
        tc.configure([101, 199])  # no channel 199 on a 34901A
    tc.channel.send("MEAS:WARP?")
    with pytest.raises(DeviceFault, match="-113"):
        tc.check_errors()
    with pytest.raises(ValueError):
        tc.configure([101], "X")


def test_no_answer_times_out(logger):
    dev, tc = logger
    tc.channel.timeout_s = 0.05
    with pytest.raises(InstrumentTimeout):
        tc.channel.query("*RST")  # a command, not a query: nothing comes back


@pytest.mark.parametrize(
    "pattern, header, ok",
    [
        ("SENSe:TEMPerature:TRANsducer:TCouple:CHECk", "SENS:TEMP:TRAN:TC:CHEC", True),
        ("[SENSe:]TEMPerature:TRANsducer:TCouple:CHECk", "temp:tran:tcouple:check", True),
        ("[SENSe:]TEMPerature:TRANsducer:TCouple:CHECk", "SENS:TEMP:TRAN:TC:CHE", False),
        ("ROUTe:SCAN", ":ROUT:SCAN", True),
        ("SYSTem:ERRor?", "SYST:ERR", False),
    ],
)
def test_scpi_header_matching(pattern, header, ok):
    assert header_matches(pattern, header) is ok


def test_channel_lists():
    assert parse_channel_list("(@101:103,105)") == [101, 102, 103, 105]
    for bad in ("101", "(@103:101)", "(@a)"):
        with pytest.raises(ValueError):
            parse_channel_list(bad)
