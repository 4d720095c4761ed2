"""TVAC chamber: Watlow F4 driver <-> simulated F4 over real Modbus/TCP on 127.0.0.1, TPG 261
driver <-> simulated gauge over ``sim://``, and the composite ``TvacChamber``. All on a
:class:`VirtualClock` driving the real :class:`Chamber` physics."""

from __future__ import annotations

import itertools
import subprocess
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymodbus.client import ModbusTcpClient

from bench.clock import VirtualClock
from bench.errors import DeviceFault, InstrumentError, InstrumentTimeout, ProtocolError
from bench.sim import registry
from bench.sim.chamber import Chamber, ChamberParams
from bench.sim.tpg261 import Tpg261Sim
from bench.sim.watlow_f4_server import WatlowF4Server
from drivers.tpg261 import Tpg261, parse_pr_reply
from drivers.tvac import TvacChamber
from drivers.watlow_f4 import BY_NAME, REGISTERS, WatlowF4
from tests.programs import find_program

TIMEOUT_S = 0.3
_names = itertools.count()


@pytest.fixture
def clock():
    return VirtualClock()


@pytest.fixture
def chamber():
    return Chamber(ChamberParams())


@pytest.fixture
def server(clock, chamber):
    sim = WatlowF4Server(clock, chamber)
    sim.start()
    yield sim
    sim.stop()


@pytest.fixture
def f4(server):
    driver = WatlowF4.open(f"modbus-tcp://127.0.0.1:{server.port}", timeout_s=TIMEOUT_S)
    yield driver
    driver.close()


@pytest.fixture
def gauge_sim(clock, chamber):
    sim = Tpg261Sim(clock, chamber)
    name = f"tvac.gauge.{next(_names)}"
    sim.url = registry.register(name, sim)
    yield sim
    registry.unregister(name)


@pytest.fixture
def gauge(gauge_sim):
    driver = Tpg261.open(gauge_sim.url, timeout_s=TIMEOUT_S)
    yield driver
    driver.close()


# ---- Watlow F4 over Modbus/TCP ------------------------------------------------------------------
def test_pv_reads_chamber_air_and_mount(f4, clock, chamber):
    f4.set_set_point_c(60.0)
    clock.sleep(1200)
    assert f4.read_air_temp_c() == pytest.approx(chamber.air_temp_c(clock.now()), abs=0.05)
    assert f4.read_mount_temp_c() == pytest.approx(chamber.mount_temp_c(clock.now()), abs=0.05)
    assert f4.read_air_temp_c() > 25.0
    assert f4.read_output_pct() == pytest.approx(chamber.output_pct(clock.now()), abs=0.01)


def test_set_point_write_reaches_chamber(f4, chamber):
    f4.set_set_point_c(-12.3)
    assert chamber.set_point_c == pytest.approx(-12.3)
    assert f4.read_set_point_c() == pytest.approx(-12.3)
    f4.set_ramp_rate_c_per_min(1.5)
    assert chamber.ramp_rate_c_per_min == pytest.approx(1.5)
    assert f4.read_set_point_limits_c() == chamber.set_point_limits_c


def test_out_of_limit_set_point_is_exception_3(f4, chamber):
    with pytest.raises(ProtocolError, match=r"exception 3 \(illegal data value\).*register 300"):
        f4.set_set_point_c(chamber.set_point_limits_c[1] + 1.0)
    assert chamber.set_point_c == pytest.approx(20.0)


def test_raw_client_sees_exceptions_2_3_and_1(server):
    client = ModbusTcpClient("127.0.0.1", port=server.port, timeout=TIMEOUT_S, retries=0)
    assert client.connect()
    try:
        assert client.read_holding_registers(100, count=1, device_id=1).registers == [200]  # 20.0 °C raw
        rr = client.read_holding_registers(101, count=1, device_id=1)
        assert rr.isError() and rr.exception_code == 2
        rr = client.read_holding_registers(99, count=2, device_id=1)  # range touching an unmapped one
        assert rr.isError() and rr.exception_code == 2
        rr = client.write_register(100, 5, device_id=1)  # PV is read-only: 2 (Watlow Comms Guide p. 15)
        assert rr.isError() and rr.exception_code == 2
        rr = client.write_register(300, 2000, device_id=1)  # 200.0 °C above the set point limit
        assert rr.isError() and rr.exception_code == 3
        rr = client.read_input_registers(100, count=1, device_id=1)  # FC 4 not served
        assert rr.isError() and rr.exception_code == 1
        assert not client.write_registers(300, [250], device_id=1).isError()  # FC 16
        assert client.read_holding_registers(300, count=1, device_id=1).registers == [250]
    finally:
        client.close()


def test_negative_temperatures_are_signed(f4, clock, chamber):
    f4.set_set_point_c(-30.0)
    clock.sleep(6 * 3600)
    assert f4.read_air_temp_c() == pytest.approx(chamber.air_temp_c(clock.now()), abs=0.05)
    assert f4.read_air_temp_c() < -25.0


