"""Sensor error models (bench/model/) and model files (configs/sensors/).

Expected values are computed here by hand from the seed documents' published numbers, not taken
from the model code: NPSAT1 thesis (seed 000), NASA AMS report (seed 001), ESTCube-2 thesis (004).
"""

from __future__ import annotations

import dataclasses
import math
import sys
import types
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.errors import InputError, InputErrors
from bench.model import adc, digital
from bench.model.accel import NasaSensorParams, model_rate, nasa_sensor_input, nasa_sensor_output, sting_gravity
from bench.model.gyro import (
    GyroModel,
    GyroModelParams,
    bias_instability_processes,
    deterministic_output_dps,
    gyro_output,
    in_run_temperature_bias_dps,
    pressure_bias_dps,
    two_level_bias_dps,
)
from bench.model.inputs import SensorInputs, stationary_inputs
from bench.model.loader import load_sensor_model, parse_sensor_model

ROOT = Path(__file__).resolve().parents[1]
SENSORS = ROOT / "configs" / "sensors"
CONFIGS = sorted(SENSORS.glob("*.yaml"))


def adev(y: np.ndarray, fs: float, tau_s: float) -> np.ndarray:
    """Non-overlapping Allan deviation of rate columns ``y`` (n, k) at cluster time ``tau_s``
    (NPSAT1 Eq. 18-20)."""
    m = int(round(tau_s * fs))
    k = y.shape[0] // m
    means = y[: k * m].reshape(k, m, -1).mean(axis=1)
    return np.sqrt(0.5 * np.mean(np.diff(means, axis=0) ** 2, axis=0))


def noise_only(**kw) -> GyroModelParams:
    return GyroModelParams(**kw)


# ---- model files ---------------------------------------------------------------------------------
@pytest.mark.parametrize("path", CONFIGS, ids=[p.name for p in CONFIGS])
def test_every_model_file_loads(path: Path):
    spec = load_sensor_model(path)
    built = {"imu_simple": spec.imu, "npsat1_gyro": spec.gyro, "nasa_sensor": spec.nasa_packages or None}[spec.model]
    assert built is not None
    text = path.read_text()
    assert "schema: bench-sensor-model/1" in text
    if spec.model != "imu_simple":  # every number of the new files cites its seed
        assert "seed 00" in text


def test_expected_files_exist():
    names = {p.name for p in CONFIGS}
    for name in ("acs_board_simple.yaml", "npsat1_qrs11_ground.yaml", "npsat1_qrs11_spacecraft.yaml",
                 "estcube_bmg160.yaml", "estcube_mpu6000.yaml", "estcube_l3gd20h.yaml",
                 "nasa_accel_table3.yaml", "nasa_gyro_table4.yaml"):
        assert name in names


def test_acs_board_simple_still_valid_for_the_lab_config():
    from bench.config import load_config

    config = load_config(ROOT / "configs" / "sim.yaml")
    assert config.instruments["acs_board"].sim.settings.model.gyro_bias_poly_degc == [-1.150e-1, -7.561e-3, -1.124e-4]


# ---- NPSAT1 published coefficients ---------------------------------------------------------------
def test_table4_ground_polynomial_hand_value():
    p = load_sensor_model(SENSORS / "npsat1_qrs11_ground.yaml").gyro
    # Table 4 X at 25 degC: 0.05232 - 0.00309*25 + 1.61507e-5*25^2 - 2.06176e-7*25^3
    x25 = 0.05232 - 0.07725 + 0.0100941875 - 0.0032215
    # Table 4 Z at -10 degC: 0.06502 + 0.0144 + 2.71648e-5*100 + 2.97345e-7*1000
    zm10 = 0.06502 + 0.0144 + 0.00271648 + 0.000297345
    b = in_run_temperature_bias_dps(p, np.array([25.0, -10.0]))
    assert b[0, 0] == pytest.approx(x25, abs=1e-12)
    assert b[1, 2] == pytest.approx(zm10, abs=1e-12)


