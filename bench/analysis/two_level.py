"""Two-level speed × temperature calibration (method ``two-level``), ESTCube-2 thesis section 4.3.

ESTCube-2 measured the gyros on the stepper bench at 9 speeds (0-3 deg/s) at each of 4 chamber
temperatures (-20.4, 0.1, 20.2, 59.8 °C) and fitted "two types of calibration functions", both of the
second-order form of Eq. 4.1, f(x) = p1·x² + p2·x + p3:

* the temperature function gives the offset to add to the measurement at temperature T (°C):
  ``correction(T) = p1·T² + p2·T + p3``;
* its three coefficients come from the speed functions of the speed v (deg/s):
  ``p_i(v) = p_i1·v² + p_i2·v + p_i3``  (Table 4.1: row "p_i-BMG", columns "p1-speed",
  "p2-speed", "p3-speed").

So ``correction(v, T) = Σ_i p_i(v)·T^(3−i)`` and the corrected rate is ``measured + correction``.
The fit follows the thesis' two levels: at each speed a quadratic in T through the per-temperature
means, then for each of p1, p2, p3 a quadratic in v through the per-speed values. Standard errors
are those of each least-squares level (level 1 needs ≥ 4 temperatures, level 2 ≥ 4 speeds, else
``null``).

Input: a :class:`~bench.analysis.dataset.Dataset` with ``ref_rate_<axis>_dps`` (the bench speed),
``temp_c`` and ``gyro_<axis>_dps``. Constant-speed steps are found as for ``rate-transfer``; steps
of one speed whose mean temperatures are within ``temp_tol_c`` form one temperature level.

JSON (``--json``)::

    {"form": "...", "target": "correction" | "offset",
     "axes": {"z": {"coefficients": [[p11, p12, p13], [p21, p22, p23], [p31, p32, p33]],
                    "coefficients_se": [[...], [...], [...]],
                    "levels": [{"speed_dps": v, "temp_poly": [p1, p2, p3], "temp_poly_se": [...],
                                "points": [{"temp_c": T, "mean_output_dps": m, "correction_dps": c,
                                            "n_steps": k}, ...]}, ...],
                    "residual_rms_dps": r, "residual_max_dps": r,
                    "speed_range_dps": [lo, hi], "temp_range_c": [lo, hi]}}}

``coefficients[i][j]`` is Table 4.1's cell (row p(i+1), column p(j+1)-speed): descending powers of T
across rows and of v across columns, exactly as the thesis prints them. With ``target=offset`` the
fitted quantity is the measured offset ``output − speed`` instead of the correction ``speed −
output`` (the thesis: the function "outputs the offset which needs to be added to the taken
measurement", i.e. the correction, the default).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from bench.analysis.dataset import AXES, GYRO, REF_RATE, Dataset
from bench.analysis.rate_transfer import (RATE_TOL_DPS, SETTLE_S, MIN_STEP_SAMPLES, check_options, find_steps, jfloat,
                                          opt_axes, opt_float, opt_int)
from bench.analysis.result import CalibrationResult, ResultTable
from bench.errors import InputError, Location

ORDER = 2
"""Both levels are second-order polynomials, ESTCube-2 Eq. 4.1: f(x) = p1·x² + p2·x + p3."""
TEMP_TOL_C = 1.0
"""Steps at one speed whose mean temperatures differ by less than this are one temperature level
(°C): twice ESTCube-2's 0.5 °C stabilisation criterion (Sec. 4.2.1); its levels were ~20 °C apart."""

FORM = ("correction(v, T) = p1(v)·T² + p2(v)·T + p3(v), p_i(v) = p_i1·v² + p_i2·v + p_i3 "
        "(ESTCube-2 Eq. 4.1, Table 4.1); v = speed (deg/s), T = temperature (°C), correction in deg/s")


