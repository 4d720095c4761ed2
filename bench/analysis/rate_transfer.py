"""Rate-transfer calibration (method ``rate-transfer``): scale-factor error, fixed bias, misalignment
and output error per rate from constant-rate steps on a rate table (NPSAT1 thesis, section IV-E).

Two inputs:

* a :class:`~bench.analysis.dataset.Dataset` (measured-data CSV or run file) with ``ref_rate_*_dps``
  and ``gyro_*_dps``: :func:`find_steps` cuts it into segments of constant reference rate, drops
  the settling transient at each end and averages the outputs per step; or
* a summary CSV (:func:`calibrate_summary_csv`) with one row per step: ``axis`` (x/y/z, the sensor
  under test), ``rate_dps`` (table rate, deg/s) and ``mean_output_dps`` (that sensor's mean output,
  deg/s); rows with ``rate_dps`` 0 are zero-rate references. Optional: ``std_output_dps`` and ``n``
  (the step's sample scatter and count) and ``u_mean_dps`` (other standard uncertainty of the mean,
  e.g. a transcribed table's rounding). Extra columns are ignored.

Per sensor axis i (NPSAT1 Eq. 17, ``output = bias + S̃f·input``), over the steps driven about axis i
plus the zero-rate steps: ``scale_factor_error = S̃f − 1`` (fraction) and ``bias_dps`` (the fixed bias
b_cons) with their least-squares standard errors. The cross-axis slopes give the misalignment matrix
``M[i][j] = d(output_i)/d(rate_j)`` (``M[i][i] = S̃f − 1``; NPSAT1 Eq. 2/3), ``null`` where the data
have no steps about axis j or no output i.

Percent error per step (NPSAT1 Tables 9-11): "no ref" is ``100·(m − r)/r`` with the step's mean
output m and table rate r; "minus ref" first subtracts the zero-rate reference recorded before and
after the test cycle (mean of the nearest zero-rate steps before and after the step, or the one
available; ``null`` without any). NB the thesis prints these tables (and the diagonal of its M) with
the opposite sign, ``100·(r − m)/r``: see docs/calibration.md.

Residuals (:func:`axis_residuals`): each step's mean output minus its axis' line, tested against the
line refitted without the step's rate (externally studentised, so an outlier cannot hide itself),
with a variance from the step's own noise and the scatter of the other rates; a step is ``off`` when
its p-value is below 1 %/n (Bonferroni over the axis' n points), and points found off are left out
of the reference for the rest until nothing new turns up. ``common_mode`` (:func:`common_mode`)
lists the rates off on every axis measured at them (a reference or table effect, not a sensor one).

Resolution at the ±5 % requirement: the rate below which the fixed bias alone breaks the
requirement, ``|bias| / 0.05`` (NPSAT1 Sec. IV-E-2: biases of 0.024, 0.017, 0.019 °/s give 0.48,
0.34, 0.38 °/s); also reported, the observed resolution: the smallest tested |rate| at and above
which every step meets ±5 % (with and without the reference).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from bench.analysis.dataset import AXES, GYRO, REF_RATE, Dataset
from bench.analysis.result import CalibrationResult, ResultTable
from bench.csvsrc import read_csv_table
from bench.errors import InputError, Location, finite_number

REQUIREMENT_FRACTION = 0.05
"""NPSAT1 Sec. I-C-1-a: "The MEMS is required to be able to provide an accuracy of within ±5 % of the
actual rate"."""
SETTLE_S = 2.0
"""Time dropped at the start and at the end of each step (s). NPSAT1 Sec. IV-E-2 drops "the first and
last data points of each step"; its ACS saves one averaged point every 2 s (Sec. III-D, IV-G-1)."""
RATE_TOL_DPS = 1e-4
"""Two reference rates closer than this are the same step (deg/s): a tenth of the finest spacing of
the NPSAT1 test rates (0.009 vs 0.008 °/s, Table 9)."""
MIN_STEP_SAMPLES = 3
"""Fewest samples left in a step after the settling trim for it to count (bench choice: a mean and
a standard deviation need a few)."""


# ---- options shared by the calibration methods ---------------------------------------------------
def check_options(method: str, opts: dict[str, Any], accepted: dict[str, str]) -> None:
    """:class:`InputError` for an option the method does not know (``accepted``: name → help)."""
    for key in opts:
        if key not in accepted:
            raise InputError(f"unknown option for method {method!r} (accepted: "
                             f"{', '.join(f'{k} ({v})' for k, v in accepted.items()) or 'none'})", None, key)


def opt_float(opts: dict[str, Any], name: str, default: float, lo: float = -math.inf, hi: float = math.inf) -> float:
    """Option ``name`` as a finite float in [lo, hi] (strings from the command line are converted)."""
    v = opts.get(name, default)
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise InputError(f"expected a number, got {v!r}", None, name) from None
    if not math.isfinite(x) or not lo <= x <= hi:
        raise InputError(f"must be a finite number in [{lo:g}, {hi:g}], got {v!r}", None, name)
    return x


def opt_int(opts: dict[str, Any], name: str, default: int, lo: int, hi: int) -> int:
    """Option ``name`` as an integer in [lo, hi] (strings from the command line are converted)."""
    v = opts.get(name, default)
    x: int | None = None
    if isinstance(v, int) and not isinstance(v, bool):
        x = v
    elif isinstance(v, float) and v.is_integer():
        x = int(v)
    elif isinstance(v, str):
        try:
            x = int(v.strip())
        except ValueError:
            x = None
    if x is None:
        raise InputError(f"expected an integer, got {v!r}", None, name)
    if not lo <= x <= hi:
        raise InputError(f"must be between {lo} and {hi}, got {v!r}", None, name)
    return x


def opt_axes(opts: dict[str, Any], name: str = "axes") -> list[str] | None:
    """Option ``axes`` ("z", "x,y", ["x", "z"]) as a list of axis letters, or None when not given."""
    v = opts.get(name)
    if v is None:
        return None
    items = v.replace(",", " ").split() if isinstance(v, str) else list(v) if isinstance(v, (list, tuple)) else None
    if not items or any(not isinstance(a, str) or a.strip().lower() not in AXES for a in items):
        raise InputError(f"expected axis letters x, y, z (e.g. 'x,z'), got {v!r}", None, name)
    return [a.strip().lower() for a in items]