def test_table8_spacecraft_polynomial_and_table15_terms():
    p = load_sensor_model(SENSORS / "npsat1_qrs11_spacecraft.yaml").gyro
    assert in_run_temperature_bias_dps(p, np.array([0.0]))[0] == pytest.approx([0.10358, 0.04631, 0.09842])
    assert p.b_cons_dps == [7.18e-3, -8.12e-3, 7.00e-3]  # Table 15 b_const(B-dot)
    assert p.misalignment_pct == [[0.042, 0.102, 1.298], [-0.156, -0.4, 0.128], [-0.2, -0.139, 0.506]]
    assert p.arw_deg_rth == [0.3546, 0.386, 0.352] and p.bias_instability_dph == [1.920, 0.886, 2.381]  # Table 13


def test_table15_volts_polynomial_hand_value():
    # Table 15 / Table 7 X in volts at T_m = -0.5042 V (25.7 degC by Eq. 10), divided by S_f = 0.5 (Eq. 8)
    p = load_sensor_model(SENSORS / "npsat1_qrs11_spacecraft_volts.yaml").gyro
    tm = -0.5042
    volts = -0.00809 - 0.05675 * tm - 0.0107 * tm**2 - 0.00503 * tm**3
    assert in_run_temperature_bias_dps(p, np.array([25.7]))[0, 0] == pytest.approx(volts / 0.5, abs=1e-12)


@pytest.mark.parametrize("kind", ["ground", "spacecraft"])
def test_volts_and_degc_tables_describe_the_same_fit(kind):
    """Tables 3/4 (and 7/8) are one fit in two unit systems; through Eq. 10-12 and S_f they agree
    over the qualification range -29..+66 degC (IV.C) to the published digits (~1e-3 deg/s)."""
    t = np.linspace(-29.0, 66.0, 40)
    a = in_run_temperature_bias_dps(load_sensor_model(SENSORS / f"npsat1_qrs11_{kind}.yaml").gyro, t)
    b = in_run_temperature_bias_dps(load_sensor_model(SENSORS / f"npsat1_qrs11_{kind}_volts.yaml").gyro, t)
    assert np.max(np.abs(a - b)) < 3e-3


def test_pressure_term_ground_and_spacecraft():
    g = load_sensor_model(SENSORS / "npsat1_qrs11_ground.yaml").gyro
    s = load_sensor_model(SENSORS / "npsat1_qrs11_spacecraft.yaml").gyro
    shift = np.array([0.02808, 0.00209, 0.02039]) / 0.5  # Table 6 row 5.9E-6..1E-5 Torr, V / S_f
    assert pressure_bias_dps(g, np.array([760.0]))[0] == pytest.approx([0, 0, 0], abs=1e-12)
    assert pressure_bias_dps(g, np.array([1e-5]))[0] == pytest.approx(shift * (1 - 1 / (1 + 760 / 200)), rel=1e-6)
    assert pressure_bias_dps(s, np.array([1e-5]))[0] == pytest.approx([0, 0, 0], abs=1e-9)
    # monotonic, smooth transition
    p = np.logspace(-7, 3, 50)
    b = pressure_bias_dps(g, p)[:, 0]
    assert np.all(np.diff(b) < 0)
    # ground polynomial + vacuum shift ~ spacecraft polynomial: B differences ~0.05/0.01/0.03 deg/s (IV.D.3.b)
    assert shift == pytest.approx([0.0513, 0.0137, 0.0334], abs=0.011)


