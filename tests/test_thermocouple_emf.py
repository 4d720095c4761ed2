"""NIST ITS-90 type K/T reference functions and the physical thermocouple-logger simulator."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.clock import VirtualClock
from bench.config import load_config
from bench.sim import registry
from bench.sim.factory import build_devices
from bench.sim.thermocouple_emf import (EMF_RANGE_MV, INVERSE_ERROR_C, emf_to_temp_c, seebeck_uv_per_c,
                                        temp_to_emf_mv)
from bench.sim.thermocouple_reader import IDEAL, KEYSIGHT_34970A, ThermocoupleReaderSim
from drivers.thermocouple_reader import ThermocoupleReader
from tests.conftest import ROOT

# NIST Monograph 175 / ITS-90 database tables (mV, reference junction at 0 °C)
NIST_K = [(-200, -5.891), (-100, -3.554), (0, 0.0), (20, 0.798), (100, 4.096), (500, 20.644), (1000, 41.276),
          (1372, 54.886)]
NIST_T = [(-200, -5.603), (-100, -3.379), (0, 0.0), (20, 0.790), (100, 4.279), (200, 9.288), (400, 20.872)]


@pytest.mark.parametrize("kind, table", [("K", NIST_K), ("T", NIST_T)])
def test_reference_function_matches_nist_tables(kind, table):
    temps, emfs = np.array(table, dtype=float).T
    assert np.allclose(temp_to_emf_mv(temps, kind), emfs, atol=0.0005)  # tables print 1 µV
    for t, e in table:
        assert temp_to_emf_mv(t, kind) == pytest.approx(e, abs=0.0005)
    # back again: the polynomial's error plus the table's 0.5 µV rounding seen through the slope
    tolerance = INVERSE_ERROR_C[kind] + 0.5 / seebeck_uv_per_c(temps, kind)
    assert np.all(np.abs(emf_to_temp_c(emfs, kind) - temps) <= tolerance)


def test_seebeck_coefficient_near_room_temperature():
    # slope of the NIST table between 0 and 50 °C: K 2.023 mV / 50 °C, T 2.036 mV / 50 °C
    assert seebeck_uv_per_c(25.0, "K") == pytest.approx(2023 / 50, rel=0.01)
    assert seebeck_uv_per_c(25.0, "T") == pytest.approx(2036 / 50, rel=0.02)


def test_out_of_range_raises_naming_the_range():
    with pytest.raises(ValueError, match="-270..1372"):
        temp_to_emf_mv(1400.0, "K")
    with pytest.raises(ValueError, match="-270..400"):
        temp_to_emf_mv(np.array([20.0, 450.0]), "T")
    with pytest.raises(ValueError, match="-5.603..20.872 mV"):
        emf_to_temp_c(25.0, "T")
    with pytest.raises(ValueError, match="one of"):
        temp_to_emf_mv(20.0, "J")


@settings(max_examples=200, deadline=None)
@given(kind=st.sampled_from(["K", "T"]), frac=st.floats(0.0, 1.0))
def test_inverse_round_trip(kind, frac):
    hi = {"K": 1372.0, "T": 400.0}[kind]
    t = -200.0 + frac * (hi + 200.0)
    e = temp_to_emf_mv(t, kind)
    # the NIST inverse polynomials alone: within their stated error (K 500..1372 °C: -0.05..+0.06 °C)
    assert abs(emf_to_temp_c(e, kind) - t) <= INVERSE_ERROR_C[kind]
    assert emf_to_temp_c(e, kind, exact=True) == pytest.approx(t, abs=1e-6)


def test_vectorised_shapes():
    t = np.linspace(-50, 150, 12).reshape(3, 4)
    e = temp_to_emf_mv(t, "K")
    assert e.shape == (3, 4) and np.allclose(emf_to_temp_c(e, "K", exact=True), t, atol=1e-8)
    lo, hi = EMF_RANGE_MV["T"]
    assert emf_to_temp_c(np.array([lo, hi]), "T") == pytest.approx([-200.0, 400.0], abs=0.05)


# ---- simulator through the real driver ----------------------------------------------------------
@pytest.fixture
def bench():
    """World and clock of the rotating-bench configuration; ``make(**kwargs)`` builds a logger
    simulator on that world, registers it and returns (sim, driver)."""
    config = load_config(ROOT / "configs" / "sim_rotating_bench.yaml")
    clock = VirtualClock()
    base = build_devices(config, clock, ["thermocouples"])["thermocouples"].device
    names = []

    def make(**kwargs):
        dev = ThermocoupleReaderSim(clock, base.world, **kwargs)
        name = f"tc_emf_{id(dev)}"
        names.append(name)
        return dev, ThermocoupleReader.open(registry.register(name, dev))

    yield base.world, clock, make
    for name in names:
        registry.unregister(name)


def heat(world, clock, sp_c=60.0, hours=3.0):
    world.chamber.command_set_point(clock.now(), sp_c)
    clock.sleep(hours * 3600.0)
    return world.chamber.mount_temp_c(clock.now())


def test_ideal_logger_reads_mount_air_and_die(bench):
    world, clock, make = bench
    dev, tc = make(points={102: "air", 103: "die"})
    world.set_unit_power(clock.now(), True)
    mount = heat(world, clock, 50.0, 2.0)
    tc.configure([101, 102, 103], "K")
    scan = tc.read()
    now = clock.now()
    assert scan.temps_c[101] == pytest.approx(mount, abs=1e-6)
    assert scan.temps_c[102] == pytest.approx(world.chamber.air_temp_c(now), abs=1e-6)
    assert scan.temps_c[103] == pytest.approx(float(world.unit_temperature_c([now])[0]), abs=1e-6)
    assert scan.temps_c[103] > scan.temps_c[101] + 3.0  # the powered die runs warmer than its mount
    with pytest.raises(ValueError):
        make(points={101: "shroud"})


def test_realistic_logger_accuracy_and_noise(bench):
    world, clock, make = bench
    # exact EMF -> temperature conversion, so the test can recover the quantised voltages
    spec = dataclasses.replace(KEYSIGHT_34970A, exact_conversion=True)
    dev, tc = make(spec=spec, seed=3)
    mount = heat(world, clock)
    assert 55.0 < mount < 61.0
    tc.configure([101, 102], "K")
    readings = np.array([[tc.read().temps_c[c] for c in (101, 102)] for _ in range(300)])
    # within the stated thermocouple accuracy, reference-junction error included
    assert np.all(np.abs(readings - mount) <= spec.tc_accuracy_c)
    # the reference junction is off by its fixed offset, within its stated accuracy
    rj = tc.reference_junction_c(101)
    assert rj == pytest.approx(20.0 + dev.rj_offset_c, abs=1e-6) and abs(rj - 20.0) <= spec.rj_accuracy_c
    # mean error = reference-junction offset seen through the two Seebeck coefficients
    predicted_bias = dev.rj_offset_c * seebeck_uv_per_c(20.0, "K") / seebeck_uv_per_c(mount, "K")
    assert readings.mean() - mount == pytest.approx(predicted_bias, abs=0.01)
    # scatter = voltage noise (plus quantisation) over the Seebeck coefficient at the reading
    sigma_uv = np.hypot(spec.noise_uv_rms, spec.resolution_uv / np.sqrt(12))
    predicted_sigma = sigma_uv / seebeck_uv_per_c(mount, "K")
    assert readings.std(axis=0) == pytest.approx([predicted_sigma, predicted_sigma], rel=0.15)
    # readings sit on the DMM's voltage grid
    volts_uv = (temp_to_emf_mv(readings, "K") - temp_to_emf_mv(rj, "K")) * 1000.0
    assert np.allclose(volts_uv, np.round(volts_uv / spec.resolution_uv) * spec.resolution_uv, atol=1e-4)


def test_seeded_and_deterministic(bench):
    world, clock, make = bench
    heat(world, clock, 40.0, 1.0)
    runs = []
    for seed in (7, 7, 8):
        dev, tc = make(spec=KEYSIGHT_34970A, seed=seed)
        tc.configure([101, 102, 103], "K")
        runs.append([tc.read().temps_c for _ in range(5)])
    assert runs[0] == runs[1] and runs[0] != runs[2]


def test_wrong_type_reads_wrong_by_the_predicted_amount(bench):
    world, clock, make = bench
    dev, tc = make(installed_types="K")
    mount = heat(world, clock)
    tc.configure([101], "T")  # K wire, logger set for T
    wrong = tc.read().temps_c[101]
    emf = temp_to_emf_mv(mount, "K") - temp_to_emf_mv(20.0, "K")
    predicted = emf_to_temp_c(emf + temp_to_emf_mv(20.0, "T"), "T", exact=True)
    assert wrong == pytest.approx(predicted, abs=1e-6)
    assert abs(wrong - mount) > 0.3  # K and T differ by ~1 % in slope near room temperature
    tc.configure([101], "K")
    assert tc.read().temps_c[101] == pytest.approx(mount, abs=1e-6)


def test_fault_open(bench):
    world, clock, make = bench
    dev, tc = make(spec=KEYSIGHT_34970A)
    heat(world, clock, 40.0, 1.0)
    tc.configure([101, 102], "K")
    dev.inject("open", 102)
    scan = tc.read()
    assert scan.open_channels == [102] and scan.temps_c[102] is None and scan.temps_c[101] is not None
    tc.channel.send("SENS:TEMP:TRAN:TC:CHEC OFF,(@102)")
    floating = [tc.read().temps_c[102] for _ in range(20)]
    assert all(v is not None for v in floating) and np.std(floating) > 0.1  # garbage, near the room
    dev.clear_faults()
    assert abs(tc.read().temps_c[102] - world.chamber.mount_temp_c(clock.now())) < 1.0


def test_fault_open_channels_argument_still_works(bench):
    world, clock, make = bench
    dev, tc = make(open_channels=(104,))
    tc.configure([103, 104], "K")
    assert tc.read().open_channels == [104]
    dev.clear_faults()
    assert tc.read().open_channels == [104]  # a wiring fault from the configuration stays


def test_fault_stuck(bench):
    world, clock, make = bench
    dev, tc = make(spec=KEYSIGHT_34970A)
    tc.configure([101, 102], "K")
    heat(world, clock, 60.0, 0.5)
    before = tc.read().temps_c
    dev.inject("stuck", 101)
    frozen = tc.read().temps_c[101]
    assert abs(frozen - before[101]) < 0.2
    clock.sleep(1800.0)  # the chamber keeps heating
    later = tc.read().temps_c
    assert later[101] == frozen and later[102] > before[102] + 2.0


def test_fault_runaway(bench):
    world, clock, make = bench
    dev, tc = make()
    tc.configure([101, 102], "K")
    dev.inject("runaway", 102, rate_c_per_min=2.0)
    clock.sleep(600.0)
    scan = tc.read()
    assert scan.temps_c[101] == pytest.approx(20.0, abs=1e-6)
    assert scan.temps_c[102] == pytest.approx(40.0, abs=1e-6)  # 10 min at 2 °C/min
    with pytest.raises(ValueError):
        dev.inject("runaway", 102)
    with pytest.raises(ValueError):
        dev.inject("melted", 102)


def test_fault_noisy(bench):
    world, clock, make = bench
    dev, tc = make()
    tc.configure([101, 102], "K")
    dev.inject("noisy", channel=None, sigma_c=0.5)
    values = np.array([[tc.read().temps_c[c] for c in (101, 102)] for _ in range(200)])
    assert values.std(axis=0) == pytest.approx([0.5, 0.5], rel=0.2)
    assert values.mean(axis=0) == pytest.approx([20.0, 20.0], abs=0.15)
    dev.clear_faults(101)
    assert tc.read().temps_c[101] == pytest.approx(20.0, abs=1e-6)


def test_ideal_is_default():
    assert ThermocoupleReaderSim.__init__.__kwdefaults__["spec"] is None and IDEAL.noise_uv_rms == 0.0


def test_firmware_conversion_stays_within_the_nist_inverse_error(bench):
    """The 34970A preset converts with the NIST inverse polynomials, as firmware does: readings
    differ from the exact conversion by at most the polynomial's stated error."""
    world, clock, make = bench
    mount = heat(world, clock)
    _, exact = make(spec=dataclasses.replace(KEYSIGHT_34970A, noise_uv_rms=0.0, resolution_uv=0.0, exact_conversion=True), seed=3)
    _, firmware = make(spec=dataclasses.replace(KEYSIGHT_34970A, noise_uv_rms=0.0, resolution_uv=0.0), seed=3)
    for tc in (exact, firmware):
        tc.configure([101], "K")
    a, b = exact.read().temps_c[101], firmware.read().temps_c[101]
    assert 0 < abs(a - b) <= INVERSE_ERROR_C["K"]
    assert abs(a - mount) < 1.0