def test_mbpoll_reads_pv_at_raw_address_100(server, clock, chamber):
    mbpoll = find_program("mbpoll")
    if mbpoll is None:
        pytest.skip("mbpoll not installed (apt-get install mbpoll): raw-address check with a foreign client not run")
    chamber.command_set_point(clock.now(), 45.0)
    clock.sleep(900)
    expected = round(chamber.air_temp_c(clock.now()) * 10)
    out = subprocess.run([mbpoll, "-m", "tcp", "-p", str(server.port), "-a", "1", "-0", "-r", "100", "-c", "1",
                          "-1", "127.0.0.1"], capture_output=True, text=True, timeout=10)
    assert f"[100]: \t{expected}" in out.stdout, out.stdout + out.stderr


def test_traffic_hook_sees_request_and_answer_adus(server):
    seen = []
    driver = WatlowF4.open(f"modbus-tcp://127.0.0.1:{server.port}", timeout_s=TIMEOUT_S,
                           on_traffic=lambda d, n, raw: seen.append((d, n, raw)))
    try:
        driver.read_air_temp_c()
    finally:
        driver.close()
    cmd = [s for s in seen if s[1] == "read 100"]
    assert [d for d, _, _ in cmd] == ["command", "reply"]
    assert cmd[0][2][6:] == bytes([1, 3, 0, 100, 0, 1])  # MBAP header, then unit 1, FC 3, addr 100, count 1


def test_fault_exception_code(f4, server):
    server.inject("exception", code=4)
    with pytest.raises(ProtocolError, match=r"exception 4 \(server device failure\).*register 100"):
        f4.read_air_temp_c()
    server.inject("exception", code=6)  # busy: retried, then reported
    with pytest.raises(ProtocolError, match="busy"):
        f4.read_set_point_c()
    server.clear_faults()
    assert f4.read_set_point_c() == pytest.approx(20.0)


def test_fault_timeout_is_instrument_timeout_within_timeout(f4, server):
    server.inject("timeout")
    t0 = time.monotonic()
    with pytest.raises(InstrumentTimeout):
        f4.read_air_temp_c()
    assert time.monotonic() - t0 < TIMEOUT_S + 0.5
    with pytest.raises(InstrumentTimeout, match="not retried"):
        f4.set_set_point_c(30.0)
    server.clear_faults()
    assert f4.read_air_temp_c() == pytest.approx(20.0)


def test_fault_runaway_and_stuck(f4, server, clock, chamber):
    server.inject("runaway", rate_c_per_min=5.0)
    clock.sleep(600)
    assert f4.read_air_temp_c() == pytest.approx(20.0 + 50.0, abs=0.1)
    assert chamber.air_temp_c(clock.now()) == pytest.approx(20.0, abs=0.1)
    assert f4.read_alarms()["high_deviation"]
    server.clear_faults()
    f4.set_set_point_c(60.0)
    server.inject("stuck")
    frozen = f4.read_air_temp_c()
    clock.sleep(1200)
    assert f4.read_air_temp_c() == frozen
    assert chamber.air_temp_c(clock.now()) > frozen + 5


def test_fault_open_sensor_is_device_fault(f4, server):
    server.inject("open_sensor", input=1)
    with pytest.raises(DeviceFault, match="open sensor"):
        f4.read_air_temp_c()
    alarms = f4.read_alarms()
    assert alarms["input_1_error"] and alarms["input_1_code"] == "open sensor"


def test_fault_disconnect_then_refused_then_back(f4, server):
    server.inject("disconnect")
    with pytest.raises(InstrumentError):
        f4.read_air_temp_c()
    with pytest.raises(InstrumentError, match="cannot connect"):
        WatlowF4.open(f"modbus-tcp://127.0.0.1:{server.port}", timeout_s=TIMEOUT_S)
    server.clear_faults()
    assert f4.read_air_temp_c() == pytest.approx(20.0)


def test_events_switch_pump_and_vent(f4, chamber):
    f4.set_event(1, True)
    f4.set_event(2, True)
    assert chamber.pump_on and chamber.vent_open
    assert f4.read_event(1) and f4.read_event(2)
    f4.set_event(2, False)
    assert not chamber.vent_open


# ---- register scaling ---------------------------------------------------------------------------
@given(reg=st.sampled_from(REGISTERS), raw=st.integers(0, 0xFFFF))
def test_register_raw_round_trip(reg, raw):
    assert reg.encode(reg.decode(raw)) == raw


@given(value=st.floats(-3276.8, 3276.7, allow_nan=False))
def test_temperature_value_round_trip(value):
    reg = BY_NAME["set_point_1"]
    assert abs(reg.decode(reg.encode(value)) - value) <= 0.05 + 1e-9


# ---- TPG 261 over sim:// ------------------------------------------------------------------------
# A PKR is a logarithmic gauge: its 3rd and 4th decimals are always 0 (BG 5195 BEN/A p71), so a
# reading carries 3 significant digits, 0.5 % at worst.
PKR_REL = 5e-3
def test_gauge_reads_chamber_pressure_in_torr(gauge, gauge_sim, clock, chamber):
    assert gauge.read_pressure_torr() == pytest.approx(760.0, rel=PKR_REL)
    chamber.set_pump(clock.now(), True)
    clock.sleep(1800)
    assert gauge.read_pressure_torr() == pytest.approx(chamber.pressure_torr(clock.now()), rel=PKR_REL)
    assert gauge.identify()["gauges"] == "PKR,noSEn"


