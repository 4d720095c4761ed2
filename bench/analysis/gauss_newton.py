"""Gauss-Newton calibration of accelerometers and gyros with the NASA AMS sensor model.

Source: NASA/CR-2003 "High-accuracy angular measurement system for hypersonic wind tunnels"
(contractor report, Old Dominion University for NASA LaRC), called "the report" below; equation
numbers are the report's. ``docs/gauss-newton.md`` has the derivation and the conventions.

Sensor model (section III-B/III-C; implemented once, in :mod:`bench.model.accel`, and fitted
here). Each sensor axis k (x, y, z) of a package has a bias B, a
sensitivity S, an azimuth angle A and a coning angle C. A and C turn the desired measurement
axis into the true sensitive axis: azimuth rotation A about the desired axis k, then coning
rotation C about the next intermediate axis (x: A about x then C about y; y: A about y then C
about z; z: A about z then C about x; Eqs. III-B.7-III-B.12, III-C.6-III-C.11). The row of the
resulting transformation that belongs to axis k (Eqs. III-B.14, III-C.13) is the sensitive-axis
unit vector, with (k, p, q) the cyclic order (x, y, z), (y, z, x), (z, x, y)::

    u_k = cos C,   u_p = sin A sin C,   u_q = -cos A sin C

and the output is (Eqs. III-B.23/24, III-C.14)::

    V_k = B_k + S_k (u(A_k, C_k) · v)

with v the input vector in the desired (nominal) axes: the gravity vector for the report's
accelerometers (Eqs. III-B.25-III-B.32), the angular velocity for its gyros (Eqs.
III-C.15-III-C.18). C is the angle between desired and true axis (a cone half-angle, reported
≥ 0); A is measured in the plane normal to the desired axis from -q toward +p ("the angle
subtended by the -z_st axis and projected excitation axis" for the x axis, Figure 5).

Calibration (section IV-A, IV-C): each axis has its own unknown quadruple X = [B S A C]ᵀ and is
solved independently by the Gauss-Newton iteration X ← X + (JᵀJ)⁻¹Jᵀ(V − V_r) (Eqs. IV-A.6,
IV-C.6) with the analytic Jacobian (Eqs. IV-A.7-IV-A.32, IV-C.7-IV-C.18).

Bench conventions (``calibrate``): accelerometer input = specific force in the sensor frame (g),
from the rate table's platter angle θ (``table_angle_deg``) and tilt φ (``tilt_deg``):
f = [-cos θ sin φ, sin θ sin φ, cos φ] (``bench.sim.world``), which is the report's sting-frame
gravity vector G_st of Eq. III-B.6 / IV-B.3-IV-B.5 with pitch Θ = φ, yaw Ψ = θ and G = 1 g;
gyro input = the rate table's reference rate in the sensor frame (deg/s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.analysis.result import CalibrationResult, ResultTable
from bench.errors import InputError, Location, finite_number
from bench.model.accel import NasaSensorParams, nasa_sensor_input, sensitive_axes, sting_gravity

AXES = ("x", "y", "z")

REPORT_GRAVITY_G = 1.0
"""G in the report's MATLAB listings ("g = 1", Appendix B), so sensitivities are in V/g."""

REPORT_ACCEL_INITIAL = (1.23, 0.45, math.radians(0.07), math.radians(0.06))
"""Initial guess (B V, S V/g, A rad, C rad) of the report's accelerometer calibration (Appendix B:
b0 = 1.23, S0 = 0.45, A0 = 0.07*d2r, Om0 = 0.06*d2r)."""

REPORT_GYRO_INITIAL = (0.05, 1.25, math.radians(0.1), math.radians(0.1))
"""Initial guess (B V, S V/(deg/s), A rad, C rad) of the report's gyro calibration (Appendix D:
b0 = 0.05, S0 = 1.25, A0 = 0.1*d2r, Om0 = 0.1*d2r)."""