def jfloat(x: float | None) -> float | None:
    """A float for JSON: ``None`` for NaN/inf/None (JSON has no NaN)."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def linear_fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float, float]:
    """Ordinary least squares ``y = intercept + slope·x`` (NPSAT1 Eq. 17): (slope, intercept,
    se_slope, se_intercept); standard errors are NaN with fewer than 3 points (no residual dof)."""
    X = np.column_stack([x, np.ones_like(x)])
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    dof = x.size - 2
    if dof > 0:
        resid = y - X @ coef
        cov = float(resid @ resid) / dof * np.linalg.inv(X.T @ X)
        se = np.sqrt(np.clip(np.diag(cov), 0, None))
    else:
        se = np.array([math.nan, math.nan])
    return float(coef[0]), float(coef[1]), float(se[0]), float(se[1])


# ---- steps ---------------------------------------------------------------------------------------
@dataclass
class Step:
    """One constant-rate step: reference ``rates`` (deg/s about x, y, z; 0 for an axis without a
    reference column), mean and standard deviation of each gyro output (deg/s), mean ``temp_c``
    (°C, when recorded), sample count, time span (s) and ``order`` (position in time / file)."""

    order: int
    rates: tuple[float, float, float]
    mean_output: dict[str, float]
    std_output: dict[str, float] = field(default_factory=dict)
    n: int = 1
    t_start_s: float | None = None
    t_end_s: float | None = None
    mean_temp_c: float | None = None
    line: int | None = None
    n_eff: dict[str, float] = field(default_factory=dict)
    """Effective number of independent samples per output (AR(1): ``n·(1−ρ)/(1+ρ)``), for the
    uncertainty of the step mean, ``std/√n_eff``."""
    u_mean: dict[str, float] = field(default_factory=dict)
    """Other known standard uncertainty of the mean output (deg/s; e.g. a transcribed table's
    rounding), added in quadrature to ``std/√n_eff``."""

    def driven_axis(self, tol: float = RATE_TOL_DPS) -> str | None:
        """'x'/'y'/'z' when only that axis turns, None at zero rate, 'mixed' otherwise."""
        on = [a for a, r in zip(AXES, self.rates) if abs(r) > tol]
        return None if not on else on[0] if len(on) == 1 else "mixed"


def find_steps(ds: Dataset, rate_tol_dps: float = RATE_TOL_DPS, settle_s: float = SETTLE_S,
               min_samples: int = MIN_STEP_SAMPLES) -> list[Step]:
    """Cut ``ds`` into segments of constant reference rate (every ``ref_rate_*_dps`` within
    ``rate_tol_dps`` deg/s of the segment's first sample), drop ``settle_s`` s at both ends of each
    and average the gyro outputs (deg/s) and ``temp_c`` (°C) over the rest. Segments with fewer than
    ``min_samples`` samples left (e.g. the table's acceleration ramps) are skipped.

    Raises :class:`InputError` when the data have no reference-rate column.
    """
    present = [a for a in AXES if REF_RATE[a] in ds]
    if not present:
        raise InputError("the rate-transfer analysis needs the reference rate (columns ref_rate_x_dps, "
                         "ref_rate_y_dps, ref_rate_z_dps; or use a summary CSV with axis, rate_dps, mean_output_dps)",
                         Location(ds.source), "ref_rate_z_dps")
    t = ds["time_s"]
    n = t.size
    R = np.zeros((n, 3))
    for k, a in enumerate(AXES):
        if REF_RATE[a] in ds:
            R[:, k] = ds[REF_RATE[a]]
    gyro_axes = ds.gyro_axes
    ok = np.all(np.isfinite(R), axis=1) & np.isfinite(t)
    for a in gyro_axes:
        ok &= np.isfinite(ds[GYRO[a]])
    # candidate runs: consecutive samples with small rate changes and finite values
    brk = np.ones(n, dtype=bool)
    if n > 1:
        brk[1:] = (np.max(np.abs(np.diff(R, axis=0)), axis=1) > rate_tol_dps) | ~ok[1:] | ~ok[:-1]
    starts = np.flatnonzero(brk)
    ends = np.append(starts[1:], n)
    segments: list[tuple[int, int]] = []
    for s, e in zip(starts.tolist(), ends.tolist()):
        if not ok[s]:
            continue
        span = np.max(np.ptp(R[s:e], axis=0)) if e - s > 1 else 0.0
        if span <= rate_tol_dps:
            segments.append((s, e))
            continue
        # a slow ramp: split where the rate leaves the tolerance band around the segment start
        i0 = s
        for i in range(s + 1, e):
            if np.max(np.abs(R[i] - R[i0])) > rate_tol_dps:
                segments.append((i0, i))
                i0 = i
        segments.append((i0, e))
    steps: list[Step] = []
    temp = ds["temp_c"] if "temp_c" in ds else None
    for s, e in segments:
        keep = np.arange(s, e)
        keep = keep[(t[keep] >= t[s] + settle_s) & (t[keep] <= t[e - 1] - settle_s)]
        if keep.size < min_samples:
            continue
        rates = tuple(float(np.mean(R[keep, k])) for k in range(3))
        mean = {a: float(np.mean(ds[GYRO[a]][keep])) for a in gyro_axes}
        std = {a: float(np.std(ds[GYRO[a]][keep], ddof=1)) for a in gyro_axes}
        n_eff = {a: _n_eff(ds[GYRO[a]][keep]) for a in gyro_axes}
        tc = None
        if temp is not None:
            tt = temp[keep]
            tt = tt[np.isfinite(tt)]
            tc = float(np.mean(tt)) if tt.size else None
        line = int(ds.line_numbers[keep[0]]) if ds.line_numbers is not None else None
        steps.append(Step(len(steps), rates, mean, std, int(keep.size), float(t[keep[0]]), float(t[keep[-1]]), tc, line,
                          n_eff))
    return steps


def _n_eff(v: np.ndarray) -> float:
    """Effective sample size of ``v`` for its mean: ``n·(1−ρ)/(1+ρ)`` with the lag-1 autocorrelation
    ρ clipped to [0, 0.99] (AR(1), as in ``thermal_cal``); ``n`` itself below 3 samples."""
    n = v.size
    if n < 3:
        return float(n)
    d = v - v.mean()
    den = float(d @ d)
    rho = float(d[1:] @ d[:-1]) / den if den > 0 else 0.0
    rho = min(max(rho, 0.0), 0.99)
    return max(1.0, n * (1 - rho) / (1 + rho))


effective_samples = _n_eff
"""The public name of :func:`_n_eff` (the six-position calibration uses it too)."""


# ---- summary CSV ---------------------------------------------------------------------------------
SUMMARY_COLUMNS = ("axis", "rate_dps", "mean_output_dps")
SCATTER_COLUMNS = ("std_output_dps", "n")
"""Optional summary-CSV columns: the standard deviation of the samples in the step (deg/s) and their
number; with both, the step mean's own uncertainty ``std/√n`` enters its residual's σ."""
U_MEAN_COLUMN = "u_mean_dps"
"""Optional summary-CSV column: any other standard uncertainty of ``mean_output_dps`` (deg/s), e.g. the
rounding of a transcribed table (a value printed to a step q has q/√12)."""


def is_summary_csv(path: str | Path) -> bool:
    """True when ``path`` is a CSV whose header (first non-comment line) has an ``axis`` column.
    Never raises: an unreadable file gives False (the data loader then reports the problem)."""
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as fh:
            for line in fh:
                s = line.strip()
                if not s or s.startswith("#"):
                    continue
                return "axis" in [h.strip() for h in s.split(",")]
    except OSError:
        return False
    return False


def read_summary_csv(path: str | Path) -> list[Step]:
    """The rows of a summary CSV as :class:`Step` s (one axis driven, one output each).

    :class:`InputError` with file:line and column for a missing column, a row with the wrong number
    of cells, an axis other than x/y/z, or a rate/output that is not a finite number.
    """
    table = read_csv_table(path)
    for name in SUMMARY_COLUMNS:
        if name not in table.header:
            raise InputError(f"missing column (a summary CSV has {', '.join(SUMMARY_COLUMNS)}; header has: "
                             f"{', '.join(table.header) or 'nothing'})", Location(table.path, table.header_line), name)
    idx = {name: table.header.index(name) for name in SUMMARY_COLUMNS}
    if not table.rows:
        raise InputError("no data rows after the header", Location(table.path, table.header_line))
    steps: list[Step] = []
    for row, ln in zip(table.rows, table.lines):
        where = Location(table.path, ln)
        if len(row) != len(table.header):
            raise InputError(f"expected {len(table.header)} values like the header, got {len(row)}", where)
        axis = row[idx["axis"]].strip().lower()
        if axis not in AXES:
            raise InputError(f"expected x, y or z, got {row[idx['axis']].strip()!r}", where, "axis")
        nums = {}
        for name in ("rate_dps", "mean_output_dps"):
            nums[name] = finite_number(row[idx[name]].strip(), where, name)
        rates = tuple(nums["rate_dps"] if a == axis else 0.0 for a in AXES)
        step = Step(len(steps), rates, {axis: nums["mean_output_dps"]}, line=ln)
        if all(name in table.header for name in SCATTER_COLUMNS):
            std_cell = row[table.header.index("std_output_dps")].strip()
            n_cell = row[table.header.index("n")].strip()
            if std_cell or n_cell:  # both empty: this step's scatter is unknown
                try:
                    std = float(std_cell)
                except ValueError:
                    raise InputError(f"expected a number (or both std_output_dps and n empty), got {std_cell!r}",
                                     where, "std_output_dps") from None
                if not math.isfinite(std) or std < 0:
                    raise InputError(f"expected a finite number >= 0, got {std_cell!r}", where, "std_output_dps")
                try:
                    count = float(n_cell)
                except ValueError:
                    count = math.nan
                if not (count.is_integer() and count >= 2):
                    raise InputError(f"expected a sample count >= 2 (or both std_output_dps and n empty), got {n_cell!r}",
                                     where, "n")
                step.std_output, step.n, step.n_eff = {axis: std}, int(count), {axis: count}
        if U_MEAN_COLUMN in table.header:
            cell = row[table.header.index(U_MEAN_COLUMN)].strip()
            if cell:
                try:
                    v = float(cell)
                except ValueError:
                    v = math.nan
                if not math.isfinite(v) or v < 0:
                    raise InputError(f"expected a finite number >= 0 (or empty), got {cell!r}", where, U_MEAN_COLUMN)
                step.u_mean = {axis: v}
        steps.append(step)
    return steps


# ---- residuals against the fit -------------------------------------------------------------------
ALPHA = 0.01
"""Family-wise false-alarm probability of the off-the-line flags (bench choice, 1 %): per axis over
its points (a point is off when its two-sided p-value is below ``ALPHA / n_points``; per rate,
``ALPHA / n_rates``), and for the common-mode test over the rates measured on two or more axes."""
MAX_PASSES = 20
"""Most passes of the exclude-and-retest loop in :func:`axis_residuals` (it stops when nothing new is
found; each pass can only add points, so a handful suffice)."""


def _groups(x: np.ndarray, tol: float) -> list[np.ndarray]:
    """Indices of ``x`` grouped by value: sorted, a new group where the gap to the group's first
    value exceeds ``tol``."""
    order = np.argsort(x, kind="stable")
    out: list[list[int]] = []
    for i in order.tolist():
        if out and x[i] - x[out[-1][0]] <= tol:
            out[-1].append(i)
        else:
            out.append([i])
    return [np.array(g, dtype=int) for g in out]


def _satterthwaite(comps: np.ndarray, dofs: np.ndarray) -> float:
    """Welch-Satterthwaite degrees of freedom of ``sum(comps)`` (inf when every part is exact)."""
    total = float(np.sum(comps))
    if not 0 < total < math.inf:
        return math.inf
    w = comps / total  # scale-free: (Σc)² / Σ(c²/ν) = 1 / Σ(w²/ν)
    den = float(np.sum(np.where(w > 0, w ** 2 / dofs, 0.0)))
    return 1.0 / den if den > 0 else math.inf


def _p_two_sided(t: float, dof: float) -> float:
    return float(2 * stats.t.sf(abs(t), min(dof, 1e9)))


def axis_residuals(x: np.ndarray, y: np.ndarray, u: np.ndarray | None = None, dof_u: np.ndarray | None = None,
                   rate_tol_dps: float = RATE_TOL_DPS, alpha: float = ALPHA
                   ) -> tuple[list[dict[str, Any]], list[dict[str, Any]], dict[str, Any]]:
    """Residuals of one axis' points ``(x, y)`` (rate, step mean output; deg/s) against its line,
    per step and per rate, with their uncertainties, t and off-the-line flags.

    *Residual* (``residual_dps``, ``residual_percent``): measured minus the least-squares line through
    all points (the calibration's fit, ``fitted_dps``).

    *Test*: each rate's steps are compared with the line fitted *without that rate* (all its steps,
    e.g. both NPSAT1 sample sets) and without the points already found off: the deleted residual
    ``deleted_residual_dps = y − ŷ`` over its standard uncertainty ``sigma_dps`` gives ``t``
    (externally studentised: a step cannot hide itself by pulling the line or inflating the scatter,
    nor be hidden by its repeat). Points whose two-sided p-value is below ``alpha / n`` (Bonferroni
    over the axis' n points; per rate ``alpha / n_rates``) are off; they are then left out of the
    reference for the others and everything is retested until nothing new is found (masking: on
    NPSAT1 the four ±5 deg/s steps of an axis hide each other in a single pass).

    *Variance model* of a step mean: ``u² + σ_b² + σ_e²``. ``u``: its known standard uncertainty
    (``std/√n_eff`` of its samples, rounding, ...; 0 when unknown; dof ``dof_u``). ``σ_b²``: scatter
    shared by the steps at one rate (repeats are not independent: the NPSAT1 sample sets' residuals
    correlate at 0.96); ``σ_e²``: scatter of repeats at one rate beyond u. Both are estimated by
    moments from the reference points' residuals (``σ_e²`` from the spread within rates,
    ``Σ(k − 1)`` dof; ``σ_b²`` from the rate means, ``n_rates − 3`` dof), net of u. Then
    ``σ_d² = u² + σ_b² + σ_e² + var ŷ`` for a step and ``σ_b² + Σ(u² + σ_e²)/k² + var ŷ`` for a rate's
    mean, with Welch-Satterthwaite degrees of freedom. With one step per rate and no u this is the
    textbook externally studentised residual (Student-t, ``n − 3`` dof).

    Returns (one row per point, in input order; one row per rate, ascending; the axis summary).
    A point is untestable (None) when fewer than 3 other rates remain.
    """
    n = x.size
    u2 = np.zeros(n) if u is None else np.asarray(u, dtype=float) ** 2
    nu_u = np.full(n, np.inf) if dof_u is None else np.maximum(np.asarray(dof_u, dtype=float), 1.0)
    X = np.column_stack([x, np.ones(n)])
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    fitted = X @ coef
    resid = y - fitted
    groups = _groups(x, max(rate_tol_dps, 1e-12))
    label = np.empty(n, dtype=int)
    for g, idx in enumerate(groups):
        label[idx] = g
    step_level, rate_level = alpha / n, alpha / len(groups)

    def reference(ref: np.ndarray) -> dict[str, Any] | None:
        """Line and two-level scatter of the points ``ref`` (indices), or None with < 3 rates."""
        others = np.unique(label[ref])
        if others.size < 3:
            return None
        Xr = X[ref]
        A = np.linalg.inv(Xr.T @ Xr)
        beta = A @ (Xr.T @ y[ref])
        e = y[ref] - Xr @ beta
        Z = (label[ref][:, None] == others[None, :]).astype(float)  # steps × rates
        k = Z.sum(axis=0)
        gmean = (Z.T @ e) / k
        dof_w = int(np.sum(k - 1))
        kj = k[np.searchsorted(others, label[ref])]
        s_e2 = max(0.0, (float(np.sum((e - Z @ gmean) ** 2)) - float(np.sum((1 - 1 / kj) * u2[ref]))) / dof_w) if dof_w else 0.0
        P = Z.T @ Xr
        MZ = Z - Xr @ (A @ P.T)  # (I − H)·Z
        Gm = np.diag(k) - P @ A @ P.T  # Zᵀ(I − H)Z
        c_b = float(np.sum(Gm ** 2 / k[:, None] ** 2))  # E[Σ mean²] per unit σ_b²
        c_d = float(np.sum(((u2[ref] + s_e2)[:, None] * MZ ** 2).sum(axis=0) / k ** 2))
        s_b2 = max(0.0, (float(gmean @ gmean) - c_d) / c_b) if c_b > 0 else 0.0
        return {"ref": ref, "A": A, "beta": beta, "Z": Z, "s_b2": s_b2, "s_e2": s_e2,
                "dof_b": others.size - 2, "dof_w": dof_w}

    def test(excl: np.ndarray) -> tuple[list[tuple], list[tuple]]:
        st: list[tuple] = [(None,) * 4] * n  # (d, sigma_d, t, dof) per step
        rt: list[tuple] = [(None,) * 4] * len(groups)
        for g, G in enumerate(groups):
            m = reference(np.flatnonzero((label != g) & ~excl))
            if m is None:
                continue
            ref, s_b2, s_e2, dof_b, dof_w = m["ref"], m["s_b2"], m["s_e2"], m["dof_b"], max(m["dof_w"], 1)
            kg = G.size
            d_steps = y[G] - X[G] @ m["beta"]
            c = X[ref] @ (m["A"] @ np.array([float(np.mean(x[G])), 1.0]))  # prediction weights at the rate
            cz = m["Z"].T @ c
            pv_b, pv_e, pv_u = s_b2 * float(cz @ cz), s_e2 * float(c @ c), c ** 2 * u2[ref]
            for j, i in enumerate(G.tolist()):
                comps = np.concatenate([[u2[i], s_b2 + pv_b, s_e2 + pv_e], pv_u])
                var = float(comps.sum())
                if 0 < var < math.inf and math.isfinite(d_steps[j]):
                    nu = _satterthwaite(comps, np.concatenate([[nu_u[i], dof_b, dof_w], nu_u[ref]]))
                    st[i] = (float(d_steps[j]), math.sqrt(var), float(d_steps[j]) / math.sqrt(var), nu)
            comps = np.concatenate([[s_b2 + pv_b, s_e2 / kg + pv_e], u2[G] / kg ** 2, pv_u])
            var = float(comps.sum())
            d = float(np.mean(d_steps))
            if 0 < var < math.inf and math.isfinite(d):
                nu = _satterthwaite(comps, np.concatenate([[dof_b, dof_w], nu_u[G], nu_u[ref]]))
                rt[g] = (d, math.sqrt(var), d / math.sqrt(var), nu)
        return st, rt

    excl = np.zeros(n, dtype=bool)
    passes = 0
    while True:
        passes += 1
        st, rt = test(excl)
        off = np.array([s[2] is not None and _p_two_sided(s[2], s[3]) < step_level for s in st])
        for g, r in enumerate(rt):
            if r[2] is not None and _p_two_sided(r[2], r[3]) < rate_level:
                off[groups[g]] = True
        new = excl | off
        if (new == excl).all() or passes >= MAX_PASSES:
            break
        excl = new
    clean = ~excl
    m = reference(np.flatnonzero(clean))
    step_rows = []
    for i, (d, sd, t, nu) in enumerate(st):
        row = {"fitted_dps": jfloat(fitted[i]), "residual_dps": jfloat(resid[i]),
               "residual_percent": jfloat(100.0 * float(resid[i]) / x[i]) if x[i] != 0 else None,
               "deleted_residual_dps": d, "sigma_dps": sd, "t": t, "dof": None if nu is None else jfloat(nu),
               "p_value": None if t is None else _p_two_sided(t, nu), "off": False}
        row["off"] = row["p_value"] is not None and row["p_value"] < step_level
        if u2[i] > 0:
            row["sigma_known_dps"] = float(math.sqrt(u2[i]))
        step_rows.append(row)
    rate_rows = []
    for g, (d, sd, t, nu) in enumerate(rt):
        G = groups[g]
        pv = None if t is None else _p_two_sided(t, nu)
        rate_rows.append({"rate_dps": float(np.mean(x[G])), "n_steps": int(G.size), "residual_dps": jfloat(np.mean(resid[G])),
                          "deleted_residual_dps": d, "sigma_dps": sd, "z": t, "dof": None if nu is None else jfloat(nu),
                          "p_value": pv, "off": pv is not None and pv < rate_level})
    # scatter of the clean points about their own line (what the σ are made of)
    info: dict[str, Any] = {
        "alpha": alpha, "p_threshold": step_level, "p_threshold_rate": rate_level,
        "t_threshold": None, "n_tested": sum(1 for s in st if s[2] is not None),
        "n_off": int(sum(r["off"] for r in step_rows)), "n_rates": len(groups), "n_rates_off": int(sum(r["off"] for r in rate_rows)),
        "passes": passes, "n_left_out": int(excl.sum()),
        "scatter_dps": None, "scatter_clean_dps": None,
        "between_rate_dps": None if m is None else jfloat(math.sqrt(m["s_b2"])),
        "within_rate_dps": None if m is None or not m["dof_w"] else jfloat(math.sqrt(m["s_e2"])),
        "known_dps": float(math.sqrt(np.mean(u2[u2 > 0]))) if np.any(u2 > 0) else None,
    }
    nus = [s[3] for s in st if s[2] is not None]
    if nus:
        info["t_threshold"] = float(stats.t.isf(step_level / 2, min(float(np.median(nus)), 1e9)))
    if n > 2:
        info["scatter_dps"] = jfloat(math.sqrt(float(np.sum(resid ** 2)) / (n - 2)))
    if clean.sum() > 2 and np.unique(x[clean]).size >= 2:
        bc, *_ = np.linalg.lstsq(X[clean], y[clean], rcond=None)
        ec = y[clean] - X[clean] @ bc
        info["scatter_clean_dps"] = jfloat(math.sqrt(float(np.sum(ec ** 2)) / (clean.sum() - 2)))
    return step_rows, rate_rows, info


def common_mode(axes_json: dict[str, Any], rate_tol_dps: float = RATE_TOL_DPS, alpha: float = ALPHA
                ) -> tuple[list[dict[str, Any]], dict[str, Any], list[dict[str, Any]]]:
    """Reference rates whose steps are off the line on every axis measured at that rate.

    "Measured at that rate": the axes with steps driven about themselves at that signed rate, or
    with zero-rate references for rate 0 (each axis on the table in turn, as NPSAT1 Tables 9-11; a
    cross axis sees the table rate only through M, ~1e-3 of it, so a table-rate error does not show
    there). Only rates measured on two or more axes are tested. Per axis the rate's steps are pooled
    (:func:`axis_residuals`, in ``axes[a]["rates"]``). A rate is common-mode when its two-sided
    p-value is below ``alpha / n_rates`` on *every* measured axis (intersection-union test,
    Bonferroni over the ``n_rates`` rates tested). The residual signs need not agree (a reference
    shift need not act alike on every axis); ``same_sign`` says whether they do (a table running fast
    or slow gives the same sign on every axis).

    Returns (common-mode rates, test summary, partial: rates off on some but not all measured axes).
    """
    tol = max(rate_tol_dps, 1e-12)
    rows = [(a, r) for a, info in axes_json.items() for r in info.get("rates", [])]
    xs = np.array([r["rate_dps"] for _, r in rows], dtype=float)
    tested = []
    for G in _groups(xs, tol) if xs.size else []:
        by_axis: dict[str, dict[str, Any]] = {}
        for i in G.tolist():
            by_axis.setdefault(rows[i][0], rows[i][1])
        if len(by_axis) >= 2:
            tested.append((float(np.mean(xs[G])), by_axis))
    level = alpha / len(tested) if tested else math.nan
    found, partial = [], []
    for rate, by_axis in tested:
        axes_out = {a: {"residual_dps": r["residual_dps"], "deleted_residual_dps": r["deleted_residual_dps"],
                        "sigma_dps": r["sigma_dps"], "z": r["z"], "dof": r["dof"], "p_value": r["p_value"],
                        "off": r["p_value"] is not None and r["p_value"] < level, "n_steps": r["n_steps"],
                        "n_steps_off": sum(1 for s in axes_json[a]["steps"] + axes_json[a]["references"]
                                           if s["off"] and abs((s.get("rate_dps") or 0.0) - rate) <= tol)}
                    for a, r in sorted(by_axis.items())}
        entry = {"rate_dps": rate, "axes": axes_out,
                 "same_sign": len({math.copysign(1, v["deleted_residual_dps"] if v["deleted_residual_dps"] is not None
                                                  else v["residual_dps"]) for v in axes_out.values()}) == 1}
        n_off = sum(v["off"] for v in axes_out.values())
        if n_off == len(axes_out):
            found.append(entry)
        elif n_off:
            partial.append(entry)
    test = {"alpha": alpha, "n_rates": len(tested), "p_threshold": level if tested else None,
            "rule": "p < alpha/n_rates on every axis measured at the rate (its steps pooled per axis)"}
    return found, test, partial


# ---- the analysis --------------------------------------------------------------------------------
def _references(steps: list[Step], axis: str, tol: float) -> list[Step]:
    return [s for s in steps if s.driven_axis(tol) is None and axis in s.mean_output]


def _reference_for(step: Step, refs: list[Step], out: str) -> float | None:
    """Output ``out`` at zero rate for ``step`` (deg/s): mean of the nearest zero-rate references
    before and after it (or the one available), as the NPSAT1 references recorded "before and after
    the test cycle" (Sec. IV-E-1); None without references."""
    before = [r for r in refs if r.order < step.order]
    after = [r for r in refs if r.order > step.order]
    picked = ([before[-1]] if before else []) + ([after[0]] if after else [])
    if not picked:
        return None
    return float(np.mean([r.mean_output[out] for r in picked]))


def _observed_resolution(rates: list[float], errors: list[float | None]) -> float | None:
    """Smallest tested |rate| (deg/s) at and above which every step's |error| ≤ 5 % (NPSAT1 Sec. I-C-1-a)."""
    pairs = [(abs(r), e) for r, e in zip(rates, errors)]
    if not pairs or any(e is None for _, e in pairs):
        return None
    best = None
    for mag in sorted({m for m, _ in pairs}, reverse=True):
        if all(abs(e) <= 100 * REQUIREMENT_FRACTION for m, e in pairs if m == mag):
            best = mag
        else:
            break
    return best


def _within(step: Step, out: str) -> tuple[float, float]:
    """(known standard uncertainty of the step mean of output ``out``, its degrees of freedom):
    ``std/√n_eff`` of its samples (dof ``n_eff − 1``) combined with ``u_mean`` (e.g. rounding; exact);
    (0, inf) when neither is known."""
    std, ne = step.std_output.get(out), step.n_eff.get(out)
    parts = [] if std is None or ne is None or not math.isfinite(std) or ne < 2 else [(std ** 2 / ne, ne - 1.0)]
    extra = step.u_mean.get(out)
    if extra:
        parts.append((extra ** 2, math.inf))
    if not parts:
        return 0.0, math.inf
    var = sum(v for v, _ in parts)
    return math.sqrt(var), _satterthwaite(np.array([v for v, _ in parts]), np.array([d for _, d in parts]))


def analyse_steps(steps: list[Step], source: str, rate_tol_dps: float = RATE_TOL_DPS, alpha: float = ALPHA) -> CalibrationResult:
    """The rate-transfer calibration of a list of steps (from :func:`find_steps` or a summary CSV),
    with each step's residual against its axis' fit (:func:`axis_residuals`) and the common-mode
    rates (:func:`common_mode`); ``alpha`` is the family-wise false-alarm probability of the flags."""
    notes: list[str] = []
    mixed = [s for s in steps if s.driven_axis(rate_tol_dps) == "mixed"]
    if mixed:
        notes.append(f"{len(mixed)} step(s) turn about more than one axis at once and are not used")
    outputs = [a for a in AXES if any(a in s.mean_output for s in steps)]
    driven = {a: [s for s in steps if s.driven_axis(rate_tol_dps) == a] for a in AXES}
    axes_json: dict[str, Any] = {}
    M: list[list[float | None] | None] = [None, None, None]
    M_se: list[list[float | None] | None] = [None, None, None]
    for i, out in enumerate(AXES):
        if out not in outputs:
            continue
        refs = _references(steps, out, rate_tol_dps)
        row: list[float | None] = [None, None, None]
        row_se: list[float | None] = [None, None, None]
        for j, inp in enumerate(AXES):
            pts = [s for s in driven[inp] if out in s.mean_output]
            if not pts:
                continue
            use = pts + refs
            x = np.array([s.rates[j] for s in use])
            y = np.array([s.mean_output[out] for s in use])
            if np.unique(x).size < 2:
                continue
            slope, icpt, se_slope, se_icpt = linear_fit(x, y)
            row[j] = jfloat(slope - 1.0 if i == j else slope)
            row_se[j] = jfloat(se_slope)
            if i != j:
                continue
            step_rows = []
            minus_ref: list[tuple[float, float]] = []  # (rate, output − reference) for the "minus ref" fit
            for s in pts:
                r, m = s.rates[j], s.mean_output[out]
                ref = _reference_for(s, refs, out)
                entry: dict[str, Any] = {"rate_dps": r, "mean_output_dps": m,
                                         "percent_error": 100.0 * (m - r) / r,
                                         "percent_error_ref": None if ref is None else 100.0 * ((m - ref) - r) / r}
                if s.std_output.get(out) is not None and s.n > 1:
                    entry["std_output_dps"] = jfloat(s.std_output[out])
                    entry["n"] = s.n
                if s.t_start_s is not None:
                    entry["time_s"] = [s.t_start_s, s.t_end_s]
                if s.line is not None:
                    entry["line"] = s.line
                step_rows.append(entry)
                if ref is not None:
                    minus_ref.append((r, m - ref))
            bias_ref = None  # NPSAT1 b_minus_ref: residual bias after the references (Sec. IV-E-2-a)
            if len({r for r, _ in minus_ref}) >= 2:
                bias_ref = linear_fit(np.array([r for r, _ in minus_ref]), np.array([v for _, v in minus_ref]))[1]
            within = [_within(s, out) for s in use]
            u = np.array([w for w, _ in within])
            res_rows, rate_rows, res_info = axis_residuals(x, y, u if np.any(u > 0) else None, np.array([d for _, d in within]),
                                                           rate_tol_dps, alpha)
            for entry, res in zip(step_rows, res_rows):
                entry.update(res)
            ref_rows = [{"mean_output_dps": s.mean_output[out], **({"time_s": [s.t_start_s, s.t_end_s]} if s.t_start_s is not None else {}),
                         **({"line": s.line} if s.line is not None else {}),
                         **{k: v for k, v in res.items() if k != "residual_percent"}}
                        for s, res in zip(refs, res_rows[len(pts):])]
            rates = [s["rate_dps"] for s in step_rows]
            axes_json[out] = {
                "scale_factor_error": jfloat(slope - 1.0),
                "scale_factor_error_se": jfloat(se_slope),
                "bias_dps": jfloat(icpt),
                "bias_se_dps": jfloat(se_icpt),
                "bias_minus_ref_dps": jfloat(bias_ref),
                "steps": step_rows,
                "references": ref_rows,
                "residuals": res_info,
                "rates": rate_rows,
                "resolution_dps": jfloat(abs(icpt) / REQUIREMENT_FRACTION),
                "resolution_observed_dps": _observed_resolution(rates, [s["percent_error"] for s in step_rows]),
                "resolution_observed_ref_dps": _observed_resolution(rates, [s["percent_error_ref"] for s in step_rows]),
                "n_steps": len(step_rows),
                "n_fit": len(use),
            }
        M[i], M_se[i] = row, row_se
    if not axes_json:
        raise InputError("no axis has constant-rate steps at two or more different rates about itself "
                         f"(found {len(steps)} step(s)); the rate-transfer fit (NPSAT1 Eq. 17) needs them", Location(source))
    for a in outputs:
        if a not in axes_json:
            notes.append(f"axis {a}: no steps about this axis; scale factor and bias not determined")
    cm, cm_test, partial = common_mode(axes_json, rate_tol_dps, alpha)
    js = {"axes": axes_json, "M": M, "M_se": M_se, "requirement_percent": 100 * REQUIREMENT_FRACTION,
          "common_mode": cm, "common_mode_test": cm_test, "source": source}
    notes.extend(_residual_notes(js, partial))
    return CalibrationResult("rate-transfer", js, _tables(js), _calibration(js), notes)


def _signed(x: float) -> str:
    return f"{x:+g}"


def _residual_notes(js: dict[str, Any], partial: list[dict[str, Any]]) -> list[str]:
    """One line per axis with points off the line, one naming the common-mode rates (or none), one
    per rate off on some but not all of its measured axes, and one when the step means scatter
    much more than their own known noise explains."""
    notes = []
    for a, r in js["axes"].items():
        info = r["residuals"]
        off = [("0 deg/s (ref)" if s.get("rate_dps") is None else f"{_signed(s['rate_dps'])} deg/s", s)
               for s in r["steps"] + r["references"] if s["off"]]
        if off:
            notes.append(f"axis {a}: {len(off)} of {info['n_tested']} step(s) off the line (p < {info['p_threshold']:.2g}; "
                         "off by, against the line without the step's rate): "
                         + "; ".join(f"{name} {s['deleted_residual_dps']:+.3g} ± {s['sigma_dps']:.2g} deg/s (t = {s['t']:+.1f})"
                                     for name, s in off))
        if info["n_tested"] == 0:
            notes.append(f"axis {a}: too few rates ({info['n_rates']}) to test the residuals (each needs 3 other rates)")
        known, seen = info["known_dps"], info["scatter_clean_dps"]
        if known and seen is not None and seen > 3 * known:
            notes.append(f"axis {a}: the step means scatter about the line by {seen:.2g} deg/s, {seen / known:.0f}× their own "
                         f"noise ({known:.2g} deg/s): drift or rate-dependent error between steps; the σ include it")
    t = js["common_mode_test"]
    if js["common_mode"]:
        notes.append("common mode (off on every axis measured at the rate): " + "; ".join(
            f"{_signed(c['rate_dps'])} deg/s (" + ", ".join(f"{a} {v['deleted_residual_dps']:+.3g} ± {v['sigma_dps']:.2g}"
                                                          for a, v in c["axes"].items()) + " deg/s)" for c in js["common_mode"]))
    elif t["n_rates"]:
        notes.append(f"common mode: none (of {t['n_rates']} rate(s) measured on two or more axes)")
    else:
        notes.append("common mode: not tested (no rate measured on two or more axes)")
    for c in partial:
        on = [a for a, v in c["axes"].items() if v["off"]]
        rest = ", ".join(f"{a} {v['deleted_residual_dps']:+.3g} ± {v['sigma_dps']:.2g} deg/s (z = {v['z']:+.1f})"
                         if v["z"] is not None else f"{a} untested" for a, v in c["axes"].items() if not v["off"])
        notes.append(f"rate {_signed(c['rate_dps'])} deg/s: off on {', '.join(on)} but not on {rest}")
    return notes


def _pct(x: float | None, digits: int = 3) -> str:
    return "—" if x is None else f"{100 * x:.{digits}f}"


def _num(x: float | None, fmt: str = ".5f") -> str:
    return "—" if x is None else format(x, fmt)


def _tables(js: dict[str, Any]) -> list[ResultTable]:
    rows = []
    for a, r in js["axes"].items():
        rows.append([a, _pct(r["scale_factor_error"]), _pct(r["scale_factor_error_se"]), _num(r["bias_dps"]),
                     _num(r["bias_se_dps"]), _num(r["resolution_dps"], ".3f"),
                     f"{_num(r['resolution_observed_dps'], 'g')} / {_num(r['resolution_observed_ref_dps'], 'g')}",
                     str(r["n_steps"])])
    summary = ResultTable("Rate transfer (NPSAT1 Eq. 17): scale-factor error and fixed bias",
                          ["axis", "SF err %", "±", "bias deg/s", "±", "|b|/5% deg/s", "seen no ref/ref", "steps"], rows)
    steps = ResultTable("Output error per rate (NPSAT1 Tables 9-11; 100·(output − rate)/rate)",
                        ["axis", "rate deg/s", "mean output deg/s", "error % (no ref)", "error % (minus ref)"],
                        [[a, f"{s['rate_dps']:g}", f"{s['mean_output_dps']:.5f}", f"{s['percent_error']:.2f}",
                          _num(s["percent_error_ref"], ".2f")] for a, r in js["axes"].items() for s in r["steps"]])
    mrows = []
    for a, row in zip(AXES, js["M"]):
        mrows.append([a] + (["—"] * 3 if row is None else [_pct(v) for v in row]))
    mat = ResultTable("Misalignment matrix M (%): M[i][j] = d(output i)/d(rate j), diagonal = SF error",
                      ["output \\ rate", "x", "y", "z"], mrows)
    out = [summary, steps, mat]
    for a, r in js["axes"].items():
        info = r["residuals"]
        thr = f", |t| > {info['t_threshold']:.2f}" if info["t_threshold"] is not None else ""
        rows = []
        for st in r["steps"] + r["references"]:
            rate = st.get("rate_dps")
            rows.append([f"{rate:g}" if rate is not None else "0 (ref)", f"{st['mean_output_dps']:.5f}", f"{st['fitted_dps']:.5f}",
                         f"{st['residual_dps']:+.5f}", _num(st.get("residual_percent"), "+.2f"), _num(st["deleted_residual_dps"], "+.5f"),
                         _num(st["sigma_dps"], ".5f"), _num(st["t"], "+.2f"), "OFF" if st["off"] else ""])
        out.append(ResultTable(f"Residuals against the fit, axis {a}: off when p < {info['alpha']:g}/{len(rows)}{thr} "
                               "(deg/s; 'w/o rate': against the line fitted without the step's rate, σ and t of that)",
                               ["rate", "measured", "fitted", "residual", "% of rate", "w/o rate", "σ", "t", "off"], rows))
    if js["common_mode"]:
        out.append(ResultTable("Common-mode rates: off on every axis measured at the rate",
                               ["rate deg/s", "axis", "mean residual deg/s", "vs line without it deg/s", "σ deg/s", "z", "steps off"],
                               [[f"{c['rate_dps']:g}", a, f"{v['residual_dps']:+.5f}", _num(v["deleted_residual_dps"], "+.5f"),
                                 _num(v["sigma_dps"], ".5f"), _num(v["z"], "+.2f"), f"{v['n_steps_off']}/{v['n_steps']}"]
                                for c in js["common_mode"] for a, v in c["axes"].items()]))
    return out


def _calibration(js: dict[str, Any]) -> dict[str, Any]:
    return {
        "method": "rate-transfer",
        "model": "output = (I + M)·rate + b_cons (NPSAT1 Eq. 2, 3 and 17); rates in deg/s",
        "b_cons_dps": {a: r["bias_dps"] for a, r in js["axes"].items()},
        "b_cons_se_dps": {a: r["bias_se_dps"] for a, r in js["axes"].items()},
        "scale_factor_error": {a: r["scale_factor_error"] for a, r in js["axes"].items()},
        "scale_factor_error_se": {a: r["scale_factor_error_se"] for a, r in js["axes"].items()},
        "M": js["M"],
        "M_se": js["M_se"],
        "units": {"b_cons_dps": "deg/s", "scale_factor_error": "1 (fraction)", "M": "1 (fraction); rows = output axis x, y, z; columns = rate axis"},
    }


_OPTIONS = {
    "rate_tol_dps": f"reference rates closer than this are one step, deg/s (default {RATE_TOL_DPS})",
    "settle_s": f"time dropped at each end of a step, s (default {SETTLE_S})",
    "min_samples": f"fewest samples per step after the trim (default {MIN_STEP_SAMPLES})",
    "alpha": f"family-wise false-alarm probability of the off-the-line and common-mode flags (default {ALPHA})",
}
_SUMMARY_OPTIONS = {"alpha": _OPTIONS["alpha"]}


def calibrate(ds: Dataset, **opts: Any) -> CalibrationResult:
    """Method ``rate-transfer`` on a Dataset: steps from :func:`find_steps`, then the Eq. 17 fits.

    Options: ``rate_tol_dps`` (deg/s), ``settle_s`` (s), ``min_samples``, ``alpha``.
    """
    check_options("rate-transfer", opts, _OPTIONS)
    alpha = opt_float(opts, "alpha", ALPHA, 1e-9, 0.5)
    tol = opt_float(opts, "rate_tol_dps", RATE_TOL_DPS, 0.0, 1e3)
    settle = opt_float(opts, "settle_s", SETTLE_S, 0.0, 1e6)
    min_samples = opt_int(opts, "min_samples", MIN_STEP_SAMPLES, 1, 10**9)
    if not ds.gyro_axes:
        raise InputError("no gyro column (gyro_x_dps, gyro_y_dps, gyro_z_dps)", Location(ds.source), "gyro_z_dps")
    steps = find_steps(ds, tol, settle, min_samples)
    result = analyse_steps(steps, ds.source, tol, alpha)
    missing = [REF_RATE[a] for a in AXES if REF_RATE[a] not in ds]
    if missing:
        result.notes.append(f"no {', '.join(missing)}: taken as 0 deg/s (not driven)")
    result.json["n_steps_found"] = len(steps)
    return result


def calibrate_summary_csv(path: str | Path, **opts: Any) -> CalibrationResult:
    """Method ``rate-transfer`` on a summary CSV (columns ``axis``, ``rate_dps``, ``mean_output_dps``;
    one row per step, rate 0 = zero-rate reference; optional ``std_output_dps`` and ``n``). Bad cells
    raise :class:`InputError` with file:line. Option: ``alpha``."""
    check_options("rate-transfer", opts, _SUMMARY_OPTIONS)
    alpha = opt_float(opts, "alpha", ALPHA, 1e-9, 0.5)
    steps = read_summary_csv(path)
    return analyse_steps(steps, str(path), 0.0, alpha)
