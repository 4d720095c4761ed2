"""Gauss-Newton calibration and attitude construction with the NASA AMS sensor model.

Reference values: tests/data/nasa_tables_3_4.yaml (the report's Tables 3 and 4, with its
calibration motion profiles and initial guesses).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from bench.analysis.attitude import (
    accel_attitude_closed_form,
    closed_form_pitch_yaw,
    euler_rates,
    gauss_newton_pitch_yaw,
    gauss_newton_roll,
    gyro_body_rates,
    integrate_gyro_euler,
    integrate_gyro_quaternion,
    quat_about_axis,
    quat_angle_rad,
    quat_multiply,
    quat_to_dcm,
    report_euler_to_quaternion,
)
from bench.analysis.dataset import Dataset
from bench.analysis.gauss_newton import (
    REPORT_ACCEL_INITIAL,
    REPORT_GYRO_INITIAL,
    calibrate,
    gauss_newton_calibrate,
    invert_nasa_outputs,
    report_model_from_sting,
)
from bench.errors import InputError
from bench.model.accel import NasaSensorParams, nasa_sensor_output
from bench.model.accel import model_rate as _model_rate
from bench.model.accel import sting_gravity as report_sting_gravity


def report_body_rate(pitch, yaw, roll, pitch_rate, yaw_rate, roll_rate):
    """Ω_m of Eq. III-C.2 (does not depend on the pitch angle itself)."""
    return _model_rate(yaw, roll, pitch_rate, yaw_rate, roll_rate)

TABLES = yaml.safe_load((Path(__file__).parent / "data" / "nasa_tables_3_4.yaml").read_text())
d2r = math.radians


def table_params(table: str, package: str, column: str = "specified") -> NasaSensorParams:
    rows = [TABLES[table][package][a][column] for a in "xyz"]
    return NasaSensorParams([r["bias"] for r in rows], [r["sensitivity"] for r in rows],
                            np.radians([r["azimuth_deg"] for r in rows]), np.radians([r["coning_deg"] for r in rows]))


def initial(kind: str) -> tuple[float, float, float, float]:
    i = TABLES["initial"][kind]
    return (i["bias"], i["sensitivity"], d2r(i["azimuth_deg"]), d2r(i["coning_deg"]))


def accel_profile() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Section IV-A: Θ = Ψ = Φ = linear 0 → 10 deg, n = 1,001 (rad)."""
    p = TABLES["profiles"]["accel"]
    a = np.radians(np.linspace(p["start_deg"], p["end_deg"], p["n"]))
    return a, a, a


def gyro_profile() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Section IV-C: harmonic pitch/yaw/roll; returns t (s), angles (n, 3) rad, rates (n, 3) deg/s."""
    p = TABLES["profiles"]["gyro"]
    t = np.arange(p["n"]) * p["step_s"]
    amp = p["amplitude_deg"]
    w = [2 * math.pi * p["frequency_hz"][k] for k in ("pitch", "yaw", "roll")]
    ang = np.stack([np.radians(amp * np.sin(wi * t)) for wi in w], axis=1)
    rate = np.stack([amp * wi * np.cos(wi * t) for wi in w], axis=1)
    return t, ang, rate


def package_data(which: str) -> tuple[NasaSensorParams, np.ndarray, tuple]:
    """(specified parameters, true input vectors, initial guess) of one package on the report's profile."""
    th, ps, ph = accel_profile()
    g_st = report_sting_gravity(th, ps)
    if which == "sting":
        return table_params("table_3", "sting"), g_st, REPORT_ACCEL_INITIAL
    if which == "model":
        return table_params("table_3", "model"), report_model_from_sting(ph, g_st), REPORT_ACCEL_INITIAL
    _, ang, rate = gyro_profile()
    omega = report_body_rate(ang[:, 0], ang[:, 1], ang[:, 2], rate[:, 0], rate[:, 1], rate[:, 2])
    return table_params("table_4", "model"), omega, REPORT_GYRO_INITIAL


def rich_orientations() -> np.ndarray:
    """Tilts 0-180 deg and table angles 0-345 deg in 15 deg steps (312 positions), gravity in g."""
    tilt, table = np.meshgrid(np.arange(0.0, 181.0, 15.0), np.arange(0.0, 360.0, 15.0))
    return report_sting_gravity(np.radians(tilt.ravel()), np.radians(table.ravel()))