def test_estcube_two_level_matches_table_4_1_and_imu_simple():
    p = load_sensor_model(SENSORS / "estcube_mpu6000.yaml").gyro
    rate = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 3.0]])
    temp = np.array([20.0, -20.0])
    b = two_level_bias_dps(p, rate, temp)
    # omega = 0: p1..p3 = third column of Table 4.1 (p1-MPU 1.124e-4, p2-MPU 7.561e-3, p3-MPU 1.150e-1)
    assert b[0, 2] == pytest.approx(-(1.124e-4 * 400 + 7.561e-3 * 20 + 0.115), abs=1e-12)
    # omega = 3 deg/s at -20 degC
    p1 = 7.840e-6 * 9 - 2.124e-5 * 3 + 1.124e-4
    p2 = -2.137e-4 * 9 + 6.094e-4 * 3 + 7.561e-3
    p3 = -6.072e-3 * 9 + 1.587e-2 * 3 + 1.150e-1
    assert b[1, 2] == pytest.approx(-(p1 * 400 - p2 * 20 + p3), abs=1e-12)
    assert b[:, :2] == pytest.approx(np.zeros((2, 2)))
    simple = load_sensor_model(SENSORS / "acs_board_simple.yaml").imu
    assert np.polynomial.polynomial.polyval(20.0, simple.gyro_bias_poly_degc) == pytest.approx(b[0, 2])


def test_deterministic_model_eq1_terms():
    p = GyroModelParams(b_cons_dps=[0.01, 0.02, 0.03], misalignment_pct=[[1, 0, 0], [0, 0, 2], [0, 0, 0]],
                        warmup_amplitude_dps=[0.1, 0, 0], warmup_tau_s=[100, 1, 1], rate_ramp_dph_per_h=[0, 3600, 0])
    inp = SensorInputs(time_s=[0.0, 100.0], rate_dps=[1.0, 0.0, 4.0], temp_c=20.0, power_on_s=[0.0, 3600.0])
    out = deterministic_output_dps(p, inp)
    assert out[0] == pytest.approx([1.0 + 0.01 + 0.01 + 0.1, 0.02 + 0.08, 4.03])
    # one hour later: warm-up gone (e^-36), ramp 3600 deg/h/h * 1 h = 3600 deg/h = 1 deg/s on y
    assert out[1] == pytest.approx([1.02, 0.02 + 0.08 + 1.0, 4.03], abs=1e-12)


# ---- ADC (NPSAT1 Eq. 4-12) and digital path -----------------------------------------------------
P_ADC = adc.AdcParams()


def test_adc_equations_hand_values():
    assert P_ADC.lsb_v == pytest.approx(5 / 4095) and P_ADC.lsb_v * 1e3 == pytest.approx(1.22, abs=0.005)  # "1.22 mV"
    assert adc.decode_rate(2048, P_ADC) == pytest.approx((2048 / 4095 * 5 - 2.5) / 0.5)  # Eq. 5, 8
    assert adc.decode_rate(adc.encode_rate(0.0, P_ADC), P_ADC) == pytest.approx(0.0, abs=P_ADC.lsb_dps)
    # Eq. 10-12 at the nominal voltages give T_ave (Table 2)
    assert adc.channel_v_to_temp_c(np.array([-0.5042, -0.4909, -0.5071]), P_ADC) == pytest.approx([25.7, 25.4, 25.3])
    assert adc.channel_v_to_temp_c(np.array([0.0, 0.0, 0.0]), P_ADC)[0] == pytest.approx(25.7 + 0.5042 / 0.0264)
    assert P_ADC.rate_range_dps() == (-5.0, 5.0)
    assert adc.encode_rate(np.array([-100.0, 100.0]), P_ADC).tolist() == [0, 4095]  # clipped


@settings(max_examples=200, deadline=None)
@given(st.floats(min_value=-5.0, max_value=5.0, allow_nan=False))
def test_adc_rate_encode_decode_inverse_within_one_lsb(rate):
    back = adc.decode_rate(adc.encode_rate(rate, P_ADC), P_ADC)
    assert abs(float(back) - rate) <= P_ADC.lsb_dps


@settings(max_examples=100, deadline=None)
@given(st.floats(min_value=-29.0, max_value=66.0, allow_nan=False))
def test_adc_temperature_encode_decode_inverse_within_one_lsb(temp):
    back = adc.decode_temperature(adc.encode_temperature(temp, P_ADC), P_ADC)
    assert np.all(np.abs(back - temp) <= P_ADC.lsb_v / P_ADC.temp_slope_v_per_c)


