"""Thermal-ramp bias calibration (method ``thermal``): the in-run bias of each gyro axis as a
polynomial in temperature, from a thermal ramp at zero rate (NPSAT1 thesis, sections IV-C and IV-D).

Input: a :class:`~bench.analysis.dataset.Dataset` with ``time_s``, ``temp_c`` (°C) and
``gyro_*_dps`` (deg/s). Rows used: those at zero rate (every ``ref_rate_*_dps`` present within
``rate_tol_dps`` of 0) and, when ``power_on_s`` is recorded, after the warm-up (``warmup_s``, NPSAT1
Sec. IV-A: "the datasets were restricted to t > 5 minutes").

Model (NPSAT1 Tables 3/4, 7/8: ``y = B + m1·T + m2·T² + m3·T³``), ascending powers:
``bias(T) = c0 + c1·T + c2·T² + … + c_d·T^d`` (deg/s, T in °C), ordinary least squares (on a
centred and scaled temperature for conditioning, mapped back to powers of T with the covariance).

Standard errors: the residuals of a ramp are autocorrelated (slow drift, run-to-run and warm-up
effects that the polynomial does not follow), so the i.i.d. least-squares covariance understates
the uncertainty. With the lag-1 autocorrelation ρ of the time-ordered residuals, the effective
sample size of an AR(1) error is n_eff = n·(1 − ρ)/(1 + ρ); the covariance is multiplied by
n/n_eff = (1 + ρ)/(1 − ρ) when ρ > 0 (for a slowly varying regressor such as a ramp temperature the
variance inflation of every regression coefficient tends to this factor). ``poly_se`` is the
inflated value, ``poly_se_iid`` the plain least-squares one (what the thesis' Origin reports give).

Hysteresis (NPSAT1 Sec. IV-C-2-a: "path misalignment of up to 0.004 °/sec"): the data are split into
heating and cooling paths at the temperature reversals (a reversal is a return of more than
``reversal_c`` from the running extreme), each path is fitted with the same polynomial and the
hysteresis is the largest |difference of the two fits| over their common temperature range
(``null`` without both paths or without a common range).

Start-temperature (run-to-run) offsets (NPSAT1 Sec. IV-C-2-b): when ``power_on_s`` falls back (a new
power-on), each run gets its own constant: ``offset_dps`` relative to the first run, fitted together
with one common polynomial.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from bench.analysis.dataset import AXES, GYRO, REF_RATE, Dataset, refuse_nothing_to_fit
from bench.analysis.rate_transfer import RATE_TOL_DPS, check_options, jfloat, opt_axes, opt_float, opt_int
from bench.analysis.result import CalibrationResult, ResultTable
from bench.errors import InputError, Location

DEGREE = 3
"""NPSAT1 Sec. IV-C: "the temperature dependence ... was determined by estimating the zero-rate bias
over the full qualification range ... using a 3rd-order polynomial" (Tables 3, 4, 7, 8)."""
WARMUP_S = 300.0
"""NPSAT1 Sec. IV-A: "the datasets were restricted to t > 5 minutes" after power-on (the warm-up)."""
REVERSAL_C = 1.0
"""A heating/cooling reversal needs a return of more than this from the extreme (°C): twice the
0.5 °C fluctuation below which ESTCube-2 counts a temperature as stable (Sec. 4.2.1)."""
HYSTERESIS_GRID = 201
"""Points of the common temperature range where the two path fits are compared (bench choice)."""
MAX_RHO = 0.99
"""Cap on the lag-1 autocorrelation used for the inflation, so that n_eff stays ≥ n/199 (bench choice)."""

_OPTIONS = {
    "degree": f"polynomial degree in temperature, 1-6 (default {DEGREE}, NPSAT1 Table 4)",
    "warmup_s": f"data before this time since power-on are dropped when power_on_s is recorded, s (default {WARMUP_S:g})",
    "rate_tol_dps": f"|reference rate| at or below this counts as zero rate, deg/s (default {RATE_TOL_DPS})",
    "reversal_c": f"temperature return that marks a heating/cooling reversal, °C (default {REVERSAL_C:g})",
    "axes": "gyro axes to calibrate, e.g. 'x,z' (default: every gyro column)",
}


