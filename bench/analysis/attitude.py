"""Attitude construction from calibrated accelerometers and gyros (NASA AMS report, section IV-B, IV-D).

Conventions are the report's (``bench.analysis.gauss_newton`` module docstring,
``docs/gauss-newton.md``): pitch Θ about y, then yaw Ψ about the new z (sting axes), then roll
Φ about x_st (model axes), starting from the initial orientation (Eqs. III-B.2-III-B.5). Angles
are in rad, rates in rad/s unless a name says otherwise.

* Accelerometers (IV-B): sensor outputs → gravity components by inverting the sensor model
  (Eqs. IV-B.1/2), then closed form (Eqs. IV-B.9-IV-B.11) or Gauss-Newton on the outputs
  (Eqs. IV-B.12-IV-B.28). One triad gives two angles (Θ, Ψ); roll needs the second (model)
  package, as in the report.
* Gyros (IV-D): sensor outputs → body rates (Eq. IV-D.1), then either the report's Euler-angle
  kinematics (Eq. IV-D.4) integrated with its 5th-order Runge-Kutta (Eqs. IV-D.6/7) or classic
  RK4, or a quaternion q̇ = ½ q ⊗ (0, ω) integrated with RK4 (singularity-free; our addition).
  Sampled rates are interpolated between samples (cubic spline with 4+ samples, else linear) at
  the Runge-Kutta stage times, which keeps RK4 4th order for smooth rates.

Quaternions are scalar-first (w, x, y, z) and map body (model) vectors to the reference
(initial-orientation) frame: v_ref = q ⊗ (0, v_body) ⊗ q*.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from bench.analysis.gauss_newton import REPORT_GRAVITY_G, invert_nasa_outputs
from bench.errors import InputError
from bench.model.accel import NasaSensorParams, sensitive_axes, sting_gravity

GN_INITIAL_RAD = 0.1
"""Starting angle of the report's iterative attitude construction (Appendix C: Th0 = Psi0 = Phi0 = 0.1)."""

GN_MAX_ITER = 10
"""Iteration limit of the report's iterative attitude construction (Appendix C: ``for ii=1:10``)."""

GN_TOL = 1e-10
"""Step tolerance (rad) of the report's iterative attitude construction (Appendix C: Tolerance = 1e-10)."""

RK5_BUTCHER = (
    (0.0, []),
    (0.25, [0.25]),
    (0.25, [1 / 8, 1 / 8]),
    (0.5, [0.0, -0.5, 1.0]),
    (0.75, [3 / 16, 0.0, 0.0, 9 / 16]),
    (1.0, [-3 / 7, 2 / 7, 12 / 7, -12 / 7, 8 / 7]),
), (7 / 90, 0.0, 32 / 90, 12 / 90, 32 / 90, 7 / 90)
"""The report's 5th-order Runge-Kutta (Butcher's, Eqs. IV-D.6/7 and Appendix E; Chapra & Canale
p. 604): stage times and coefficients, then weights. (Eq. IV-D.6 as printed writes the 4th stage
as ½(−k2 + 2k3); the listing's −½k2 + k3 is the same.)"""

RK4_CLASSIC = (
    (0.0, []),
    (0.5, [0.5]),
    (0.5, [0.0, 0.5]),
    (1.0, [0.0, 0.0, 1.0]),
), (1 / 6, 1 / 3, 1 / 3, 1 / 6)
"""Classic 4th-order Runge-Kutta tableau."""

_TABLEAUX = {"rk4": RK4_CLASSIC, "rk5": RK5_BUTCHER}