MAX_ITER = 100
"""Iteration limit of the report's calibration loops (Appendix B: ``for ii=1:100``)."""

TOL = 1e-12
"""Stop when the Gauss-Newton step ‖ΔX‖ (mixed units, as the report's ``error_D``, Appendix B/D)
falls below this. The report used 1e-32 (accelerometers, i.e. always 100 iterations) and 1e-10
(gyros); 1e-12 is reached in a few iterations and is below every printed digit of Tables 3/4."""

RANK_RCOND = 1e-10
"""Relative singular-value threshold of the column-scaled Jacobian below which a parameter is
declared not determined by the positions (numerical rank deficiency; numerical choice, no source)."""


# ---- model (bench.model.accel holds the forward model; this module fits it) -------------------
def invert_nasa_outputs(params: NasaSensorParams, outputs: np.ndarray) -> np.ndarray:
    """Input vectors (n, 3) from package outputs (n, 3): v = T_sn⁻¹ S⁻¹ (V − B) (Eqs. IV-B.1/2,
    IV-D.1), i.e. :func:`bench.model.accel.nasa_sensor_input` raising ``InputError`` (zero or
    non-finite sensitivity, coplanar sensitive axes) instead of ``ValueError``."""
    if not np.all(np.isfinite(params.sensitivity)):
        raise InputError(f"cannot invert the sensor model: sensitivities {params.sensitivity.tolist()} must be finite and non-zero")
    try:
        return np.atleast_2d(nasa_sensor_input(params, np.atleast_2d(np.asarray(outputs, dtype=float))))
    except ValueError as exc:
        raise InputError(f"cannot invert the sensor model: {exc} (sensitivities {params.sensitivity.tolist()} "
                         "must be finite and non-zero)") from None


def _axis_design(k: int, x: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Model output (n,) and Jacobian (n, 4) of axis k at X = [B, S, A, C] for inputs v (n, 3).

    Jacobian columns: ∂V/∂B = 1, ∂V/∂S = u·v, ∂V/∂A = S (∂u/∂A)·v, ∂V/∂C = S (∂u/∂C)·v; the
    report writes these out per axis and package (Eqs. IV-A.7-IV-A.32, IV-C.7-IV-C.18).
    """
    b, s, a, c = x
    p, q = (k + 1) % 3, (k + 2) % 3
    sa, ca, sc, cc = math.sin(a), math.cos(a), math.sin(c), math.cos(c)
    vk, vp, vq = v[:, k], v[:, p], v[:, q]
    proj = v @ sensitive_axes(np.full(3, a), np.full(3, c))[k]
    d_a = ca * sc * vp + sa * sc * vq
    d_c = -sc * vk + sa * cc * vp - ca * cc * vq
    jac = np.column_stack([np.ones_like(proj), proj, s * d_a, s * d_c])
    return b + s * proj, jac


def report_model_from_sting(roll_rad: np.ndarray, vectors_st: np.ndarray) -> np.ndarray:
    """Vectors (n, 3) in the report's model axes from sting axes: T_m/st (roll Φ about x_st, rad;
    Eq. III-B.5)."""
    ph = np.asarray(roll_rad, dtype=float)
    v = np.atleast_2d(np.asarray(vectors_st, dtype=float))
    c, s = np.cos(ph), np.sin(ph)
    return np.stack([v[:, 0], c * v[:, 1] + s * v[:, 2], -s * v[:, 1] + c * v[:, 2]], axis=-1)


# ---- Gauss-Newton calibration -------------------------------------------------------------------
@dataclass
class NasaFit:
    """Result of :func:`gauss_newton_calibrate` for the fitted axes (``axes``, e.g. ('x', 'y', 'z')).

    ``params``/``std_errors``: :class:`NasaSensorParams` (angles in rad; NaN for axes not fitted);
    standard errors from σ²(JᵀJ)⁻¹ with σ² = Σr²/(n − 4). ``iterations``, ``residual_rms`` (output
    units), ``converged``: per fitted axis. ``covariance``: (axes, 4, 4) in the order B, S, A, C.
    """

    axes: tuple[str, ...]
    params: NasaSensorParams
    std_errors: NasaSensorParams
    iterations: list[int]
    residual_rms: list[float]
    converged: list[bool]
    covariance: np.ndarray
    n_points: int
    notes: list[str] = field(default_factory=list)

    @property
    def total_residual_rms(self) -> float:
        """RMS of all residuals of the fitted axes (output units)."""
        return float(math.sqrt(np.mean(np.square(self.residual_rms)))) if self.residual_rms else float("nan")


def _initial_from_linear(k: int, v: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Starting X = [B, S, A, C] from the linear fit y = B + w·v, w = S u (same model, linear in
    B and w); used when no initial guess is given."""
    m = np.column_stack([np.ones(v.shape[0]), v])
    coef, *_ = np.linalg.lstsq(m, y, rcond=None)
    b, w = float(coef[0]), coef[1:]
    s = float(np.linalg.norm(w))
    if s == 0.0:
        return np.array([b, 1.0, 0.0, 0.0])
    p, q = (k + 1) % 3, (k + 2) % 3
    u = w / s
    c = math.acos(max(-1.0, min(1.0, u[k])))
    a = math.atan2(u[p], -u[q]) if math.hypot(u[p], u[q]) > 0 else 0.0
    return np.array([b, s, a, c])