def fit_quadratic(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least squares ``y = p1·x² + p2·x + p3`` (Eq. 4.1): coefficients [p1, p2, p3] (descending) and
    their standard errors (NaN with only 3 points)."""
    X = np.vander(x, ORDER + 1)  # columns x², x, 1
    p, *_ = np.linalg.lstsq(X, y, rcond=None)
    dof = x.size - (ORDER + 1)
    if dof > 0:
        resid = y - X @ p
        cov = float(resid @ resid) / dof * np.linalg.pinv(X.T @ X)
        se = np.sqrt(np.clip(np.diag(cov), 0, None))
    else:
        se = np.full(ORDER + 1, math.nan)
    return p, se


def fit_two_level(speed_dps: np.ndarray, temp_c: np.ndarray, value_dps: np.ndarray,
                  speed_tol_dps: float = RATE_TOL_DPS) -> dict[str, Any]:
    """The two-level fit of ``value`` (deg/s) at points (speed deg/s, temperature °C), one point per
    (speed, temperature level). Level 1 per speed: quadratic in T; level 2 per coefficient: quadratic
    in v. Raises ``ValueError`` with fewer than 3 speeds or fewer than 3 temperatures at a speed."""
    speed_dps, temp_c, value_dps = (np.asarray(a, dtype=float) for a in (speed_dps, temp_c, value_dps))
    order = np.argsort(speed_dps, kind="stable")
    groups: list[list[int]] = []
    for i in order.tolist():
        if groups and abs(speed_dps[i] - speed_dps[groups[-1][0]]) <= speed_tol_dps:
            groups[-1].append(i)
        else:
            groups.append([i])
    if len(groups) < ORDER + 1:
        raise ValueError(f"need steps at {ORDER + 1} or more speeds for the speed polynomial (Eq. 4.1), got {len(groups)}")
    levels = []
    for g in groups:
        idx = np.array(g)
        v = float(np.mean(speed_dps[idx]))
        if np.unique(np.round(temp_c[idx], 9)).size < ORDER + 1:
            raise ValueError(f"at {v:g} deg/s: need {ORDER + 1} or more temperature levels for the temperature "
                             f"polynomial (Eq. 4.1), got {np.unique(np.round(temp_c[idx], 9)).size}")
        p, se = fit_quadratic(temp_c[idx], value_dps[idx])
        levels.append({"speed_dps": v, "temp_poly": p, "temp_poly_se": se, "idx": idx})
    V = np.array([lv["speed_dps"] for lv in levels])
    P = np.array([lv["temp_poly"] for lv in levels])  # (speeds, 3)
    coef = np.zeros((ORDER + 1, ORDER + 1))
    coef_se = np.zeros((ORDER + 1, ORDER + 1))
    for i in range(ORDER + 1):
        coef[i], coef_se[i] = fit_quadratic(V, P[:, i])
    model = evaluate(coef, speed_dps, temp_c)
    resid = value_dps - model
    return {"coefficients": coef, "coefficients_se": coef_se, "levels": levels, "residuals": resid}


def evaluate(coefficients: np.ndarray | list[list[float]], speed_dps: np.ndarray | float,
             temp_c: np.ndarray | float) -> np.ndarray:
    """``Σ_i p_i(v)·T^(2−i)`` with ``p_i(v) = Σ_j coefficients[i][j]·v^(2−j)`` (Table 4.1 layout), deg/s."""
    C = np.asarray(coefficients, dtype=float)
    v = np.asarray(speed_dps, dtype=float)
    T = np.asarray(temp_c, dtype=float)
    d = C.shape[0] - 1
    return sum(np.polyval(C[i], v) * T ** (d - i) for i in range(d + 1))


_OPTIONS = {
    "axes": "axes to calibrate, e.g. 'z' (default: every axis with a gyro and a reference column at 3+ speeds)",
    "target": "'correction' (speed − output, added to the measurement; default) or 'offset' (output − speed)",
    "temp_tol_c": f"steps closer in temperature than this are one temperature level, °C (default {TEMP_TOL_C:g})",
    "rate_tol_dps": f"reference rates closer than this are one speed, deg/s (default {RATE_TOL_DPS})",
    "settle_s": f"time dropped at each end of a step, s (default {SETTLE_S})",
    "min_samples": f"fewest samples per step after the trim (default {MIN_STEP_SAMPLES})",
}


def _cluster_temps(steps: list[tuple[float, float, int]], tol: float) -> list[tuple[float, float, int]]:
    """Merge (temp, value, n) steps closer than ``tol`` °C in temperature: sample-weighted means."""
    out: list[list[tuple[float, float, int]]] = []
    for s in sorted(steps):
        if out and s[0] - out[-1][-1][0] < tol:
            out[-1].append(s)
        else:
            out.append([s])
    merged = []
    for grp in out:
        w = np.array([g[2] for g in grp], dtype=float)
        merged.append((float(np.average([g[0] for g in grp], weights=w)), float(np.average([g[1] for g in grp], weights=w)), len(grp)))
    return merged


def calibrate(ds: Dataset, **opts: Any) -> CalibrationResult:
    """Method ``two-level`` (ESTCube-2 Eq. 4.1, Table 4.1) on a Dataset of constant-speed steps at
    several temperatures. Options: ``axes``, ``target``, ``temp_tol_c`` (°C), ``rate_tol_dps``
    (deg/s), ``settle_s`` (s), ``min_samples``."""
    check_options("two-level", opts, _OPTIONS)
    target = str(opts.get("target", "correction")).strip().lower()
    if target not in ("correction", "offset"):
        raise InputError(f"expected 'correction' or 'offset', got {opts.get('target')!r}", None, "target")
    temp_tol = opt_float(opts, "temp_tol_c", TEMP_TOL_C, 0.0, 1e3)
    tol = opt_float(opts, "rate_tol_dps", RATE_TOL_DPS, 0.0, 1e3)
    settle = opt_float(opts, "settle_s", SETTLE_S, 0.0, 1e6)
    min_samples = opt_int(opts, "min_samples", MIN_STEP_SAMPLES, 1, 10**9)
    where = Location(ds.source)
    if "temp_c" not in ds:
        raise InputError("missing column: the two-level calibration needs the temperature (°C)", where, "temp_c")
    requested = opt_axes(opts)
    for a in requested or []:
        for col in (GYRO[a], REF_RATE[a]):
            if col not in ds:
                raise InputError(f"missing column for requested axis {a}", where, col)
    candidates = requested or [a for a in AXES if GYRO[a] in ds and REF_RATE[a] in ds]
    if not candidates:
        raise InputError("the two-level calibration needs a gyro column and its reference rate (e.g. gyro_z_dps and "
                         "ref_rate_z_dps)", where, "ref_rate_z_dps")
    steps = find_steps(ds, tol, settle, min_samples)
    notes: list[str] = []
    axes_json: dict[str, Any] = {}
    problems: list[str] = []
    for a in candidates:
        k = AXES.index(a)
        mine = [s for s in steps if s.driven_axis(tol) in (a, None) and s.mean_temp_c is not None and a in s.mean_output]
        by_speed: dict[float, list] = {}
        for s in sorted(mine, key=lambda s: s.rates[k]):
            key = next((v for v in by_speed if abs(v - s.rates[k]) <= tol), s.rates[k])
            by_speed.setdefault(key, []).append(s)
        pts_v, pts_T, pts_y, levels_pts = [], [], [], {}
        for v, ss in by_speed.items():
            sign = 1.0 if target == "correction" else -1.0
            merged = _cluster_temps([(s.mean_temp_c, sign * (s.rates[k] - s.mean_output[a]), s.n) for s in ss], temp_tol)
            levels_pts[v] = merged
            for T, val, _ in merged:
                pts_v.append(v), pts_T.append(T), pts_y.append(val)
        try:
            fit = fit_two_level(np.array(pts_v), np.array(pts_T), np.array(pts_y), tol)
        except ValueError as exc:
            if requested:
                raise InputError(f"axis {a}: {exc}", where, GYRO[a]) from None
            problems.append(f"axis {a}: {exc}")
            continue
        sign = 1.0 if target == "correction" else -1.0
        levels = []
        for lv in fit["levels"]:
            v = lv["speed_dps"]
            key = min(levels_pts, key=lambda q: abs(q - v))
            levels.append({"speed_dps": v, "temp_poly": lv["temp_poly"].tolist(),
                           "temp_poly_se": [jfloat(x) for x in lv["temp_poly_se"]],
                           "points": [{"temp_c": T, "mean_output_dps": v - sign * val, f"{target}_dps": val, "n_steps": n}
                                      for T, val, n in levels_pts[key]]})
        r = fit["residuals"]
        axes_json[a] = {
            "coefficients": fit["coefficients"].tolist(),
            "coefficients_se": [[jfloat(x) for x in row] for row in fit["coefficients_se"]],
            "levels": levels,
            "residual_rms_dps": float(np.sqrt(np.mean(r**2))),
            "residual_max_dps": float(np.max(np.abs(r))),
            "speed_range_dps": [float(min(pts_v)), float(max(pts_v))],
            "temp_range_c": [float(min(pts_T)), float(max(pts_T))],
        }
    if not axes_json:
        raise InputError("no axis can be calibrated: " + "; ".join(problems) + f" ({len(steps)} constant-rate step(s) found)", where)
    notes.extend(problems)
    js = {"form": FORM, "target": target, "axes": axes_json, "source": ds.source}
    return CalibrationResult("two-level", js, _tables(js), _calibration(js), notes)


def _tables(js: dict[str, Any]) -> list[ResultTable]:
    rows = []
    for a, r in js["axes"].items():
        for i in range(ORDER + 1):
            rows.append([a, f"p{i + 1}"] + [f"{r['coefficients'][i][j]:.4g}" for j in range(ORDER + 1)]
                        + ["—" if x is None else f"{x:.2g}" for x in r["coefficients_se"][i]])
    coefs = ResultTable(f"Two-level {js['target']} coefficients (ESTCube-2 Table 4.1 layout)",
                        ["axis", "coefficient", "p1-speed", "p2-speed", "p3-speed", "± p1-speed", "± p2-speed", "± p3-speed"], rows)
    lv_rows = []
    for a, r in js["axes"].items():
        for lv in r["levels"]:
            lv_rows.append([a, f"{lv['speed_dps']:g}"] + [f"{x:.4g}" for x in lv["temp_poly"]]
                           + [", ".join(f"{p['temp_c']:.1f}" for p in lv["points"])])
    levels = ResultTable("Temperature polynomial at each speed (Eq. 4.1: p1·T² + p2·T + p3)",
                         ["axis", "speed deg/s", "p1", "p2", "p3", "temperatures °C"], lv_rows)
    return [coefs, levels]


def _calibration(js: dict[str, Any]) -> dict[str, Any]:
    return {
        "method": "two-level",
        "model": js["form"] + ("" if js["target"] == "correction" else "; fitted quantity: offset = output − speed"),
        "target": js["target"],
        "axes": {a: {"coefficients": r["coefficients"], "standard_errors": r["coefficients_se"],
                     "speed_range_dps": r["speed_range_dps"], "temp_range_c": r["temp_range_c"]}
                 for a, r in js["axes"].items()},
        "units": {"coefficients": "row i, column j: deg/s / (degC^(2-i) · (deg/s)^(2-j))"},
    }