def test_adc_counts_round_trip_exactly():
    counts = np.arange(4096)
    assert np.array_equal(adc.encode_rate(adc.decode_rate(counts, P_ADC), P_ADC), counts)


@settings(max_examples=100, deadline=None)
@given(st.floats(min_value=-250.0, max_value=250.0 - 250.0 / 2**15, allow_nan=False))
def test_digital_quantise_within_half_lsb(rate):
    p = digital.DigitalParams()
    assert p.lsb == pytest.approx(0.0076, abs=1e-4)  # ESTCube-2 Table 2.1 MPU-6000 resolution
    assert abs(float(digital.counts_to_dps(digital.quantise(rate, p), p)) - rate) <= p.lsb / 2 + 1e-12


def test_moving_average_batches_equal_one_call_and_prefill():
    rng = np.random.default_rng(3)
    x = rng.standard_normal((500, 3))
    whole, _ = digital.moving_average(x, 40)
    ma = digital.MovingAverage(40)
    parts = np.concatenate([ma(x[a:b]) for a, b in [(0, 1), (1, 77), (77, 300), (300, 500)]])
    assert np.allclose(parts, whole)
    assert np.allclose(whole[0], x[0])  # buffer pre-filled with the first sample (ESTCube-2 3.3)
    assert np.allclose(whole[1], (39 * x[0] + x[1]) / 40)
    assert np.allclose(whole[39], x[:40].mean(axis=0)) and np.allclose(whole[100], x[61:101].mean(axis=0))


# ---- noise -----------------------------------------------------------------------------------------
def test_arw_matches_configured_allan_at_one_second():
    p = noise_only(arw_deg_rth=[0.3546, 0.386, 0.352])  # Table 13
    y = gyro_output(p, stationary_inputs(600.0, 100.0), np.random.default_rng(11))
    expected = np.array([0.3546, 0.386, 0.352]) / 60.0  # deg/sqrt(s): sigma(1 s) = N (Eq. 21)
    assert adev(y, 100.0, 1.0) == pytest.approx(expected, rel=0.12)
    assert y.std(axis=0) == pytest.approx(expected * math.sqrt(100.0), rel=0.03)  # sigma = N / sqrt(dt)


def test_bias_instability_plateau_and_rrw_slope():
    p = noise_only(bias_instability_dph=[20.0, 20.0, 20.0])
    taus, sig = bias_instability_processes(p)
    assert taus[0] == 1.0 and taus[-1] == pytest.approx(1e4) and len(taus) == 9
    y = gyro_output(p, stationary_inputs(40000.0, 1.0), np.random.default_rng(5))
    plateau = 0.664 * 20.0 / 3600.0  # Eq. 22
    assert adev(y, 1.0, 100.0).mean() == pytest.approx(plateau, rel=0.15)
    k = 50.0  # deg/h/sqrt(h)
    y = gyro_output(noise_only(rrw_deg_h_rth=[k] * 3), stationary_inputs(40000.0, 1.0), np.random.default_rng(6))
    ks = k / 3600.0 / 60.0
    assert adev(y, 1.0, 300.0).mean() == pytest.approx(ks * math.sqrt(300.0 / 3.0), rel=0.25)


def test_batching_gives_the_same_statistics_as_one_call():
    p = noise_only(arw_deg_rth=[0.35] * 3, bias_instability_dph=[8.0] * 3, rrw_deg_h_rth=[20.0] * 3)
    fs = 10.0
    inp = stationary_inputs(3000.0, fs)
    one = GyroModel(p, np.random.default_rng(1)).evaluate(inp)
    model = GyroModel(p, np.random.default_rng(2))
    cuts = np.unique(np.concatenate([[0, inp.n], np.random.default_rng(9).integers(1, inp.n, 60)]))
    batched = np.concatenate([model.evaluate(inp.select(slice(a, b))) for a, b in zip(cuts[:-1], cuts[1:])])
    assert batched.shape == one.shape
    for tau in (0.1, 1.0, 10.0, 100.0):
        assert adev(batched, fs, tau).mean() == pytest.approx(adev(one, fs, tau).mean(), rel=0.25), tau
    # the state carries over: steps across batch boundaries look like steps inside batches
    rrw = noise_only(rrw_deg_h_rth=[500.0] * 3)
    model = GyroModel(rrw, np.random.default_rng(4))
    inp = stationary_inputs(2000.0, 10.0)
    y = np.concatenate([model.evaluate(inp.select(slice(a, a + 10))) for a in range(0, inp.n, 10)])
    d = np.diff(y, axis=0)
    boundary = d[9::10]
    inside = np.delete(d, np.s_[9::10], axis=0)
    assert boundary.std() == pytest.approx(inside.std(), rel=0.2)