def _normalise(x: np.ndarray) -> np.ndarray:
    """Canonical (A, C): C ≥ 0 ((A, C) and (A + π, −C) give the same axis), A in (−π, π]."""
    b, s, a, c = (float(t) for t in x)
    if c < 0:
        c, a = -c, a + math.pi
    a = math.atan2(math.sin(a), math.cos(a))
    return np.array([b, s, a, c])


def _fit_axis(k: int, v: np.ndarray, y: np.ndarray, x0: np.ndarray, max_iter: int, tol: float,
              ) -> tuple[np.ndarray, np.ndarray, int, float, bool, list[str]]:
    """Gauss-Newton for one axis (Eq. IV-A.6/IV-C.6) with step halving when a full step would
    increase the sum of squares (a safeguard; the fixed point is the report's). Returns X,
    covariance, iterations, residual RMS, converged flag and notes."""
    notes: list[str] = []
    x = np.asarray(x0, dtype=float).copy()
    model, jac = _axis_design(k, x, v)
    r = y - model
    cost = float(r @ r)
    converged = False
    it = 0
    for it in range(1, max_iter + 1):
        scale = np.linalg.norm(jac, axis=0)
        scale[scale == 0] = 1.0
        # minimum-norm step: with sin C = 0 the azimuth column vanishes and A is left unchanged
        dx = np.linalg.lstsq(jac / scale, r, rcond=RANK_RCOND)[0] / scale
        step = 1.0
        while True:
            x_new = x + step * dx
            m_new, j_new = _axis_design(k, x_new, v)
            r_new = y - m_new
            cost_new = float(r_new @ r_new)
            if cost_new <= cost or step < 1e-6:
                break
            step /= 2
        x, jac, r, cost = x_new, j_new, r_new, cost_new
        if float(np.linalg.norm(step * dx)) < tol:
            converged = True
            break
    if not converged:
        notes.append(f"axis {AXES[k]}: Gauss-Newton did not reach the step tolerance {tol:g} in {max_iter} iterations")
    x = _normalise(x)
    model, jac = _axis_design(k, x, v)
    r = y - model
    n = y.shape[0]
    dof = n - 4
    s2 = float(r @ r) / dof if dof > 0 else float("nan")
    scale = np.linalg.norm(jac, axis=0)
    scale[scale == 0] = 1.0
    _, sv, vt = np.linalg.svd(jac / scale, full_matrices=False)
    if sv[-1] <= RANK_RCOND * sv[0]:
        # only possible through sin C = 0 (the inputs were checked): the azimuth is undefined
        notes.append(f"axis {AXES[k]}: coning angle is 0, so the azimuth is undefined (standard error inf)")
        keep = [0, 1, 3]
        cov = np.full((4, 4), np.nan)
        cov[np.ix_(keep, keep)] = s2 * np.linalg.pinv(jac[:, keep].T @ jac[:, keep])
        cov[2, 2] = math.inf
    else:
        cov = s2 * ((vt.T / sv**2) @ vt) / np.outer(scale, scale)
    return x, cov, it, float(math.sqrt(np.mean(r**2))), converged, notes