# ---- polynomial fit with covariance ---------------------------------------------------------------
def poly_fit(T: np.ndarray, y: np.ndarray, degree: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares polynomial ``y = Σ c_k·T^k`` (ascending powers): (coefficients, i.i.d.
    covariance, residuals). Fitted in u = (T − T̄)/s for conditioning and mapped back exactly."""
    mu = float(np.mean(T))
    sc = float(np.std(T)) or 1.0
    u = (T - mu) / sc
    V = np.vander(u, degree + 1, increasing=True)
    a, *_ = np.linalg.lstsq(V, y, rcond=None)
    resid = y - V @ a
    dof = T.size - (degree + 1)
    s2 = float(resid @ resid) / dof if dof > 0 else math.nan
    cov_a = s2 * np.linalg.pinv(V.T @ V)
    # c = A a with u^j = Σ_k C(j,k) T^k (−μ)^(j−k) / s^j
    A = np.zeros((degree + 1, degree + 1))
    for j in range(degree + 1):
        for k in range(j + 1):
            A[k, j] = math.comb(j, k) * (-mu) ** (j - k) / sc**j
    return A @ a, A @ cov_a @ A.T, resid


def poly_eval(c: np.ndarray | list[float], T: np.ndarray | float) -> np.ndarray:
    """Σ c_k·T^k (ascending powers, T in °C)."""
    return np.polynomial.polynomial.polyval(T, np.asarray(c, dtype=float))


def lag1_autocorrelation(r: np.ndarray) -> float:
    """Lag-1 autocorrelation of a residual series (0 for fewer than 3 points)."""
    if r.size < 3:
        return 0.0
    r = r - r.mean()
    den = float(r @ r)
    return float(r[:-1] @ r[1:]) / den if den > 0 else 0.0


# ---- heating / cooling paths --------------------------------------------------------------------
def ramp_direction(T: np.ndarray, reversal_c: float = REVERSAL_C) -> np.ndarray:
    """+1 (heating) or −1 (cooling) for each sample of a time-ordered temperature (°C); 0 before the
    first move of more than ``reversal_c`` from the start. A path ends at its extreme once the
    temperature has come back by more than ``reversal_c``."""
    n = T.size
    d = np.zeros(n, dtype=int)
    if n == 0:
        return d
    start = 0
    direction = 0
    ext_i = 0
    for i in range(1, n):
        if direction == 0:
            if T[i] - T[start] > reversal_c:
                direction, ext_i = 1, int(np.argmax(T[start:i + 1])) + start
            elif T[start] - T[i] > reversal_c:
                direction, ext_i = -1, int(np.argmin(T[start:i + 1])) + start
            continue
        if direction * (T[i] - T[ext_i]) > 0:
            ext_i = i
        elif direction * (T[ext_i] - T[i]) > reversal_c:
            d[start:ext_i + 1] = direction
            start, direction = ext_i, -direction
            ext_i = i
    if direction:
        d[start:] = direction
    return d


def _hysteresis(T: np.ndarray, y: np.ndarray, direction: np.ndarray, degree: int) -> dict[str, Any]:
    out: dict[str, Any] = {"hysteresis_dps": None, "hysteresis_at_c": None, "hysteresis_range_c": None,
                           "heating_n": int(np.sum(direction > 0)), "cooling_n": int(np.sum(direction < 0))}
    fits = {}
    for name, sel in (("heating", direction > 0), ("cooling", direction < 0)):
        Ts = T[sel]
        if Ts.size < degree + 2 or np.unique(Ts).size < degree + 1:
            return out
        fits[name] = (poly_fit(Ts, y[sel], degree)[0], float(Ts.min()), float(Ts.max()))
    lo = max(fits["heating"][1], fits["cooling"][1])
    hi = min(fits["heating"][2], fits["cooling"][2])
    if not hi > lo:
        return out
    grid = np.linspace(lo, hi, HYSTERESIS_GRID)
    diff = poly_eval(fits["cooling"][0], grid) - poly_eval(fits["heating"][0], grid)
    k = int(np.argmax(np.abs(diff)))
    out.update(hysteresis_dps=float(abs(diff[k])), hysteresis_signed_dps=float(diff[k]), hysteresis_at_c=float(grid[k]),
               hysteresis_range_c=[lo, hi], heating_poly_degc=fits["heating"][0].tolist(),
               cooling_poly_degc=fits["cooling"][0].tolist())
    return out


def _run_offsets(T: np.ndarray, y: np.ndarray, run: np.ndarray, degree: int) -> list[dict[str, Any]] | None:
    """Common polynomial + one constant per run (first run = reference): offsets with standard errors."""
    ids = np.unique(run)
    if ids.size < 2:
        return None
    V = np.vander(T - T.mean(), degree + 1, increasing=True)
    D = np.column_stack([(run == r).astype(float) for r in ids[1:]])
    X = np.column_stack([V, D])
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    dof = y.size - X.shape[1]
    if dof <= 0:
        return None
    resid = y - X @ coef
    cov = float(resid @ resid) / dof * np.linalg.pinv(X.T @ X)
    out = []
    for k, r in enumerate(ids):
        sel = run == r
        off = 0.0 if k == 0 else float(coef[degree + k])
        se = 0.0 if k == 0 else math.sqrt(max(cov[degree + k, degree + k], 0.0))
        out.append({"run": int(k + 1), "start_temp_c": float(T[sel][0]), "n": int(sel.sum()),
                    "offset_dps": off, "offset_se_dps": se})
    return out


# ---- the method ---------------------------------------------------------------------------------
def calibrate(ds: Dataset, degree: int = DEGREE, **opts: Any) -> CalibrationResult:
    """Method ``thermal``: per gyro axis the bias polynomial in temperature from a zero-rate ramp.

    Options: ``degree`` (1-6), ``warmup_s`` (s), ``rate_tol_dps`` (deg/s), ``reversal_c`` (°C),
    ``axes``. Raises :class:`InputError` (naming the column) without ``temp_c`` or gyro columns, or
    with too few usable rows or too narrow a temperature range for the polynomial.
    """
    check_options("thermal", {"degree": degree, **opts}, _OPTIONS)
    degree = opt_int({"degree": degree}, "degree", DEGREE, 1, 6)
    warmup = opt_float(opts, "warmup_s", WARMUP_S, 0.0, 1e9)
    tol = opt_float(opts, "rate_tol_dps", RATE_TOL_DPS, 0.0, 1e6)
    reversal = opt_float(opts, "reversal_c", REVERSAL_C, 0.0, 1e3)
    where = Location(ds.source)
    if "temp_c" not in ds:
        raise InputError("missing column: the thermal calibration needs the sensor temperature (°C)", where, "temp_c")
    axes = opt_axes(opts) or ds.gyro_axes
    if not ds.gyro_axes:
        raise InputError("missing column: no gyro output (gyro_x_dps, gyro_y_dps, gyro_z_dps)", where, "gyro_x_dps")
    for a in axes:
        if GYRO[a] not in ds:
            raise InputError(f"missing column for requested axis {a}", where, GYRO[a])
    notes: list[str] = []
    t = ds["time_s"]
    T_all = ds["temp_c"]
    use = np.isfinite(T_all) & np.isfinite(t)
    refs = [a for a in AXES if REF_RATE[a] in ds]
    if refs:
        still = np.ones(len(ds), dtype=bool)
        for a in refs:
            r = ds[REF_RATE[a]]
            still &= np.isfinite(r) & (np.abs(r) <= tol)
        if not np.any(still & use):
            raise InputError(f"no rows at zero reference rate (|{', '.join(REF_RATE[a] for a in refs)}| ≤ {tol:g} deg/s); "
                             "the thermal calibration needs the sensor at rest", where, REF_RATE[refs[0]])
        if np.any(~still & use):
            notes.append(f"{int(np.sum(~still & use))} row(s) with a nonzero reference rate not used")
        use &= still
    run = np.zeros(len(ds), dtype=int)
    if "power_on_s" in ds:
        p = ds["power_on_s"]
        run = np.concatenate([[0], np.cumsum(np.diff(p) < 0)]) if p.size else run
        early = np.isfinite(p) & (p < warmup)
        if np.any(early & use):
            notes.append(f"{int(np.sum(early & use))} row(s) in the first {warmup:g} s after power-on dropped (warm-up, NPSAT1 Sec. IV-A)")
        use &= ~early
    selected: dict[str, np.ndarray] = {}
    for a in axes:
        sel = selected[a] = use & np.isfinite(ds[GYRO[a]])
        T = T_all[sel]
        if T.size < degree + 2:
            raise InputError(f"nothing to fit: axis {a}: {T.size} usable row(s); a degree-{degree} fit needs at least "
                             f"{degree + 2}", where, GYRO[a])
        if np.unique(T).size < degree + 1 or float(np.ptp(T)) <= 0:
            raise InputError(f"axis {a}: the temperature does not vary enough for a degree-{degree} polynomial "
                             f"({np.unique(T).size} distinct value(s) from {T.min():g} to {T.max():g} °C)", where, "temp_c")
    refuse_nothing_to_fit(ds.select(use), [GYRO[a] for a in axes],
                          "the thermal calibration needs a gyro output that changes with temperature")
    axes_json: dict[str, Any] = {}
    for a in axes:
        sel = selected[a]
        T, y = T_all[sel], ds[GYRO[a]][sel]
        c, cov, resid = poly_fit(T, y, degree)
        rho = lag1_autocorrelation(resid)
        rho_used = min(max(rho, 0.0), MAX_RHO)
        inflation = (1 + rho_used) / (1 - rho_used)
        se_iid = np.sqrt(np.clip(np.diag(cov), 0, None))
        entry: dict[str, Any] = {
            "poly_degc": c.tolist(),
            "poly_se": (se_iid * math.sqrt(inflation)).tolist(),
            "poly_se_iid": se_iid.tolist(),
            "residual_rms_dps": float(np.sqrt(np.mean(resid**2))),
            "residual_max_dps": float(np.max(np.abs(resid))),
            "residual_lag1_autocorr": rho,
            "n_eff": float(T.size / inflation),
            "temp_range_c": [float(T.min()), float(T.max())],
            "n": int(T.size),
        }
        entry.update(_hysteresis(T, y, ramp_direction(T, reversal), degree))
        offsets = _run_offsets(T, y, run[sel], degree)
        if offsets is not None:
            entry["runs"] = offsets
        entry = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in entry.items()}
        entry["poly_se"] = [jfloat(v) for v in entry["poly_se"]]
        entry["poly_se_iid"] = [jfloat(v) for v in entry["poly_se_iid"]]
        axes_json[a] = entry
        if rho > 0.5:
            notes.append(f"axis {a}: residuals strongly autocorrelated (ρ = {rho:.2f}); standard errors inflated "
                         f"×{math.sqrt(inflation):.1f} (n_eff = {T.size / inflation:.0f} of {T.size})")
    js = {"degree": degree, "model": "bias_dps = sum(c[k] * temp_c**k)", "axes": axes_json, "source": ds.source}
    return CalibrationResult("thermal", js, _tables(js), _calibration(js), notes)


def _units(k: int) -> str:
    return "deg/s" if k == 0 else "deg/s/degC" if k == 1 else f"deg/s/degC^{k}"


def _tables(js: dict[str, Any]) -> list[ResultTable]:
    d = js["degree"]
    coef_rows = []
    for a, r in js["axes"].items():
        for k in range(d + 1):
            se = r["poly_se"][k]
            coef_rows.append([a, f"c{k}", f"{r['poly_degc'][k]:.6g}", "—" if se is None else f"{se:.3g}",
                              "—" if r["poly_se_iid"][k] is None else f"{r['poly_se_iid'][k]:.3g}", _units(k)])
    coefs = ResultTable("Thermal bias polynomial bias(T) = c0 + c1·T + … (NPSAT1 Table 4 form, T in °C)",
                        ["axis", "coefficient", "value", "std error", "std error (i.i.d.)", "units"], coef_rows)
    fit_rows = []
    for a, r in js["axes"].items():
        h = r.get("hysteresis_dps")
        fit_rows.append([a, str(r["n"]), f"{r['temp_range_c'][0]:.1f} … {r['temp_range_c'][1]:.1f}",
                         f"{r['residual_rms_dps']:.5f}", f"{r['residual_max_dps']:.5f}", f"{r['residual_lag1_autocorr']:.2f}",
                         "—" if h is None else f"{h:.5f}"])
    fit = ResultTable("Fit quality and heating/cooling hysteresis",
                      ["axis", "rows", "temperature °C", "residual RMS deg/s", "residual max deg/s", "lag-1 ρ",
                       "hysteresis deg/s"], fit_rows)
    tables = [coefs, fit]
    runs = [[a, str(x["run"]), f"{x['start_temp_c']:.1f}", f"{x['offset_dps']:.5f}", f"{x['offset_se_dps']:.5f}", str(x["n"])]
            for a, r in js["axes"].items() for x in r.get("runs", [])]
    if runs:
        tables.append(ResultTable("Run-to-run offsets by start temperature (NPSAT1 Sec. IV-C-2-b)",
                                  ["axis", "run", "start °C", "offset deg/s", "± deg/s", "rows"], runs))
    return tables


def _calibration(js: dict[str, Any]) -> dict[str, Any]:
    d = js["degree"]
    return {
        "method": "thermal",
        "model": "bias_dps = c[0] + c[1]*T + c[2]*T^2 + ... (T = temp_c in degC; NPSAT1 b_in-run, Table 4 form)",
        "axes": {a: {"coefficients": r["poly_degc"], "standard_errors": r["poly_se"],
                     "units": [_units(k) for k in range(d + 1)], "temp_range_c": r["temp_range_c"]}
                 for a, r in js["axes"].items()},
    }