def test_run_to_run_bias_drawn_once_per_power_on():
    p = noise_only(run_to_run_sigma_dps=[0.016 / 3] * 3)
    model = GyroModel(p, np.random.default_rng(8))
    a = model.evaluate(stationary_inputs(10.0, 10.0))
    b = model.evaluate(stationary_inputs(10.0, 10.0, t0_s=10.0))  # same power-on, later samples
    assert np.allclose(a, a[0]) and np.allclose(b, a[0])
    c = model.evaluate(stationary_inputs(10.0, 10.0, t0_s=100.0, power_on_at_s=100.0))  # power cycled
    assert np.allclose(c, c[0]) and not np.allclose(c[0], a[0])
    # a short run after a power cycle: power_on_s does not drop below the last one, the instant moves
    d = model.evaluate(stationary_inputs(10.0, 10.0, t0_s=200.0, power_on_at_s=180.0))
    assert not np.allclose(d[0], c[0])
    draws = np.array([gyro_output(p, stationary_inputs(1.0, 1.0), np.random.default_rng(s))[0] for s in range(400)])
    assert draws.std() == pytest.approx(0.016 / 3, rel=0.1)


def test_adc_and_digital_output_paths():
    p = load_sensor_model(SENSORS / "npsat1_qrs11_ground.yaml").gyro
    model = GyroModel(p, np.random.default_rng(0))
    inp = stationary_inputs(2.0, 50.0, rate_dps=(1.0, -2.0, 0.5), temp_c=20.0)
    raw = model.evaluate_raw(inp)
    assert raw.dtype.kind == "i" and raw.min() >= 0 and raw.max() <= 4095
    out = adc.decode_rate(raw, p.adc)
    assert out.mean(axis=0) == pytest.approx([1.0, -2.0, 0.5], abs=0.2)
    e = load_sensor_model(SENSORS / "estcube_bmg160.yaml").gyro_model(np.random.default_rng(0))
    y = e.evaluate(stationary_inputs(5.0, 100.0, temp_c=20.0))
    lsb = 125.0 / 2**15  # Table 2.1 "16 bits / 0.0038 deg/s"
    assert lsb == pytest.approx(0.0038, abs=1e-4)
    assert np.allclose(np.round(y[0] / lsb) * lsb, y[0])  # first sample: buffer pre-filled -> one count
    # the moving average (N = 40) lowers the white noise by ~sqrt(40)
    n = load_sensor_model(SENSORS / "estcube_bmg160.yaml").gyro_model(np.random.default_rng(1), output="none")
    raw_std = n.evaluate(stationary_inputs(5.0, 100.0, temp_c=20.0)).std(axis=0)
    assert np.all(y[100:].std(axis=0) < raw_std / 4)


# ---- loader errors ---------------------------------------------------------------------------------
def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "model.yaml"
    p.write_text(text)
    return p


HEAD = "schema: bench-sensor-model/1\nmodel: npsat1_gyro\n"