def _rank_message(v: np.ndarray) -> str:
    m = np.column_stack([np.ones(v.shape[0]), v])
    sv = np.linalg.svd(m / np.maximum(np.linalg.norm(m, axis=0), 1e-300), compute_uv=False)
    rank = int(np.sum(sv > RANK_RCOND * sv[0]))
    return ("the positions do not determine bias, sensitivity, azimuth and coning "
            f"(the input vectors and a constant span only {rank} of the 4 needed directions); use input "
            "vectors with components along all three axes that change between positions, e.g. several "
            "tilts and table angles for an accelerometer, rates about all three axes for a gyro")


def gauss_newton_calibrate(true_vectors: np.ndarray, outputs: np.ndarray, initial: Any = None,
                           max_iter: int = MAX_ITER, tol: float = TOL, axes: tuple[str, ...] | None = None) -> NasaFit:
    """Fit B, S, A, C per axis to outputs V (n, m) of axes ``axes`` (default x, y, z for m = 3;
    a 1-D ``outputs`` needs one axis name) from known input vectors (n, 3) in the desired axes.

    ``initial``: :class:`NasaSensorParams`, a quadruple (B, S, A_rad, C_rad) used for every axis,
    or None (a linear least-squares start, exact on noise-free data). Stops when ‖ΔX‖ < ``tol`` or
    after ``max_iter`` iterations (Eq. IV-A.6). Raises ``InputError`` on mismatched shapes,
    non-finite values, fewer than 5 points (4 unknowns and one degree of freedom for σ²) or
    positions that do not determine the parameters.
    """
    v = np.asarray(true_vectors, dtype=float)
    y = np.asarray(outputs, dtype=float)
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputError(f"true vectors must have shape (n, 3), got {v.shape}")
    if y.ndim == 1:
        y = y[:, None]
    if y.ndim != 2 or y.shape[0] != v.shape[0]:
        raise InputError(f"outputs must have one row per true vector ({v.shape[0]}), got shape {np.shape(outputs)}")
    axes = tuple(axes) if axes is not None else (AXES if y.shape[1] == 3 else ())
    if len(axes) != y.shape[1] or any(a not in AXES for a in axes):
        raise InputError(f"name the axis of each output column (x, y, z); got axes {axes!r} for {y.shape[1]} column(s)")
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(y))):
        raise InputError("true vectors and outputs must be finite numbers (found NaN or inf)")
    if v.shape[0] < 5:
        raise InputError(f"too few positions: {v.shape[0]}; the Gauss-Newton calibration fits 4 parameters "
                         "per axis (bias, sensitivity, azimuth, coning) and needs at least 5")
    try:
        max_iter, tol = int(max_iter), float(tol)
    except (TypeError, ValueError):
        raise InputError(f"max_iter and tol must be numbers, got {max_iter!r}, {tol!r}") from None
    if max_iter < 1 or not tol > 0:
        raise InputError(f"max_iter must be ≥ 1 and tol > 0, got {max_iter!r}, {tol!r}")
    lin = np.column_stack([np.ones(v.shape[0]), v])
    sv = np.linalg.svd(lin / np.maximum(np.linalg.norm(lin, axis=0), 1e-300), compute_uv=False)
    if sv[-1] <= RANK_RCOND * sv[0]:
        raise InputError(_rank_message(v))
    nan = np.full(3, np.nan)
    est = {name: nan.copy() for name in ("b", "s", "a", "c")}
    se = {name: nan.copy() for name in ("b", "s", "a", "c")}
    iters: list[int] = []
    rms: list[float] = []
    conv: list[bool] = []
    covs = []
    notes: list[str] = []
    for col, name in enumerate(axes):
        k = AXES.index(name)
        if initial is None:
            x0 = _initial_from_linear(k, v, y[:, col])
        elif isinstance(initial, NasaSensorParams):
            x0 = np.array([initial.bias[k], initial.sensitivity[k], initial.azimuth_rad[k], initial.coning_rad[k]])
        else:
            try:
                x0 = np.asarray(initial, dtype=float).reshape(4)
            except (TypeError, ValueError):
                raise InputError(f"initial must be NasaSensorParams or four numbers (B, S, A_rad, C_rad), got {initial!r}") from None
            if not np.all(np.isfinite(x0)):
                raise InputError(f"initial must be finite, got {initial!r}")
        x, cov, it, r, ok, n_ = _fit_axis(k, v, y[:, col], x0, int(max_iter), float(tol))
        for i, key in enumerate(("b", "s", "a", "c")):
            est[key][k] = x[i]
            se[key][k] = math.sqrt(cov[i, i]) if cov[i, i] >= 0 else float("nan")
        iters.append(it)
        rms.append(r)
        conv.append(ok)
        covs.append(cov)
        notes += n_
    return NasaFit(axes=axes, params=NasaSensorParams(est["b"], est["s"], est["a"], est["c"]),
                   std_errors=NasaSensorParams(se["b"], se["s"], se["a"], se["c"]), iterations=iters,
                   residual_rms=rms, converged=conv, covariance=np.array(covs), n_points=int(v.shape[0]), notes=notes)