def errors(fit_params: NasaSensorParams, true: NasaSensorParams) -> np.ndarray:
    """(4, 3) errors: bias, sensitivity, azimuth (rad), coning (rad)."""
    return np.array([fit_params.bias - true.bias, fit_params.sensitivity - true.sensitivity,
                     fit_params.azimuth_rad - true.azimuth_rad, fit_params.coning_rad - true.coning_rad])


def ses(fit_se: NasaSensorParams) -> np.ndarray:
    return np.array([fit_se.bias, fit_se.sensitivity, fit_se.azimuth_rad, fit_se.coning_rad])


# ---- the forward model is the report's ----------------------------------------------------------
def test_table_initial_guesses_match_module_constants():
    assert initial("accel") == pytest.approx(REPORT_ACCEL_INITIAL)
    assert initial("gyro") == pytest.approx(REPORT_GYRO_INITIAL)


def test_forward_model_reproduces_the_reports_scalar_equations():
    rng = np.random.default_rng(7)
    n = 50
    th, ps, ph = (rng.uniform(-1.2, 1.2, n) for _ in range(3))
    dth, dps, dph = (rng.uniform(-20, 20, n) for _ in range(3))
    p = NasaSensorParams(rng.uniform(-1, 1, 3), rng.uniform(0.3, 1.5, 3), rng.uniform(-3, 3, 3), rng.uniform(0, 0.3, 3))
    B, S, A, C = p.bias, p.sensitivity, p.azimuth_rad, p.coning_rad
    sA, cA, sC, cC = np.sin(A), np.cos(A), np.sin(C), np.cos(C)
    sT, cT, sP, cP, sF, cF = np.sin(th), np.cos(th), np.sin(ps), np.cos(ps), np.sin(ph), np.cos(ph)
    G = 1.0
    # sting accelerometers, Eqs. III-B.27-III-B.29
    v_st = np.stack([
        B[0] + S[0] * (-cC[0] * sT * cP + sA[0] * sC[0] * sT * sP - cA[0] * sC[0] * cT) * G,
        B[1] + S[1] * (cA[1] * sC[1] * sT * cP + cC[1] * sT * sP + sA[1] * sC[1] * cT) * G,
        B[2] + S[2] * (-sA[2] * sC[2] * sT * cP - cA[2] * sC[2] * sT * sP + cC[2] * cT) * G], axis=1)
    g_st = report_sting_gravity(th, ps, G)
    np.testing.assert_allclose(nasa_sensor_output(p, g_st), v_st, atol=1e-14)
    # model accelerometers, Eqs. III-B.30-III-B.32
    gx, gy, gz = g_st.T
    v_m = np.stack([
        B[0] + S[0] * (cC[0] * gx + (sA[0] * sC[0] * cF + cA[0] * sC[0] * sF) * gy + (sA[0] * sC[0] * sF - cA[0] * sC[0] * cF) * gz),
        B[1] + S[1] * (-cA[1] * sC[1] * gx + (cC[1] * cF - sA[1] * sC[1] * sF) * gy + (cC[1] * sF + sA[1] * sC[1] * cF) * gz),
        B[2] + S[2] * (sA[2] * sC[2] * gx + (-cA[2] * sC[2] * cF - cC[2] * sF) * gy + (-cA[2] * sC[2] * sF + cC[2] * cF) * gz)], axis=1)
    np.testing.assert_allclose(nasa_sensor_output(p, report_model_from_sting(ph, g_st)), v_m, atol=1e-14)
    # gyros, Eqs. III-C.16-III-C.18
    v_g = np.stack([
        B[0] + S[0] * ((cC[0] * sP + sA[0] * sC[0] * cP * cF + cA[0] * sC[0] * cP * sF) * dth
                       + (sA[0] * sC[0] * sF - cA[0] * sC[0] * cF) * dps + cC[0] * dph),
        B[1] + S[1] * ((-cA[1] * sC[1] * sP + cC[1] * cP * cF - sA[1] * sC[1] * cP * sF) * dth
                       + (cC[1] * sF + sA[1] * sC[1] * cF) * dps - cA[1] * sC[1] * dph),
        B[2] + S[2] * ((sA[2] * sC[2] * sP - cA[2] * sC[2] * cP * cF - cC[2] * cP * sF) * dth
                       + (-cA[2] * sC[2] * sF + cC[2] * cF) * dps + sA[2] * sC[2] * dph)], axis=1)
    omega = report_body_rate(th, ps, ph, dth, dps, dph)
    np.testing.assert_allclose(nasa_sensor_output(p, omega), v_g, atol=1e-12)