@pytest.mark.parametrize("body, line, field", [
    ("b_cons_dps: [0, 0, 0]\nbogus_key: 1\n", 4, "bogus_key"),
    ("b_cons_dps: [0, 0]\n", 3, "b_cons_dps"),
    ("arw_deg_rth: [0.1, fast, 0.1]\n", 3, "arw_deg_rth[1]"),
    ("arw_deg_rth: [0.1, -1, 0.1]\n", 3, "arw_deg_rth[1]"),
    ("output: adc\nadc:\n  bits: twelve\n", 5, "adc.bits"),
    ("adc:\n  bitz: 12\n", 4, "adc.bitz"),
    ("misalignment_pct: [[1, 0, 0], [0, 1, 0]]\n", 3, "misalignment_pct"),
    ("two_level_correction:\n  w: [[0, 0, 0], [0, 0, 0], [0, 0, 0]]\n", 4, "two_level_correction.w"),
    ("output: analog\n", 3, "output"),
    ("effects:\n  - {effect: thermal_lag, axis: w}\n", 4, "effects[0].axis"),
    ("effects:\n  - {axis: z}\n", 4, "effects[0].effect"),
    ("effects:\n  - effect: thermal_lag\n    color: red\n", 5, "effects[0].color"),
    ("bias_instability_tau_range_s: [1.0, 1.0e4]\n", 3, "bias_instability_tau_range_s[1]"),
])
def test_loader_errors_are_located(tmp_path, body, line, field):
    path = write(tmp_path, HEAD + body)
    with pytest.raises(InputError) as err:
        load_sensor_model(path)
    msg = str(err.value)
    assert f"{path}:{line}:" in msg and f": {field}: " in msg, msg
    assert err.value.field == field


def test_loader_reports_several_errors_and_bad_model(tmp_path):
    path = write(tmp_path, HEAD + "b_cons_dps: [0]\nfoo: 1\n")
    with pytest.raises(InputErrors) as err:
        load_sensor_model(path)
    assert {e.field for e in err.value.errors} == {"b_cons_dps", "foo"}
    with pytest.raises(InputError, match="model: expected one of"):
        load_sensor_model(write(tmp_path, "schema: bench-sensor-model/1\nmodel: magic\nx: 1\n"))
    with pytest.raises(InputError, match="schema"):
        load_sensor_model(write(tmp_path, "schema: other/1\nmodel: npsat1_gyro\n"))
    with pytest.raises(InputError, match="packages.sting.bias"):
        parse_sensor_model("schema: bench-sensor-model/1\nmodel: nasa_sensor\ninput_unit: g\npackages:\n  sting: {bias: [1, 2], "
                           "sensitivity: [1, 1, 1], azimuth_deg: [0, 0, 0], coning_deg: [0, 0, 0]}\n")


# ---- effects hook ----------------------------------------------------------------------------------
def test_effects_are_stored_and_applied_lazily(monkeypatch):
    spec = parse_sensor_model(HEAD + "effects:\n  - {effect: thermal_lag, axis: z, params: {tau_s: 300}, source: run 12}\n")
    assert spec.effects == [{"effect": "thermal_lag", "axis": "z", "params": {"tau_s": 300}, "source": "run 12"}]
    calls = []

    def apply_effects(effects, inputs, output_dps, rng):
        calls.append((effects, inputs.n))
        return output_dps + np.array([0.0, 0.0, 1.0])

    fake = types.ModuleType("bench.model.effects")
    fake.apply_effects = apply_effects
    monkeypatch.setitem(sys.modules, "bench.model.effects", fake)
    import bench.model

    monkeypatch.setattr(bench.model, "effects", fake, raising=False)
    out = spec.gyro_model(np.random.default_rng(0)).evaluate(stationary_inputs(1.0, 10.0))
    assert calls == [(spec.effects, 10)]
    assert np.allclose(out, [0.0, 0.0, 1.0])
    # no effects: the module is never imported
    calls.clear()
    parse_sensor_model(HEAD).gyro_model(np.random.default_rng(0)).evaluate(stationary_inputs(1.0, 10.0))
    assert calls == []