# ---- calibrate(ds) ------------------------------------------------------------------------------
_KNOWN_OPTS = {"sensor", "tilt_deg", "mount", "initial", "max_iter", "tol", "still_dps", "angle_tol_deg",
               "rate_tol_dps", "settle_s", "min_samples"}

STILL_DPS = 0.05
"""A table slower than this (deg/s) counts as stationary for the accelerometer positions (bench
choice: well above the simulator's encoder noise, well below any commanded move)."""

ANGLE_TOL_DEG = 0.05
"""Samples within this of a position's first table angle/tilt (deg) belong to that position."""

RATE_TOL_DPS = 0.01
"""Samples within this of a plateau's first reference rate (deg/s, each axis) belong to that plateau."""

MIN_SAMPLES = 5
"""Positions or rate plateaus with fewer samples are dropped (transients)."""


def calibrate(ds: Any, sensor: str = "accel", **opts: Any) -> CalibrationResult:
    """``bench calibrate gauss-newton``: fit the NASA model to an accelerometer or gyro triad.

    ``sensor="accel"``: stationary table positions (|table rate| < ``still_dps``); the specific
    force in the sensor frame follows from ``table_angle_deg`` and the tilt (``tilt_deg`` option:
    a number or one value per row; else a ``tilt_deg`` column; else ``tilt_deg`` in the metadata;
    else the run file's rate-table monitor) and ``mount`` (sensor axis along the platter normal,
    default ``z``). ``sensor="gyro"``: ``gyro_*_dps`` against ``ref_rate_*_dps`` on constant-rate
    plateaus. Each position/plateau contributes its mean (after ``settle_s`` s). Other options:
    ``initial`` (B, S, A_rad, C_rad), ``max_iter``, ``tol``, ``angle_tol_deg``, ``rate_tol_dps``,
    ``min_samples``. Returns a :class:`bench.analysis.result.CalibrationResult` whose JSON is
    ``{"sensor", "axes": {"x": {"bias", "sensitivity", "azimuth_deg", "coning_deg", "se": {...}}},
    "iterations", "residual_rms", ...}``. Bad input raises ``InputError``.
    """
    opts = {k: v for k, v in opts.items() if v is not None}
    sensor = str(opts.pop("sensor", sensor) or "accel")
    notes: list[str] = []
    unknown = sorted(set(opts) - _KNOWN_OPTS)
    if unknown:
        notes.append(f"ignored option(s): {', '.join(unknown)}")
    src = getattr(ds, "source", "") or "data"
    where = Location(src)
    if sensor not in ("accel", "gyro"):
        raise InputError(f"unknown sensor {sensor!r}: expected 'accel' or 'gyro'", where, "sensor")
    if len(ds) == 0:
        raise InputError("no data rows", where)
    max_iter = int(_num(opts.get("max_iter", MAX_ITER), "max_iter", where))
    tol = _num(opts.get("tol", TOL), "tol", where)
    min_samples = int(_num(opts.get("min_samples", MIN_SAMPLES), "min_samples", where))
    settle_s = _num(opts.get("settle_s", 0.0), "settle_s", where)
    initial = opts.get("initial")
    if initial is not None and not isinstance(initial, NasaSensorParams):
        try:
            initial = np.asarray([float(t) for t in (initial.split(",") if isinstance(initial, str) else initial)])
        except (TypeError, ValueError):
            initial = np.zeros(0)
        if initial.shape != (4,) or not np.all(np.isfinite(initial)):
            raise InputError(f"initial must be four numbers B, S, A_rad, C_rad, got {opts.get('initial')!r}", where, "initial")

    t = np.asarray(ds["time_s"], dtype=float)
    if sensor == "accel":
        out_cols = [f"accel_{a}_g" for a in AXES]
        _require(ds, out_cols + ["table_angle_deg"], where, "an accelerometer calibration")
        angle = np.asarray(ds["table_angle_deg"], dtype=float)
        tilt, tilt_note = tilt_per_row(ds, opts, where)
        if tilt_note:
            notes.append(tilt_note)
        mount = mount_of(opts.get("mount", ds.meta.get("mount", "z")), where)
        rate = _gradient(angle, t)
        still_dps = _num(opts.get("still_dps", STILL_DPS), "still_dps", where)
        tilt_rate = _gradient(tilt, t)
        ok = np.isfinite(angle) & np.isfinite(tilt) & (np.abs(rate) < still_dps) & (np.abs(tilt_rate) < still_dps)
        keys = np.column_stack([angle, tilt])
        groups = _plateaus(keys, ok, _num(opts.get("angle_tol_deg", ANGLE_TOL_DEG), "angle_tol_deg", where), t, settle_s, min_samples)
        kind, in_unit, out_unit = "stationary table positions", "g", "g"
        def inputs(idx: np.ndarray) -> np.ndarray:
            f = sting_gravity(np.radians(tilt[idx]), np.radians(angle[idx]), 1.0)
            return f @ mount.T
    else:
        out_cols = [f"gyro_{a}_dps" for a in AXES]
        ref_cols = [f"ref_rate_{a}_dps" for a in AXES]
        _require(ds, out_cols + ref_cols, where, "a gyro calibration")
        ref = np.column_stack([np.asarray(ds[c], dtype=float) for c in ref_cols])
        ok = np.all(np.isfinite(ref), axis=1)
        groups = _plateaus(ref, ok, _num(opts.get("rate_tol_dps", RATE_TOL_DPS), "rate_tol_dps", where), t, settle_s, min_samples)
        kind, in_unit, out_unit = "constant-rate plateaus", "deg/s", "deg/s"
        def inputs(idx: np.ndarray) -> np.ndarray:
            return ref[idx]

    out = np.column_stack([np.asarray(ds[c], dtype=float) for c in out_cols])
    groups = [g for g in groups if np.all(np.isfinite(out[g]))]
    if len(groups) < 5:
        hint = (" A session of six faces and hand or table rotations (Ferraris, imucal) is read by "
                "`bench calibrate six-position`." if sensor == "gyro" else "")
        raise InputError(f"too few positions: found {len(groups)} {kind} with at least {min_samples} samples; "
                         "the Gauss-Newton calibration fits 4 parameters per axis and needs at least 5 "
                         f"(the report used 1,001 orientations).{hint}", where)
    v = np.array([inputs(g).mean(axis=0) for g in groups])
    y = np.array([out[g].mean(axis=0) for g in groups])
    try:
        fit = gauss_newton_calibrate(v, y, initial=initial, max_iter=max_iter, tol=tol)
    except InputError as exc:  # about the positions of this file: say which file
        raise InputError(exc.message, exc.location or where, exc.field) from None
    notes += fit.notes
    p, e = fit.params, fit.std_errors
    axes_json: dict[str, Any] = {}
    rows = []
    for k, a in enumerate(AXES):
        axes_json[a] = {
            "bias": _jnum(p.bias[k]), "sensitivity": _jnum(p.sensitivity[k]),
            "azimuth_deg": _jnum(math.degrees(p.azimuth_rad[k])), "coning_deg": _jnum(math.degrees(p.coning_rad[k])),
            "se": {"bias": _jnum(e.bias[k]), "sensitivity": _jnum(e.sensitivity[k]),
                   "azimuth_deg": _jnum(math.degrees(e.azimuth_rad[k])), "coning_deg": _jnum(math.degrees(e.coning_rad[k]))},
            "iterations": int(fit.iterations[k]), "residual_rms": _jnum(fit.residual_rms[k]),
        }
        rows.append([a, f"{p.bias[k]:.6g} ± {e.bias[k]:.2g}", f"{p.sensitivity[k]:.6g} ± {e.sensitivity[k]:.2g}",
                     f"{math.degrees(p.azimuth_rad[k]):.4f} ± {math.degrees(e.azimuth_rad[k]):.2g}",
                     f"{math.degrees(p.coning_rad[k]):.4f} ± {math.degrees(e.coning_rad[k]):.2g}",
                     f"{fit.residual_rms[k]:.3g}"])
        if p.coning_rad[k] < 3 * e.coning_rad[k]:
            notes.append(f"axis {a}: coning angle within 3 standard errors of 0, so the azimuth is poorly defined")
    payload = {
        "sensor": sensor, "axes": axes_json, "iterations": int(max(fit.iterations)),
        "residual_rms": _jnum(fit.total_residual_rms), "positions": len(groups),
        "units": {"bias": out_unit, "sensitivity": f"{out_unit}/({in_unit})", "residual_rms": out_unit},
    }
    table = ResultTable(
        title=f"Gauss-Newton {sensor} calibration (NASA AMS model), {len(groups)} {kind}",
        headers=["axis", f"bias ({out_unit})", f"sensitivity ({out_unit}/({in_unit}))", "azimuth (deg)", "coning (deg)",
                 f"residual RMS ({out_unit})"],
        rows=rows)
    calibration = {"method": "gauss-newton", "sensor": sensor, "model": "V = B + S (u(A, C) . v)", "axes": axes_json}
    return CalibrationResult(method="gauss-newton", json=payload, tables=[table], calibration=calibration, notes=notes)