# ---- accelerometer: closed form -----------------------------------------------------------------
def closed_form_pitch_yaw(g_st: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pitch Θ and yaw Ψ (rad, arrays (n,)) from sting-axes gravity components (n, 3) (Eqs. IV-B.9,
    IV-B.10): Ψ = atan(−G_y/G_x) in [−90°, 90°], Θ = atan(√(G_x² + G_y²)/G_z)·sgn(−G_x/cos Ψ),
    taken with atan2 so |Θ| may exceed 90°. At Θ = 0 the yaw is undefined and returned as 0."""
    g = np.atleast_2d(np.asarray(g_st, dtype=float))
    gx, gy, gz = g[:, 0], g[:, 1], g[:, 2]
    sign = np.where(gx > 0, -1.0, 1.0)  # choose the branch with cos Ψ ≥ 0, as the report's atan
    yaw = np.arctan2(sign * gy, -sign * gx)
    horiz = np.hypot(gx, gy)
    yaw = np.where(horiz == 0, 0.0, yaw)
    pitch = sign * np.arctan2(horiz, gz)
    return pitch, yaw


def closed_form_roll(g_st: np.ndarray, g_m: np.ndarray) -> np.ndarray:
    """Roll Φ (rad, (n,)) from sting and model gravity components (n, 3) each (Eq. IV-B.11):
    Φ = atan2(G_ym G_zst − G_zm G_yst, G_ym G_yst + G_zm G_zst)."""
    s = np.atleast_2d(np.asarray(g_st, dtype=float))
    m = np.atleast_2d(np.asarray(g_m, dtype=float))
    return np.arctan2(m[:, 1] * s[:, 2] - m[:, 2] * s[:, 1], m[:, 1] * s[:, 1] + m[:, 2] * s[:, 2])


def accel_attitude_closed_form(params_st: NasaSensorParams, outputs_st: np.ndarray,
                               params_m: NasaSensorParams | None = None, outputs_m: np.ndarray | None = None,
                               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(Θ, Ψ, Φ or None), rad, from calibrated sting (and optionally model) package outputs (n, 3):
    invert the sensor model (Eqs. IV-B.1/2), then Eqs. IV-B.9-IV-B.11."""
    g_st = invert_nasa_outputs(params_st, outputs_st)
    pitch, yaw = closed_form_pitch_yaw(g_st)
    if params_m is None or outputs_m is None:
        return pitch, yaw, None
    return pitch, yaw, closed_form_roll(g_st, invert_nasa_outputs(params_m, outputs_m))


# ---- accelerometer: Gauss-Newton ----------------------------------------------------------------
def _batched_gauss_newton(residual_jac: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], x0: np.ndarray,
                          max_iter: int, tol: float) -> tuple[np.ndarray, int]:
    """X ← X + (JᵀJ)⁺Jᵀr for every sample at once (Eq. IV-B.17); r (n, m), J (n, m, p)."""
    x = x0.copy()
    it = 0
    for it in range(1, max_iter + 1):
        r, jac = residual_jac(x)
        jt = np.swapaxes(jac, 1, 2)
        dx = np.einsum("nij,nj->ni", np.linalg.pinv(jt @ jac), np.einsum("nij,nj->ni", jt, r))
        x = x + dx
        if float(np.max(np.abs(dx))) < tol:
            break
    return x, it