def test_model_inverse_recovers_the_input_vectors():
    p = table_params("table_3", "sting")
    g = rich_orientations()
    np.testing.assert_allclose(invert_nasa_outputs(p, nasa_sensor_output(p, g)), g, atol=1e-13)


def _rot(axis: int, angle: float) -> np.ndarray:
    """Frame transformation for a rotation by ``angle`` about ``axis``, as printed in the report
    (e.g. T_i2_xm/m of Eq. III-C.6: [[1, 0, 0], [0, cos, sin], [0, -sin, cos]])."""
    c, s = math.cos(angle), math.sin(angle)
    m = np.eye(3)
    p, q = (axis + 1) % 3, (axis + 2) % 3
    m[p, p], m[p, q], m[q, p], m[q, q] = c, s, -s, c
    return m


def test_bench_model_accel_equals_the_reports_rotation_matrices():
    """The forward model used here is bench.model.accel's (one place per concept); check it against
    an independent construction: row k of T(coning about the next axis)·T(azimuth about k)
    (Eqs. III-C.6-III-C.12), times the input vector, scaled and biased (Eq. III-C.14)."""
    rng = np.random.default_rng(3)
    p = NasaSensorParams(rng.uniform(-1, 1, 3), rng.uniform(0.3, 1.5, 3), rng.uniform(-3, 3, 3), rng.uniform(0, 0.5, 3))
    v = rng.normal(size=(100, 3))
    expected = np.empty_like(v)
    for k in range(3):
        t_sn = _rot((k + 1) % 3, p.coning_rad[k]) @ _rot(k, p.azimuth_rad[k])
        expected[:, k] = p.bias[k] + p.sensitivity[k] * (v @ t_sn[k])
    np.testing.assert_allclose(nasa_sensor_output(p, v), expected, atol=1e-14)


# ---- Tables 3 and 4: noise-free recovery ---------------------------------------------------------
@pytest.mark.parametrize("which", ["sting", "model", "gyro"])
def test_noise_free_report_profile_recovers_specified_values(which):
    true, vectors, init = package_data(which)
    fit = gauss_newton_calibrate(vectors, nasa_sensor_output(true, vectors), initial=init)
    assert all(fit.converged)
    err = errors(fit.params, true)
    # bias (V), sensitivity (V/g or V/(deg/s)), azimuth and coning (rad): 1e-9. The accelerometer
    # ramp (0-10 deg only) leaves the azimuth barely determined (cond([1 G]) ≈ 5e5 and
    # ∂V/∂A ∝ S sin C): its float64 floor is ~3e-10 rad = 2e-8 deg, and depends on the BLAS: with
    # numpy 2.4 / scipy 1.17 the sting's third azimuth lands at 1.3e-9 rad (8e-8 deg).
    assert np.max(np.abs(err)) < 3e-9, err
    assert max(fit.iterations) <= 20
    assert fit.total_residual_rms < 1e-14
    # the Computed column of Table 3/4 at its printed precision
    table, package = ("table_4", "model") if which == "gyro" else ("table_3", which)
    dec = TABLES["printed_decimals"]
    for k, a in enumerate("xyz"):
        comp = TABLES[table][package][a]["computed"]
        assert round(fit.params.bias[k], dec["gyro_bias"] if which == "gyro" else dec["bias"]) == comp["bias"]
        assert round(fit.params.sensitivity[k], dec["sensitivity"]) == comp["sensitivity"]
        assert round(math.degrees(fit.params.azimuth_rad[k]), dec["azimuth_deg"]) == comp["azimuth_deg"]
        assert round(math.degrees(fit.params.coning_rad[k]), dec["coning_deg"]) == comp["coning_deg"]


@pytest.mark.parametrize("package", ["sting", "model"])
def test_noise_free_well_spread_orientations_recover_table_3_to_1e_9_deg(package):
    true = table_params("table_3", package)
    g = rich_orientations()
    fit = gauss_newton_calibrate(g, nasa_sensor_output(true, g))  # default linear start
    err = errors(fit.params, true)
    assert np.max(np.abs(err[:2])) < 1e-9
    assert np.max(np.abs(np.degrees(err[2:]))) < 1e-9


def test_gauss_newton_converges_from_the_reports_initial_guess_for_one_axis():
    true, vectors, _ = package_data("gyro")
    out = nasa_sensor_output(true, vectors)[:, 1]
    fit = gauss_newton_calibrate(vectors, out, initial=REPORT_GYRO_INITIAL, axes=("y",))
    assert fit.axes == ("y",)
    assert fit.params.bias[1] == pytest.approx(0.052, abs=1e-12)
    assert np.isnan(fit.params.bias[0]) and np.isnan(fit.params.bias[2])