def _jnum(x: float) -> float | None:
    """A float for JSON; None for NaN/inf (e.g. the azimuth's standard error when C = 0)."""
    x = float(x)
    return x if math.isfinite(x) else None


def _num(value: Any, name: str, where: Location) -> float:
    return finite_number(value, where, name)


def _require(ds: Any, cols: list[str], where: Location, what: str) -> None:
    missing = [c for c in cols if c not in ds]
    if missing:
        raise InputError(f"{what} needs column(s) {', '.join(missing)} (present: {', '.join(ds.columns)})", where)


def tilt_per_row(ds: Any, opts: dict[str, Any], where: Location) -> tuple[np.ndarray, str]:
    """Per-row tilt (deg) and a note saying where it came from: the ``tilt_deg`` option (one number
    or one per row), a ``tilt_deg`` column (CSV, ``--map tilt=...``), ``tilt_deg`` in the metadata
    (``# tilt_deg: 90``, ``--map tilt_deg=90``) or the run file's rate-table monitor."""
    n = len(ds)
    if "tilt_deg" in opts:
        raw = opts["tilt_deg"]
        if np.ndim(raw) == 0:
            return np.full(n, _num(raw, "tilt_deg", where)), ""
        try:
            arr = np.asarray(raw, dtype=float)
        except (TypeError, ValueError):
            raise InputError("tilt_deg must be one number or one number per row", where, "tilt_deg") from None
        if arr.shape != (n,):
            raise InputError(f"tilt_deg must be one number or one value per row ({n}), got shape {arr.shape}", where, "tilt_deg")
        return arr, ""
    if "tilt_deg" in ds:
        return np.asarray(ds["tilt_deg"], dtype=float), ""
    if "tilt_deg" in ds.meta:
        return np.full(n, _num(ds.meta["tilt_deg"], "tilt_deg", where)), ""
    tilt = _tilt_from_run(ds)
    if tilt is not None:
        return tilt, "tilt taken from the run file's rate table (its monitor's table_tilt)"
    raise InputError("the accelerometer calibration needs the table tilt: give tilt_deg (option, column or "
                     "metadata) or a run file with a rate table's monitor (a table_tilt reading)", where, "tilt_deg")