def test_gauge_sets_torr_at_open_and_converts_other_units(gauge_sim, clock, chamber):
    gauge_sim.units = 0  # left in mbar by somebody at the front panel
    clock.sleep(3.5)  # power-up continuous mode: readings are waiting in the port
    driver = Tpg261.open(gauge_sim.url, timeout_s=TIMEOUT_S)
    try:
        assert gauge_sim.units == 1 and not gauge_sim.streaming
        for code in (0, 2):
            driver.set_units(code)
            assert gauge_sim.units == code
            assert driver.read_pressure_torr() == pytest.approx(760.0, rel=PKR_REL)
    finally:
        driver.close()


@pytest.mark.parametrize("status, meaning", [(3, "sensor error"), (4, "sensor off"), (5, "no sensor")])
def test_gauge_status_is_device_fault(gauge, gauge_sim, status, meaning):
    gauge_sim.inject("sensor_error", status=status)
    with pytest.raises(DeviceFault, match=meaning):
        gauge.read_pressure_torr()


def test_gauge_underrange_returns_value_with_status(gauge, gauge_sim):
    gauge_sim.inject("stuck", torr=1e-13)  # below the PKR's range end
    reading = gauge.read_pressure()
    assert reading.status == 1 and reading.status_text == "underrange"
    assert reading.torr == pytest.approx(1e-13, rel=1e-3)


def test_gauge_nak_is_protocol_error(gauge):
    with pytest.raises(ProtocolError, match=r"NAK.*'XYZ'.*0001"):
        gauge.command("XYZ")
    with pytest.raises(ProtocolError, match="NAK"):
        gauge.command("UNI,7")
    assert gauge.read_pressure_torr() == pytest.approx(760.0, rel=PKR_REL)


def test_gauge_garbage_and_stall_are_typed(gauge, gauge_sim, clock):
    gauge_sim.inject("garbage")
    with pytest.raises(ProtocolError):
        gauge.read_pressure_torr()
    gauge_sim.inject("garbage", data=b"0,7.60E+02\r\n")
    with pytest.raises(ProtocolError, match="is not"):
        gauge.read_pressure_torr()
    gauge_sim.clear_faults()
    gauge_sim.inject("stall")
    t0 = clock.now()
    with pytest.raises(InstrumentTimeout):
        gauge.read_pressure_torr()
    assert clock.now() - t0 <= TIMEOUT_S + 1e-9
    gauge_sim.clear_faults()
    assert gauge.read_pressure_torr() == pytest.approx(760.0, rel=PKR_REL)


@settings(max_examples=300)
@given(raw=st.binary(max_size=40) | st.from_regex(rb"\A[0-9],[+-]?[0-9]\.[0-9]{4}E[+-][0-9]{2}\r\n\Z"))
def test_pr1_decoder_never_raises_anything_else(raw):
    try:
        status, value = parse_pr_reply(raw)
    except ProtocolError:
        return
    assert 0 <= status <= 9 and isinstance(value, float)


# ---- composite ----------------------------------------------------------------------------------
@pytest.fixture
def tvac(server, gauge_sim):
    seen = []
    chamber_driver = TvacChamber.open(f"modbus-tcp://127.0.0.1:{server.port}", timeout_s=TIMEOUT_S,
                                      gauge_url=gauge_sim.url, safe_set_point_c=22.0,
                                      on_traffic=lambda d, n, raw: seen.append((d, n, raw)))
    chamber_driver.seen = seen
    yield chamber_driver
    chamber_driver.close()


def test_tvac_pump_down_vent_and_read(tvac, clock, chamber):
    tvac.pump_down()
    assert chamber.pump_on and not chamber.vent_open
    clock.sleep(600)
    state = tvac.read()
    assert state["pressure_torr"] < 1e-2 and state["pump_on"] and not state["vent_open"]
    assert set(state) == {"air_temp_c", "mount_temp_c", "set_point_c", "pressure_torr", "pump_on", "vent_open",
                          "output_pct", "alarms"}
    tvac.vent()
    assert not chamber.pump_on and chamber.vent_open
    clock.sleep(1800)
    assert tvac.read()["pressure_torr"] > 700.0
    names = {n for _, n, _ in tvac.seen}
    assert "write 2000" in names and "PR1" in names


def test_tvac_safe_state_keeps_vacuum(tvac, chamber, clock):
    tvac.pump_down()
    tvac.set_point(-20.0, ramp_c_per_min=1.0)
    assert chamber.set_point_c == -20.0 and chamber.ramp_rate_c_per_min == 1.0
    tvac.safe_state()
    assert chamber.set_point_c == 22.0 and chamber.ramp_rate_c_per_min == 0.0
    assert chamber.pump_on and not chamber.vent_open


def test_tvac_identify(tvac):
    ident = tvac.identify()
    assert set(ident) >= {"vendor", "model", "serial", "firmware"}
    assert "PKR" in ident["model"] and "units=1" in ident["model"]