# ---- with noise ---------------------------------------------------------------------------------
@pytest.mark.parametrize("which, sigma", [("sting", 1e-10), ("model", 1e-10), ("gyro", 1e-4)])
def test_noisy_report_profile_is_within_the_fit_uncertainty(which, sigma):
    """The tables state no uncertainty; the fit's own standard errors σ(JᵀJ)⁻¹ must cover the
    error (4 SE). The 0-10 deg accelerometer ramp is so ill-conditioned that σ must be tiny for
    the linearised SE to hold (σ = 1 µV gives an azimuth SE of ~40 deg)."""
    true, vectors, init = package_data(which)
    rng = np.random.default_rng(20030101)
    out = nasa_sensor_output(true, vectors) + rng.normal(0.0, sigma, (vectors.shape[0], 3))
    fit = gauss_newton_calibrate(vectors, out, initial=init)
    err, se = errors(fit.params, true), ses(fit.std_errors)
    assert np.all(np.abs(err) <= 4 * se), err / se
    assert np.array(fit.residual_rms) == pytest.approx(sigma, rel=0.15)


def test_noisy_well_spread_orientations_reproduce_table_3_printed_digits():
    """With 0.1 nV of noise and 312 positions the fit matches Table 3's Computed column to its
    printed 4 decimals; the azimuth needs such small noise because its SE ≈ SE(C)/sin C."""
    true = table_params("table_3", "sting")
    g = rich_orientations()
    rng = np.random.default_rng(5)
    fit = gauss_newton_calibrate(g, nasa_sensor_output(true, g) + rng.normal(0, 1e-10, (g.shape[0], 3)))
    for k, a in enumerate("xyz"):
        comp = TABLES["table_3"]["sting"][a]["computed"]
        assert round(fit.params.bias[k], 4) == comp["bias"]
        assert round(fit.params.sensitivity[k], 4) == comp["sensitivity"]
        assert round(math.degrees(fit.params.azimuth_rad[k]), 4) == comp["azimuth_deg"]
        assert round(math.degrees(fit.params.coning_rad[k]), 4) == comp["coning_deg"]
    assert np.all(np.abs(errors(fit.params, true)) <= 4 * ses(fit.std_errors))


def test_standard_errors_match_the_scatter_over_repeated_noisy_fits():
    true = table_params("table_3", "sting")
    g = rich_orientations()
    clean = nasa_sensor_output(true, g)
    rng = np.random.default_rng(11)
    est, se = [], []
    for _ in range(150):
        fit = gauss_newton_calibrate(g, clean + rng.normal(0, 1e-5, clean.shape))
        est.append(errors(fit.params, true))
        se.append(ses(fit.std_errors))
    ratio = np.std(est, axis=0, ddof=1) / np.mean(se, axis=0)
    assert np.all((ratio > 0.75) & (ratio < 1.3)), ratio


# ---- accelerometer attitude construction ---------------------------------------------------------
def test_closed_form_attitude_matches_true_pitch_yaw_roll_on_the_report_profile():
    th, ps, ph = accel_profile()
    p_st, p_m = table_params("table_3", "sting"), table_params("table_3", "model")
    g_st = report_sting_gravity(th, ps)
    v_st = nasa_sensor_output(p_st, g_st)
    v_m = nasa_sensor_output(p_m, report_model_from_sting(ph, g_st))
    pitch, yaw, roll = accel_attitude_closed_form(p_st, v_st, p_m, v_m)
    assert np.max(np.abs(pitch - th)) < 1e-12
    assert np.max(np.abs(yaw[1:] - ps[1:])) < 1e-9  # yaw is undefined at pitch 0 (Eq. IV-B.10)
    assert np.max(np.abs(roll - ph)) < 1e-12


def test_closed_form_pitch_yaw_over_wide_angles_including_negative_pitch():
    rng = np.random.default_rng(2)
    th = rng.uniform(-2.5, 2.5, 500)
    th = th[np.abs(th) > 0.01]
    ps = rng.uniform(-1.5, 1.5, th.size)
    pitch, yaw = closed_form_pitch_yaw(report_sting_gravity(th, ps, 9.81))
    np.testing.assert_allclose(pitch, th, atol=1e-12)
    np.testing.assert_allclose(yaw, ps, atol=1e-12)