def _tilt_from_run(ds: Any) -> np.ndarray | None:
    """The rate table's tilt (the column with role ``table_tilt``) interpolated onto the dataset's
    times, when ``ds`` came from a run file (``load_dataset`` does not expose it yet); None otherwise."""
    from pathlib import Path

    src = Path(getattr(ds, "source", "") or "")
    if src.suffix.lower() not in (".h5", ".hdf5") or not src.is_file():
        return None
    try:
        from bench.record import by_kind
        from bench.record.reader import read_run_summary, read_stream

        col = by_kind.first(read_run_summary(src, event_kinds=()), "table_tilt")
        mon = read_stream(src, col.key)
        tm = np.asarray(mon["time"], dtype=float)
        tilt = np.asarray(mon[col.column], dtype=float)
    except Exception:  # noqa: BLE001 - no monitor or no tilt field: the tilt is simply unknown
        return None
    if tm.size == 0:
        return None
    return np.interp(np.asarray(ds["time_s"], dtype=float), tm, tilt)


def mount_of(value: Any, where: Location) -> np.ndarray:
    """The mount matrix of ``value`` (the sensor axis along the platter normal, e.g. ``z``, ``-x``)."""
    from bench.model.geometry import mount_matrix

    try:
        return mount_matrix(str(value).strip())
    except ValueError as exc:
        raise InputError(str(exc), where, "mount") from None


def _gradient(x: np.ndarray, t: np.ndarray) -> np.ndarray:
    if x.shape[0] < 2:
        return np.zeros_like(x)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.gradient(x, t)


def _plateaus(keys: np.ndarray, ok: np.ndarray, tol: float, t: np.ndarray, settle_s: float, min_samples: int) -> list[np.ndarray]:
    """Runs of consecutive ``ok`` rows whose ``keys`` stay within ``tol`` of the run's first row;
    the first ``settle_s`` seconds of each run are dropped, runs under ``min_samples`` discarded."""
    keys = np.atleast_2d(keys.T).T if keys.ndim == 1 else keys
    groups: list[np.ndarray] = []
    start = None
    for i in range(keys.shape[0] + 1):
        same = (i < keys.shape[0] and ok[i] and start is not None
                and bool(np.all(np.abs(keys[i] - keys[start]) <= tol)))
        if same:
            continue
        if start is not None:
            idx = np.arange(start, i)
            idx = idx[t[idx] >= t[start] + settle_s]
            if idx.size >= max(min_samples, 1):
                groups.append(idx)
        start = i if (i < keys.shape[0] and ok[i]) else None
    return groups
