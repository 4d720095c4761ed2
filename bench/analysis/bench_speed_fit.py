"""Fit the stepper bench's speed calibration from rotation timings (ESTCube-2 thesis 3.2.1-3.2.2).

Model (Eq. 3.1/3.8): t/2π = n/k + b, i.e. n = k·(1/v − b), 1/v in s/rad. Linear least squares of
t/2π on n over every timing row (with equal repeats per n this equals the thesis fit of the means).
Uncertainties follow section 3.2.2:

* u_A (s): mean over n of the standard deviation of the timings at that n (population standard
  deviation, as the thesis: it reproduces u_A = 0.153 s from Table 3.1);
* u_B (s): stopwatch resolution Δ/√3 (Δ = 0.01 s in the thesis);
* u_C = √(u_A² + u_B²);
* u_speed (deg/s) = |d(360°/t)/dt|·u_C at the shortest rotation time (largest speed), Eq. 3.5;
* u_n = |dn/dt|·u_C = k/(2π)·u_C, Eq. 3.7;
* extended uncertainties with the Student-t factor for 95.45 % and (repeats − 1) degrees of
  freedom (2.869 for 5 repeats, Eq. 3.6/3.9).

``u_k`` and ``u_b`` are the standard errors of the least-squares fit (k = 1/slope, propagated).

On stock GRBL (docs/stepper-bench.md) the rate is linear in the feed with no offset: GRBL sends
``feed·$100`` steps per minute, so a table of S true steps per degree turns at v_cmd·$100/S and
one rotation takes t = 360·S/($100·v_cmd). :func:`fit_grbl_steps` fits the ratio c = S/$100 by
least squares through the origin of t on 360/v_cmd and gives the corrected ``$100`` = c·$100 with
the thesis's uncertainty terms (u_A, u_B, u_C per timing; Student t for 95.45 %). Its standard
uncertainty is the larger of the timing one (u_C/√Σx²) and the scatter of the fit's residuals.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy import stats

from bench.csvsrc import read_csv_table, read_numeric_csv
from bench.errors import InputError, Location

COVERAGE = 0.9545  # "confidence interval of 95.45%" (ESTCube-2 Eq. 3.6)


@dataclass
class BenchSpeedFit:
    k: float
    b_s_per_rad: float
    u_k: float
    u_b: float
    u_a_s: float
    u_b_stopwatch_s: float
    u_c_s: float
    u_speed_dps: float
    u_n: float
    coverage_factor: float
    u_speed_extended_dps: float
    u_n_extended: float
    rows: int
    levels: list[dict]

    def as_json(self) -> dict:
        return asdict(self)


def _levels(key: str, x: np.ndarray, t: np.ndarray, speed_key: str) -> tuple[list[dict], float, list[int]]:
    """Per level of ``x`` (``key``): repeats, mean and (population) standard deviation of the
    rotation times ``t`` (s) and the speed they give (deg/s, ``speed_key``); u_A, the mean of
    the standard deviations (NaN without repeats, Eq. 3.2); the repeats per level."""
    out, stds, repeats = [], [], []
    for lv in np.unique(x):
        tt = t[x == lv]
        stds.append(float(np.std(tt)) if tt.size > 1 else float("nan"))
        repeats.append(int(tt.size))
        out.append({key: float(lv), "repeats": int(tt.size), "mean_time_s": float(tt.mean()),
                    "std_time_s": stds[-1], speed_key: 360.0 / float(tt.mean())})
    valid = [sd for sd in stds if not math.isnan(sd)]
    return out, (float(np.mean(valid)) if valid else float("nan")), repeats


def fit_bench_speed(n: np.ndarray, rotation_time_s: np.ndarray, resolution_s: float = 0.01) -> BenchSpeedFit:
    """Fit k and b from timings; ``resolution_s`` is the stopwatch resolution Δ (s).

    Raises ``ValueError`` when fewer than two distinct n have timings or times are not positive.
    """
    n = np.asarray(n, dtype=float)
    t = np.asarray(rotation_time_s, dtype=float)
    if np.any(t <= 0):
        raise ValueError("rotation times must be > 0 s")
    levels = np.unique(n)
    if levels.size < 2:
        raise ValueError(f"need timings at two or more values of n, got {levels.size}")
    y = t / (2 * math.pi)  # 1/v in s/rad
    X = np.column_stack([n, np.ones_like(n)])
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    slope, intercept = float(coef[0]), float(coef[1])
    if slope <= 0:
        raise ValueError("rotation time does not grow with n: not a stepper bench speed relation")
    dof = n.size - 2
    if dof > 0:
        resid = y - X @ coef
        s2 = float(resid @ resid) / dof
        cov = s2 * np.linalg.inv(X.T @ X)
        u_slope, u_intercept = math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1])
    else:
        u_slope = u_intercept = float("nan")
    k = 1.0 / slope
    per_level, u_a, repeats = _levels("n", n, t, "speed_dps")
    valid = not math.isnan(u_a)
    u_b_sw = resolution_s / math.sqrt(3)
    u_c = math.sqrt(u_a**2 + u_b_sw**2) if valid else u_b_sw
    t_min = float(min(p["mean_time_s"] for p in per_level))
    u_speed = 360.0 / t_min**2 * u_c
    u_n = k / (2 * math.pi) * u_c
    dof_rep = min(repeats) - 1
    kf = float(stats.t.ppf(0.5 + COVERAGE / 2, dof_rep)) if dof_rep > 0 else float("nan")
    return BenchSpeedFit(
        k=k, b_s_per_rad=intercept, u_k=u_slope / slope**2, u_b=u_intercept, u_a_s=u_a, u_b_stopwatch_s=u_b_sw,
        u_c_s=u_c, u_speed_dps=u_speed, u_n=u_n, coverage_factor=kf, u_speed_extended_dps=kf * u_speed,
        u_n_extended=kf * u_n, rows=int(n.size), levels=per_level,
    )


@dataclass
class GrblStepsFit:
    """Steps per table degree from timed rotations on GRBL (see the module docstring)."""

    axis: str
    set_steps_per_deg: float
    """The ``$100`` (``$101``, ``$102``) the bench ran with while timed."""
    steps_per_deg: float
    u_steps_per_deg: float
    ratio: float
    """c = true / set steps per degree: the table turns at the commanded rate / c."""
    u_ratio: float
    u_a_s: float
    u_b_stopwatch_s: float
    u_c_s: float
    coverage_factor: float
    u_steps_extended: float
    rate_error: float
    """How much faster (+) or slower (-) than commanded the table turned: 1/c - 1."""
    largest_residual_s: float
    rows: int
    levels: list[dict]
    command: str
    """The line that sets it: ``$100=894.330``."""

    def as_json(self) -> dict:
        return asdict(self)


def fit_grbl_steps(rate_dps: np.ndarray, rotation_time_s: np.ndarray, set_steps_per_deg: float,
                   resolution_s: float = 0.01, axis: str = "X") -> GrblStepsFit:
    """Corrected steps per degree from rotation times ``rotation_time_s`` (s) at commanded rates
    ``rate_dps`` (deg/s; the sign is ignored) on a GRBL set to ``set_steps_per_deg``. ValueError
    for rates or times that are not positive, or a fit without a degree of freedom."""
    v = np.abs(np.asarray(rate_dps, dtype=float))
    t = np.asarray(rotation_time_s, dtype=float)
    if np.any(t <= 0) or np.any(v <= 0):
        raise ValueError("rates and rotation times must be > 0")
    if not (math.isfinite(set_steps_per_deg) and set_steps_per_deg > 0):
        raise ValueError(f"the steps per degree GRBL ran with must be > 0, got {set_steps_per_deg!r}")
    if t.size < 2:
        raise ValueError("need two or more timings")
    x = 360.0 / v  # the rotation time if the table turned as commanded (s)
    sxx = float(x @ x)
    c = float(x @ t) / sxx
    resid = t - c * x
    levels, u_a, repeats = _levels("rate_dps", v, t, "true_rate_dps")
    u_a = 0.0 if math.isnan(u_a) else u_a
    u_b_sw = resolution_s / math.sqrt(3)
    u_c = math.sqrt(u_a**2 + u_b_sw**2)
    u_timing = u_c / math.sqrt(sxx)
    u_scatter = math.sqrt(float(resid @ resid) / (t.size - 1) / sxx)
    u_ratio = max(u_timing, u_scatter)
    dof = min(repeats) - 1 if min(repeats) > 1 else t.size - 1
    kf = float(stats.t.ppf(0.5 + COVERAGE / 2, dof))
    steps = c * set_steps_per_deg
    n = {"X": 100, "Y": 101, "Z": 102}[axis]
    return GrblStepsFit(axis, float(set_steps_per_deg), steps, u_ratio * set_steps_per_deg, c, u_ratio, u_a, u_b_sw, u_c, kf,
                        kf * u_ratio * set_steps_per_deg, 1.0 / c - 1.0, float(np.max(np.abs(resid))), int(t.size), levels,
                        f"${n}={steps:.3f}")


def fit_timings_file(path: str | Path, resolution_s: float = 0.01, steps_per_deg: float | None = None,
                     axis: str = "X") -> BenchSpeedFit | GrblStepsFit:
    """Read a timings CSV and fit it: columns ``n``, ``rotation_time_s`` (the thesis firmware:
    :func:`fit_bench_speed`) or ``rate_dps``, ``rotation_time_s`` (stock GRBL, needs
    ``steps_per_deg``, the ``$100`` it ran with: :func:`fit_grbl_steps`); repeated rows per level."""
    if "rate_dps" in read_csv_table(path).header:
        if steps_per_deg is None:
            raise InputError("rate_dps timings are GRBL's: give the steps per degree GRBL ran with (--steps-per-deg, its $100)",
                             Location(path), "--steps-per-deg")
        values, lines = read_numeric_csv(path, ["rate_dps", "rotation_time_s"])
        for col in ("rate_dps", "rotation_time_s"):
            bad = np.flatnonzero(np.abs(values[col]) <= 0) if col == "rate_dps" else np.flatnonzero(values[col] <= 0)
            if bad.size:
                raise InputError(f"{col} must be {'non-zero' if col == 'rate_dps' else '> 0 s'}", Location(path, int(lines[bad[0]])), col)
        try:
            return fit_grbl_steps(values["rate_dps"], values["rotation_time_s"], steps_per_deg, resolution_s, axis)
        except ValueError as exc:
            raise InputError(str(exc), Location(path)) from None
    values, lines = read_numeric_csv(path, ["n", "rotation_time_s"])
    bad = np.flatnonzero(values["rotation_time_s"] <= 0)
    if bad.size:
        raise InputError("rotation time must be > 0 s", Location(path, int(lines[bad[0]])), "rotation_time_s")
    try:
        return fit_bench_speed(values["n"], values["rotation_time_s"], resolution_s)
    except ValueError as exc:
        raise InputError(str(exc), Location(path)) from None