def test_gauss_newton_attitude_matches_true_angles():
    th, ps, ph = accel_profile()
    p_st, p_m = table_params("table_3", "sting"), table_params("table_3", "model")
    g_st = report_sting_gravity(th, ps)
    v_st = nasa_sensor_output(p_st, g_st)
    v_m = nasa_sensor_output(p_m, report_model_from_sting(ph, g_st))
    pitch, yaw, it = gauss_newton_pitch_yaw(p_st, v_st)
    assert it <= 10
    assert np.max(np.abs(pitch - th)) < 1e-10
    assert np.max(np.abs(yaw[1:] - ps[1:])) < 1e-9
    roll, it = gauss_newton_roll(p_m, v_m, g_st)
    assert np.max(np.abs(roll - ph)) < 1e-10


# ---- gyro attitude construction ------------------------------------------------------------------
def test_rk4_constant_rate_gives_the_exact_angle():
    rate = 0.3  # rad/s about a fixed, oblique axis, for 7 s
    axis = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    t = np.linspace(0.0, 7.0, 701)
    q = integrate_gyro_quaternion(t, np.tile(rate * axis, (t.size, 1)))
    angle = quat_angle_rad(q[-1])
    assert abs(angle - rate * 7.0) < 1e-9
    np.testing.assert_allclose(q[-1, 1:] / np.linalg.norm(q[-1, 1:]), axis, atol=1e-12)
    # the report's Euler-angle path: a pure roll rate integrates to Φ = Φ̇ t
    e = integrate_gyro_euler(t, np.tile([rate, 0.0, 0.0], (t.size, 1)))
    assert abs(e[-1, 2] - rate * 7.0) < 1e-9 and np.max(np.abs(e[:, :2])) < 1e-15
    e4 = integrate_gyro_euler(t, np.tile([rate, 0.0, 0.0], (t.size, 1)), method="rk4")
    assert abs(e4[-1, 2] - rate * 7.0) < 1e-9