def gauss_newton_pitch_yaw(params_st: NasaSensorParams, outputs_st: np.ndarray, initial_rad: tuple[float, float] = (GN_INITIAL_RAD, GN_INITIAL_RAD),
                           max_iter: int = GN_MAX_ITER, tol: float = GN_TOL, gravity: float = REPORT_GRAVITY_G,
                           ) -> tuple[np.ndarray, np.ndarray, int]:
    """Pitch Θ, yaw Ψ (rad, (n,)) and iterations from sting package outputs (n, 3) by Gauss-Newton
    on V_i = B_i + S_i u_i·G_st(Θ, Ψ) (Eqs. IV-B.12-IV-B.23), each sample from ``initial_rad``."""
    v = np.atleast_2d(np.asarray(outputs_st, dtype=float))
    u = sensitive_axes(params_st.azimuth_rad, params_st.coning_rad)
    su = params_st.sensitivity[:, None] * u

    def rj(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        th, ps = x[:, 0], x[:, 1]
        g = sting_gravity(th, ps, gravity)
        dth = gravity * np.stack([-np.cos(th) * np.cos(ps), np.cos(th) * np.sin(ps), -np.sin(th)], axis=-1)
        dps = gravity * np.stack([np.sin(th) * np.sin(ps), np.sin(th) * np.cos(ps), np.zeros_like(th)], axis=-1)
        r = v - (params_st.bias + g @ su.T)
        return r, np.stack([dth @ su.T, dps @ su.T], axis=-1)

    x0 = np.tile(np.asarray(initial_rad, dtype=float), (v.shape[0], 1))
    x, it = _batched_gauss_newton(rj, x0, max_iter, tol)
    return x[:, 0], x[:, 1], it


def gauss_newton_roll(params_m: NasaSensorParams, outputs_m: np.ndarray, g_st: np.ndarray, initial_rad: float = GN_INITIAL_RAD,
                      max_iter: int = GN_MAX_ITER, tol: float = GN_TOL) -> tuple[np.ndarray, int]:
    """Roll Φ (rad, (n,)) and iterations from model package outputs (n, 3) and sting gravity
    components (n, 3) by Gauss-Newton (Eqs. IV-B.24-IV-B.28)."""
    v = np.atleast_2d(np.asarray(outputs_m, dtype=float))
    gs = np.atleast_2d(np.asarray(g_st, dtype=float))
    u = sensitive_axes(params_m.azimuth_rad, params_m.coning_rad)
    su = params_m.sensitivity[:, None] * u

    def rj(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c, s = np.cos(x[:, 0]), np.sin(x[:, 0])
        gm = np.stack([gs[:, 0], c * gs[:, 1] + s * gs[:, 2], -s * gs[:, 1] + c * gs[:, 2]], axis=-1)
        dgm = np.stack([np.zeros_like(c), -s * gs[:, 1] + c * gs[:, 2], -c * gs[:, 1] - s * gs[:, 2]], axis=-1)
        return v - (params_m.bias + gm @ su.T), (dgm @ su.T)[:, :, None]

    x, it = _batched_gauss_newton(rj, np.full((v.shape[0], 1), float(initial_rad)), max_iter, tol)
    return x[:, 0], it


# ---- gyro: kinematics ---------------------------------------------------------------------------
def euler_rates(angles_rad: np.ndarray, body_rate: np.ndarray) -> np.ndarray:
    """(Θ̇, Ψ̇, Φ̇) (n, 3) from angles (Θ, Ψ, Φ) (n, 3) rad and model-axes rates (n, 3):
    T_m/a⁻¹ Ω_m (Eqs. IV-D.2-IV-D.4), in the rate unit of ``body_rate``. Singular at cos Ψ = 0."""
    a = np.atleast_2d(np.asarray(angles_rad, dtype=float))
    w = np.atleast_2d(np.asarray(body_rate, dtype=float))
    ps, ph = a[:, 1], a[:, 2]
    c, s = np.cos(ph), np.sin(ph)
    dth = (c * w[:, 1] - s * w[:, 2]) / np.cos(ps)
    dps = s * w[:, 1] + c * w[:, 2]
    dph = w[:, 0] - np.sin(ps) * dth
    return np.stack([dth, dps, dph], axis=-1)


def quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product p ⊗ q of scalar-first quaternions (..., 4)."""
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    w1, x1, y1, z1 = np.moveaxis(p, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(q, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], axis=-1)


def quat_about_axis(axis: int, angle_rad: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) of rotations by ``angle_rad`` about body axis 0 (x), 1 (y) or 2 (z)."""
    a = np.asarray(angle_rad, dtype=float)
    q = np.zeros(a.shape + (4,))
    q[..., 0] = np.cos(a / 2)
    q[..., 1 + axis] = np.sin(a / 2)
    return q


def report_euler_to_quaternion(pitch_rad: np.ndarray, yaw_rad: np.ndarray, roll_rad: np.ndarray) -> np.ndarray:
    """Model-to-initial-orientation quaternion of the report's pitch-yaw-roll sequence (Θ about y,
    Ψ about z', Φ about x''; Eqs. III-B.3-III-B.5): q = q_y(Θ) ⊗ q_z(Ψ) ⊗ q_x(Φ)."""
    return quat_multiply(quat_multiply(quat_about_axis(1, pitch_rad), quat_about_axis(2, yaw_rad)), quat_about_axis(0, roll_rad))


def quat_angle_rad(q: np.ndarray) -> np.ndarray:
    """Rotation angle (rad, in [0, π]) of unit quaternions (..., 4)."""
    q = np.asarray(q, dtype=float)
    return 2 * np.arctan2(np.linalg.norm(q[..., 1:], axis=-1), np.abs(q[..., 0]))


def quat_to_dcm(q: np.ndarray) -> np.ndarray:
    """Direction cosine matrices (..., 3, 3) with v_ref = C v_body for unit quaternions (..., 4)."""
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                     np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                     np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


# ---- gyro: Runge-Kutta integration --------------------------------------------------------------
def _check_series(t_s: np.ndarray, rate: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(t_s, dtype=float)
    w = np.asarray(rate, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise InputError(f"need at least two sample times, got shape {t.shape}")
    if w.shape != (t.size, 3):
        raise InputError(f"rates must have shape ({t.size}, 3) to match the times, got {w.shape}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(w))):
        raise InputError("times and rates must be finite numbers (found NaN or inf)")
    if np.any(np.diff(t) <= 0):
        raise InputError("sample times must increase strictly")
    return t, w


def _interpolator(t: np.ndarray, w: np.ndarray) -> Callable[[float], np.ndarray]:
    if t.size >= 4:
        from scipy.interpolate import CubicSpline

        spline = CubicSpline(t, w, axis=0)
        return lambda tt: spline(tt)
    return lambda tt: np.array([np.interp(tt, t, w[:, k]) for k in range(3)])


def _integrate(f: Callable[[float, np.ndarray], np.ndarray], t: np.ndarray, y0: np.ndarray, method: str,
               post: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    if method not in _TABLEAUX:
        raise InputError(f"unknown Runge-Kutta method {method!r}: expected one of {', '.join(_TABLEAUX)}")
    stages, weights = _TABLEAUX[method]
    out = np.empty((t.size, y0.size))
    out[0] = y0
    y = y0.copy()
    for i in range(t.size - 1):
        h = t[i + 1] - t[i]
        ks: list[np.ndarray] = []
        for c, a in stages:
            yi = y + h * sum((aj * kj for aj, kj in zip(a, ks)), np.zeros_like(y))
            ks.append(f(t[i] + c * h, yi))
        y = y + h * sum(wj * kj for wj, kj in zip(weights, ks))
        if post is not None:
            y = post(y)
        out[i + 1] = y
    return out


def integrate_gyro_quaternion(t_s: np.ndarray, body_rate_rad_s: np.ndarray, q0: np.ndarray | None = None,
                              method: str = "rk4") -> np.ndarray:
    """Attitude quaternions (n, 4) at ``t_s`` (s) from body rates (n, 3, rad/s) by Runge-Kutta on
    q̇ = ½ q ⊗ (0, ω), renormalised after each step; ``q0`` defaults to identity."""
    t, w = _check_series(t_s, body_rate_rad_s)
    rate = _interpolator(t, w)
    y0 = np.array([1.0, 0.0, 0.0, 0.0]) if q0 is None else np.asarray(q0, dtype=float)
    if y0.shape != (4,) or not np.isfinite(y0).all() or np.linalg.norm(y0) == 0:
        raise InputError(f"q0 must be a non-zero quaternion (w, x, y, z), got {q0!r}")
    y0 = y0 / np.linalg.norm(y0)

    def f(tt: float, q: np.ndarray) -> np.ndarray:
        return 0.5 * quat_multiply(q, np.concatenate([[0.0], rate(tt)]))

    return _integrate(f, t, y0, method, post=lambda q: q / np.linalg.norm(q))


def integrate_gyro_euler(t_s: np.ndarray, body_rate_rad_s: np.ndarray, angles0_rad: np.ndarray = (0.0, 0.0, 0.0),
                         method: str = "rk5") -> np.ndarray:
    """The report's gyro attitude construction: (Θ, Ψ, Φ) (n, 3, rad) at ``t_s`` (s) from
    model-axes rates (n, 3, rad/s) by Runge-Kutta on Eq. IV-D.4 (default its 5th-order method,
    Eqs. IV-D.6/7), starting from ``angles0_rad`` (the pretest alignment)."""
    t, w = _check_series(t_s, body_rate_rad_s)
    rate = _interpolator(t, w)
    a0 = np.asarray(angles0_rad, dtype=float)
    if a0.shape != (3,) or not np.isfinite(a0).all():
        raise InputError(f"angles0_rad must be three finite angles (pitch, yaw, roll), got {angles0_rad!r}")
    return _integrate(lambda tt, a: euler_rates(a, rate(tt))[0], t, a0.copy(), method)


def gyro_body_rates(params: NasaSensorParams, outputs: np.ndarray) -> np.ndarray:
    """Body rates (n, 3) from calibrated gyro outputs (n, 3): T_sn⁻¹ S⁻¹ (V − B) (Eq. IV-D.1), in
    the rate unit of the calibration's sensitivity."""
    return invert_nasa_outputs(params, outputs)