def test_effects_validated_against_the_vocabulary_and_applied_for_real():
    pytest.importorskip("bench.model.effects")
    with pytest.raises(InputError) as err:
        parse_sensor_model(HEAD + "effects:\n  - {effect: no_such_term, axis: z}\n", "m.yaml")
    assert "m.yaml:4:" in str(err.value) and err.value.field == "effects[0]"
    spec = parse_sensor_model(HEAD + "effects:\n  - {effect: warmup_transient, axis: z, params: {amplitude_dps: 0.5, tau_s: 10.0}}\n")
    out = spec.gyro_model(np.random.default_rng(0)).evaluate(stationary_inputs(2.0, 1.0))
    assert out[:, 2] == pytest.approx(0.5 * np.exp(-np.array([0.0, 1.0]) / 10.0))
    assert out[:, :2] == pytest.approx(np.zeros((2, 2)))


# ---- NASA model (seed 001 section III) -----------------------------------------------------------
def test_nasa_zero_angles_unit_sensitivity_is_identity_plus_bias():
    rng = np.random.default_rng(0)
    v = rng.standard_normal((20, 3))
    p = NasaSensorParams(bias=[0.1, -0.2, 0.3], sensitivity=1.0, azimuth_rad=0.0, coning_rad=0.0)
    assert np.allclose(nasa_sensor_output(p, v), v + [0.1, -0.2, 0.3])
    assert nasa_sensor_output(p, np.array([1.0, 2.0, 3.0])) == pytest.approx([1.1, 1.8, 3.3])


def test_nasa_vector_form_reproduces_the_scalar_equations():
    rng = np.random.default_rng(1)
    a, c = rng.uniform(-0.3, 0.3, 3), rng.uniform(-0.3, 0.3, 3)
    b, s = rng.uniform(0, 2, 3), rng.uniform(0.4, 1.3, 3)
    p = NasaSensorParams(b, s, a, c)
    th, ps, ph = rng.uniform(-0.5, 0.5, (3, 50))
    dth, dps, dph = rng.uniform(-5, 5, (3, 50))
    C, S = np.cos, np.sin
    # gyro, Eq. III-C.16-III-C.18
    v = nasa_sensor_output(p, model_rate(ps, ph, dth, dps, dph))
    vx = b[0] + s[0] * ((C(c[0]) * S(ps) + S(a[0]) * S(c[0]) * C(ps) * C(ph) + C(a[0]) * S(c[0]) * C(ps) * S(ph)) * dth
                        + (S(a[0]) * S(c[0]) * S(ph) - C(a[0]) * S(c[0]) * C(ph)) * dps + C(c[0]) * dph)
    vy = b[1] + s[1] * ((-C(a[1]) * S(c[1]) * S(ps) + C(c[1]) * C(ps) * C(ph) - S(a[1]) * S(c[1]) * C(ps) * S(ph)) * dth
                        + (C(c[1]) * S(ph) + S(a[1]) * S(c[1]) * C(ph)) * dps - C(a[1]) * S(c[1]) * dph)
    vz = b[2] + s[2] * ((S(a[2]) * S(c[2]) * S(ps) - C(a[2]) * S(c[2]) * C(ps) * C(ph) - C(c[2]) * C(ps) * S(ph)) * dth
                        + (-C(a[2]) * S(c[2]) * S(ph) + C(c[2]) * C(ph)) * dps + S(a[2]) * S(c[2]) * dph)
    assert np.allclose(v, np.stack([vx, vy, vz], axis=1))
    # sting accelerometer, Eq. III-B.27-III-B.29 (G = 1)
    v = nasa_sensor_output(p, sting_gravity(th, ps))
    gx = b[0] + s[0] * (-C(c[0]) * S(th) * C(ps) + S(a[0]) * S(c[0]) * S(th) * S(ps) - C(a[0]) * S(c[0]) * C(th))
    gy = b[1] + s[1] * (C(a[1]) * S(c[1]) * S(th) * C(ps) + C(c[1]) * S(th) * S(ps) + S(a[1]) * S(c[1]) * C(th))
    gz = b[2] + s[2] * (-S(a[2]) * S(c[2]) * S(th) * C(ps) - C(a[2]) * S(c[2]) * S(th) * S(ps) + C(c[2]) * C(th))
    assert np.allclose(v, np.stack([gx, gy, gz], axis=1))
    assert np.allclose(nasa_sensor_input(p, v), sting_gravity(th, ps))