def _coning_truth(t: np.ndarray, a: float = 2.0, b: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """q(t) = q_z(a t) ⊗ q_x(b t): body rate ω = [b, a sin(bt), a cos(bt)] (non-commuting)."""
    q = quat_multiply(quat_about_axis(2, a * t), quat_about_axis(0, b * t))
    w = np.stack([np.full_like(t, b), a * np.sin(b * t), a * np.cos(b * t)], axis=1)
    return q, w


def test_coning_body_rate_is_consistent_with_its_quaternion():
    t = np.array([0.3])
    h = 1e-6
    q, w = _coning_truth(t)
    qd = (_coning_truth(t + h)[0] - _coning_truth(t - h)[0]) / (2 * h)
    conj = q * np.array([1, -1, -1, -1])
    np.testing.assert_allclose(2 * quat_multiply(conj, qd)[0, 1:], w[0], atol=1e-8)


def test_rk4_quaternion_integration_converges_at_fourth_order():
    errs = []
    for n in (41, 81, 161):
        t = np.linspace(0.0, 2.0, n)
        q_true, w = _coning_truth(t)
        q = integrate_gyro_quaternion(t, w)
        diff = quat_multiply(q[-1], q_true[-1] * np.array([1, -1, -1, -1]))
        errs.append(float(quat_angle_rad(diff)))
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all((orders > 3.6) & (orders < 4.6)), (errs, orders)


def test_report_harmonic_profile_is_reconstructed_by_euler_rk5_and_quaternion_rk4():
    """Section IV-D test (Figures 9/10): exact angles from the gyro outputs of Table 4's gyros."""
    t, ang, rate_dps = gyro_profile()
    omega_dps = report_body_rate(ang[:, 0], ang[:, 1], ang[:, 2], rate_dps[:, 0], rate_dps[:, 1], rate_dps[:, 2])
    p = table_params("table_4", "model")
    body = np.radians(gyro_body_rates(p, nasa_sensor_output(p, omega_dps)))
    e = integrate_gyro_euler(t, body)
    assert np.max(np.abs(e - ang)) < 1e-9
    q = integrate_gyro_quaternion(t, body)
    diff = quat_multiply(q, report_euler_to_quaternion(ang[:, 0], ang[:, 1], ang[:, 2]) * np.array([1, -1, -1, -1]))
    assert np.max(quat_angle_rad(diff)) < 1e-9
    np.testing.assert_allclose(euler_rates(ang, np.radians(omega_dps)), np.radians(rate_dps), atol=1e-12)
    dcm = quat_to_dcm(q[-1])
    np.testing.assert_allclose(dcm @ dcm.T, np.eye(3), atol=1e-12)


# ---- calibrate(ds) ------------------------------------------------------------------------------
BENCH_ACCEL = NasaSensorParams([0.012, -0.008, 0.02], [1.003, 0.998, 1.001], np.radians([30.0, -60.0, 120.0]),
                               np.radians([0.5, 0.8, 0.3]))
BENCH_GYRO = NasaSensorParams([0.1, -0.05, 0.07], [1.01, 0.995, 1.002], np.radians([45.0, 10.0, -100.0]),
                              np.radians([0.4, 0.6, 0.9]))


def accel_dataset(tilts=(0.0, 45.0, 90.0, 135.0, 180.0), angles=tuple(range(0, 360, 45)), sigma=1e-4,
                  tilt_as="column") -> Dataset:
    """Stationary positions (2 s at 10 Hz) joined by 1 s table moves, outputs from the NASA model."""
    rng = np.random.default_rng(42)
    t, ang, tilt = [], [], []
    now, prev = 0.0, None
    for ti in tilts:
        for a in angles:
            if prev is not None:  # move: table angle ramps from the previous angle
                for k in range(1, 10):
                    t.append(now)
                    ang.append(prev[1] + (a - prev[1]) * k / 10)
                    tilt.append(prev[0] + (ti - prev[0]) * k / 10)
                    now += 0.1
            for _ in range(20):
                t.append(now)
                ang.append(float(a))
                tilt.append(ti)
                now += 0.1
            prev = (ti, float(a))
    t, ang, tilt = np.array(t), np.array(ang), np.array(tilt)
    f = report_sting_gravity(np.radians(tilt), np.radians(ang))
    out = nasa_sensor_output(BENCH_ACCEL, f) + rng.normal(0, sigma, f.shape)
    cols = {"time_s": t, "table_angle_deg": ang, "gyro_x_dps": np.zeros_like(t)}
    cols.update({f"accel_{a}_g": out[:, k] for k, a in enumerate("xyz")})
    meta: dict = {}
    if tilt_as == "column":
        cols["tilt_deg"] = tilt
    elif tilt_as == "meta":
        meta["tilt_deg"] = float(tilts[0])
    return Dataset(cols, meta, "synthetic.csv")


def gyro_dataset(sigma=1e-3) -> Dataset:
    rng = np.random.default_rng(9)
    t, ref = [], []
    now = 0.0
    for axis in range(3):
        for r in (-50.0, -20.0, -5.0, 0.0, 5.0, 20.0, 50.0):
            for _ in range(30):
                v = np.zeros(3)
                v[axis] = r
                ref.append(v)
                t.append(now)
                now += 0.1
            for k in range(5):  # acceleration to the next rate
                v = np.zeros(3)
                v[axis] = r + 3.0 * (k + 1)
                ref.append(v)
                t.append(now)
                now += 0.1
    t, ref = np.array(t), np.array(ref)
    out = nasa_sensor_output(BENCH_GYRO, ref) + rng.normal(0, sigma, ref.shape)
    cols = {"time_s": t}
    cols.update({f"ref_rate_{a}_dps": ref[:, k] for k, a in enumerate("xyz")})
    cols.update({f"gyro_{a}_dps": out[:, k] for k, a in enumerate("xyz")})
    return Dataset(cols, {}, "synthetic.csv")


def _json_errors(js: dict, true: NasaSensorParams) -> None:
    for k, a in enumerate("xyz"):
        ax = js["axes"][a]
        for key, val in (("bias", true.bias[k]), ("sensitivity", true.sensitivity[k]),
                         ("azimuth_deg", math.degrees(true.azimuth_rad[k])), ("coning_deg", math.degrees(true.coning_rad[k]))):
            assert abs(ax[key] - val) <= 4 * ax["se"][key], (a, key, ax[key], val, ax["se"][key])


def test_calibrate_accel_from_table_positions():
    res = calibrate(accel_dataset(), sensor="accel")
    js = res.json
    assert js["sensor"] == "accel" and js["positions"] == 40
    assert set(js["axes"]) == {"x", "y", "z"}
    assert set(js["axes"]["x"]) >= {"bias", "sensitivity", "azimuth_deg", "coning_deg", "se"}
    assert set(js["axes"]["x"]["se"]) == {"bias", "sensitivity", "azimuth_deg", "coning_deg"}
    assert js["iterations"] >= 1 and js["residual_rms"] < 1e-4
    _json_errors(js, BENCH_ACCEL)
    json.dumps(js, allow_nan=False)  # plain JSON types, no NaN/inf
    assert res.method == "gauss-newton" and res.calibration is not None and res.tables


def test_calibrate_accel_with_per_row_tilt_option_and_mount():
    ds = accel_dataset(tilt_as="none")
    tilt = accel_dataset()["tilt_deg"]
    res = calibrate(ds, sensor="accel", tilt_deg=tilt, mount="z")
    _json_errors(res.json, BENCH_ACCEL)


def test_calibrate_gyro_from_rate_plateaus():
    res = calibrate(gyro_dataset(), sensor="gyro")
    js = res.json
    assert js["sensor"] == "gyro" and js["positions"] == 21
    _json_errors(js, BENCH_GYRO)
    assert js["units"]["bias"] == "deg/s"


# ---- bad input ----------------------------------------------------------------------------------
def test_too_few_positions_is_an_input_error():
    g = rich_orientations()[:4]
    with pytest.raises(InputError, match="too few positions: 4"):
        gauss_newton_calibrate(g, nasa_sensor_output(table_params("table_3", "sting"), g))
    ds = accel_dataset(tilts=(0.0, 90.0), angles=(0, 90))
    with pytest.raises(InputError, match="too few positions: found 4 stationary table positions"):
        calibrate(ds, sensor="accel")


def test_single_tilt_cannot_determine_the_parameters():
    ds = accel_dataset(tilts=(30.0,), tilt_as="meta")
    with pytest.raises(InputError, match="do not determine bias, sensitivity, azimuth and coning"):
        calibrate(ds, sensor="accel")


def test_rates_about_one_axis_cannot_calibrate_a_gyro():
    ds = gyro_dataset()
    keep = np.abs(ds["ref_rate_x_dps"]) + np.abs(ds["ref_rate_y_dps"]) == 0
    with pytest.raises(InputError, match="span only 2 of the 4"):
        calibrate(ds.select(keep), sensor="gyro")


@pytest.mark.parametrize("sensor, drop, needle", [
    ("accel", "table_angle_deg", "needs column\\(s\\) table_angle_deg"),
    ("accel", "accel_y_g", "needs column\\(s\\) accel_y_g"),
    ("gyro", "ref_rate_z_dps", "needs column\\(s\\) ref_rate_z_dps"),
])
def test_missing_columns_are_input_errors(sensor, drop, needle):
    ds = accel_dataset() if sensor == "accel" else gyro_dataset()
    del ds.columns[drop]
    with pytest.raises(InputError, match=needle):
        calibrate(ds, sensor=sensor)


def test_other_bad_input_is_an_input_error():
    with pytest.raises(InputError, match="needs the table tilt"):
        calibrate(accel_dataset(tilt_as="none"), sensor="accel")
    with pytest.raises(InputError, match="unknown sensor 'mag'"):
        calibrate(gyro_dataset(), sensor="mag")
    with pytest.raises(InputError, match="mount"):
        calibrate(accel_dataset(), sensor="accel", mount="w")
    with pytest.raises(InputError, match="tilt_deg: expected a number"):
        calibrate(accel_dataset(), sensor="accel", tilt_deg="steep")
    with pytest.raises(InputError, match="shape \\(n, 3\\)"):
        gauss_newton_calibrate(np.zeros((10, 2)), np.zeros((10, 3)))
    with pytest.raises(InputError, match="finite"):
        gauss_newton_calibrate(np.full((10, 3), np.nan), np.zeros((10, 3)))
    with pytest.raises(InputError, match="increase strictly"):
        integrate_gyro_quaternion(np.array([0.0, 1.0, 1.0]), np.zeros((3, 3)))
    with pytest.raises(InputError, match="unknown Runge-Kutta method"):
        integrate_gyro_euler(np.array([0.0, 1.0]), np.zeros((2, 3)), method="euler")
    with pytest.raises(InputError, match="initial must be"):
        gauss_newton_calibrate(rich_orientations(), np.zeros((312, 3)), initial=(1.0, 2.0))
    with pytest.raises(InputError, match="initial must be four numbers"):
        calibrate(gyro_dataset(), sensor="gyro", initial="1,2")
    with pytest.raises(InputError, match="max_iter: expected a number"):
        calibrate(gyro_dataset(), sensor="gyro", max_iter="many")
    with pytest.raises(InputError, match="sensitivities"):
        invert_nasa_outputs(NasaSensorParams(0.0, [1.0, 0.0, 1.0], 0.0, 0.0), np.zeros((1, 3)))


def test_unknown_options_are_reported_not_fatal():
    res = calibrate(gyro_dataset(), sensor="gyro", json=True, colour=None)
    assert any("ignored option(s): json" in n for n in res.notes)


# ---- every tilt the docs promise reaches the method (issue 29) ---------------------------------------
def _write_csv(path, ds: Dataset, cols: list[str], meta: dict | None = None, names: dict | None = None) -> None:
    names = names or {}
    lines = [f"# {k}: {v}" for k, v in (meta or {}).items()]
    lines.append(",".join(names.get(c, c) for c in cols))
    data = np.column_stack([ds[c] for c in cols])
    lines += [",".join(repr(float(v)) for v in row) for row in data]
    path.write_text("\n".join(lines) + "\n")


def test_tilt_column_reaches_the_accel_calibration_from_the_command_line(tmp_path, capsys):
    """A measured-data CSV with a tilt_deg column calibrates from the CLI (the loader used to drop
    the column: "needs the table tilt"); the same file with other column names through --map (tilt
    target) and through a mapping YAML gives the same result."""
    from tests.test_foreign_data import bench_in_process

    ds = accel_dataset()
    cols = ["time_s", "table_angle_deg", "tilt_deg", "gyro_x_dps", "accel_x_g", "accel_y_g", "accel_z_g"]
    csv = tmp_path / "positions.csv"
    _write_csv(csv, ds, cols)
    res = bench_in_process(capsys, "calibrate", "gauss-newton", str(csv), "--sensor", "accel", "--json")
    assert res.returncode == 0, res.stderr
    direct = json.loads(res.stdout)
    _json_errors(direct, BENCH_ACCEL)
    other = tmp_path / "other.csv"
    names = {"time_s": "t", "table_angle_deg": "platter", "tilt_deg": "incl", "gyro_x_dps": "wx",
             "accel_x_g": "ax", "accel_y_g": "ay", "accel_z_g": "az"}
    _write_csv(other, ds, cols, names=names)
    maps = ["time=t:s", "table_angle=platter:deg", "tilt=incl:deg", "gyro_x=wx:deg/s", "accel=ax,ay,az:g"]
    mapping = tmp_path / "map.yaml"
    mapping.write_text("schema: bench-mapping/1\n" + "".join(f"{m.split('=')[0]}: \"{m.split('=')[1]}\"\n" for m in maps))
    for extra in ([a for m in maps for a in ("--map", m)], ["--map", str(mapping)]):
        res = bench_in_process(capsys, "calibrate", "gauss-newton", str(other), "--sensor", "accel", "--json", *extra)
        assert res.returncode == 0, res.stderr
        assert json.loads(res.stdout)["axes"] == direct["axes"]


def test_tilt_metadata_and_the_rank_message_name_the_file(tmp_path, capsys):
    """`# tilt_deg: 90` reaches the method; one tilt cannot determine the fit, and the message says
    which file (it had no file prefix)."""
    from tests.cli_output import one_error_line
    from tests.test_foreign_data import bench_in_process

    ds = accel_dataset(tilts=(90.0,), tilt_as="meta")
    csv = tmp_path / "one_tilt.csv"
    _write_csv(csv, ds, ["time_s", "table_angle_deg", "gyro_x_dps", "accel_x_g", "accel_y_g", "accel_z_g"],
               meta={"tilt_deg": 90})
    msg = one_error_line(bench_in_process(capsys, "calibrate", "gauss-newton", str(csv), "--sensor", "accel"))
    assert msg.startswith(f"{csv}: the positions do not determine bias, sensitivity, azimuth and coning "
                          "(the input vectors and a constant span only 3 of the 4 needed directions)"), msg
    bad = tmp_path / "bad_tilt.csv"
    _write_csv(bad, ds, ["time_s", "table_angle_deg", "gyro_x_dps", "accel_x_g", "accel_y_g", "accel_z_g"],
               meta={"tilt_deg": "steep"})
    msg = one_error_line(bench_in_process(capsys, "calibrate", "gauss-newton", str(bad), "--sensor", "accel"))
    assert msg == f"{bad}:1: tilt_deg: expected a number in deg, got 'steep'"


def test_gyro_fit_on_a_ferraris_session_points_to_six_position():
    """The six still faces of a Ferraris session form one zero-rate plateau: the gyro fit is refused
    and the message names the method that reads such a session."""
    ds = gyro_dataset()
    still = np.all(np.column_stack([ds[f"ref_rate_{a}_dps"] for a in "xyz"]) == 0, axis=1)
    with pytest.raises(InputError, match="read by `bench calibrate six-position`"):
        calibrate(ds.select(still | (np.arange(len(ds)) < 40)), sensor="gyro")