def test_nasa_tables_3_and_4_files():
    acc = load_sensor_model(SENSORS / "nasa_accel_table3.yaml")
    assert set(acc.nasa_packages) == {"sting", "model"} and acc.nasa_input_unit == "g"
    sting = acc.nasa("sting")
    assert sting.bias == pytest.approx([1.25, 1.27, 1.19]) and sting.sensitivity == pytest.approx([0.51, 0.47, 0.54])
    assert np.degrees(sting.coning_rad) == pytest.approx([0.06, 0.15, 0.11])
    level = nasa_sensor_output(sting, sting_gravity(0.0, 0.0))  # G_st = [0, 0, 1] at Theta = Psi = 0
    assert level[2] == pytest.approx(1.19 + 0.54 * math.cos(math.radians(0.11)))
    gyro = load_sensor_model(SENSORS / "nasa_gyro_table4.yaml").nasa()
    assert gyro.sensitivity == pytest.approx([1.25, 1.26, 1.27])
    assert np.degrees(gyro.azimuth_rad) == pytest.approx([0.14, 0.15, 0.16])


# ---- ACS board simulator with the NPSAT1 gyro ------------------------------------------------------
def test_acs_board_streams_the_npsat1_gyro_model():
    from bench.clock import VirtualClock
    from bench.sim import registry
    from bench.sim.acs_board import AcsBoardSim, GyroBoardModel, board_model_from_file
    from bench.sim.world import World, WorldParams
    from drivers.acs_board import AcsBoard

    clock = VirtualClock()
    world = World(WorldParams())
    model = board_model_from_file(SENSORS / "npsat1_qrs11_ground.yaml", np.random.default_rng(7))
    assert isinstance(model, GyroBoardModel)
    assert model.gyro.p.output == "none"
    dev = AcsBoardSim(clock, world, model)
    name = f"acs_npsat1_{id(dev)}"
    url = registry.register(name, dev)
    try:
        board = AcsBoard.open(url)
        board.sensor_power(True)
        clock.sleep(20 * 60.0)
        board.start_stream()
        batches = []
        t_end = clock.now() + 30.0
        while clock.now() < t_end:
            clock.sleep_until(min(clock.now() + 1.0, t_end))
            batches.append(board.poll())
        board.stop_stream()
        gyro = np.concatenate([b.gyro_dps for b in batches])
        temp = np.concatenate([b.temp_degc for b in batches])
        t = np.concatenate([b.board_time_s for b in batches])
    finally:
        registry.unregister(name)
    assert gyro.shape[0] == 3000
    inp = SensorInputs(time_s=t, rate_dps=world.environment(t).rate_dps, temp_c=temp, power_on_s=t)
    expected = deterministic_output_dps(model.gyro.p, inp).mean(axis=0) + model.gyro.state.b_run_to_run_dps
    assert gyro.mean(axis=0) == pytest.approx(expected, abs=3e-3)
    # Table 13 ARW at 100 Hz: sigma = N/60*sqrt(100) ~ 0.06 deg/s per sample
    assert gyro.std(axis=0) == pytest.approx(np.array([0.3546, 0.386, 0.352]) / 60 * 10, rel=0.15)


def test_acs_board_default_model_is_still_imu_simple():
    from bench.model.imu_simple import SimpleImuModel
    from bench.sim.acs_board import board_model_from_file

    assert isinstance(board_model_from_file(SENSORS / "acs_board_simple.yaml", np.random.default_rng(0)), SimpleImuModel)
    with pytest.raises(InputError, match="cannot drive the ACS board"):
        board_model_from_file(SENSORS / "nasa_gyro_table4.yaml", np.random.default_rng(0))


def test_params_dataclass_replace_keeps_types():
    p = load_sensor_model(SENSORS / "npsat1_qrs11_ground.yaml").gyro
    q = dataclasses.replace(p, output="none")
    assert isinstance(q.adc, adc.AdcParams) and q.output == "none" and p.output == "adc"
