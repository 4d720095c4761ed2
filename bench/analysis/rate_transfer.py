"""Rate-transfer calibration (method ``rate-transfer``): scale-factor error, fixed bias, misalignment
and output error per rate from constant-rate steps on a rate table (NPSAT1 thesis, section IV-E).

Two inputs:

* a :class:`~bench.analysis.dataset.Dataset` (measured-data CSV or run file) with ``ref_rate_*_dps``
  and ``gyro_*_dps``: :func:`find_steps` cuts it into segments of constant reference rate, drops
  the settling transient at each end and averages the outputs per step; or
* a summary CSV (:func:`calibrate_summary_csv`) with one row per step: ``axis`` (x/y/z, the sensor
  under test), ``rate_dps`` (table rate, deg/s) and ``mean_output_dps`` (that sensor's mean output,
  deg/s); rows with ``rate_dps`` 0 are zero-rate references. Extra columns are ignored.

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

from bench.analysis.dataset import AXES, GYRO, REF_RATE, Dataset
from bench.analysis.result import CalibrationResult, ResultTable
from bench.csvsrc import read_csv_table
from bench.errors import InputError, Location

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
        tc = None
        if temp is not None:
            tt = temp[keep]
            tt = tt[np.isfinite(tt)]
            tc = float(np.mean(tt)) if tt.size else None
        line = int(ds.line_numbers[keep[0]]) if ds.line_numbers is not None else None
        steps.append(Step(len(steps), rates, mean, std, int(keep.size), float(t[keep[0]]), float(t[keep[-1]]), tc, line))
    return steps


# ---- summary CSV ---------------------------------------------------------------------------------
SUMMARY_COLUMNS = ("axis", "rate_dps", "mean_output_dps")


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
            cell = row[idx[name]].strip()
            try:
                v = float(cell)
            except ValueError:
                raise InputError(f"expected a number, got {cell!r}", where, name) from None
            if not math.isfinite(v):
                raise InputError(f"expected a finite number, got {cell!r}", where, name)
            nums[name] = v
        rates = tuple(nums["rate_dps"] if a == axis else 0.0 for a in AXES)
        steps.append(Step(len(steps), rates, {axis: nums["mean_output_dps"]}, line=ln))
    return steps


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


def analyse_steps(steps: list[Step], source: str, rate_tol_dps: float = RATE_TOL_DPS) -> CalibrationResult:
    """The rate-transfer calibration of a list of steps (from :func:`find_steps` or a summary CSV)."""
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
            rates = [s["rate_dps"] for s in step_rows]
            axes_json[out] = {
                "scale_factor_error": jfloat(slope - 1.0),
                "scale_factor_error_se": jfloat(se_slope),
                "bias_dps": jfloat(icpt),
                "bias_se_dps": jfloat(se_icpt),
                "bias_minus_ref_dps": jfloat(bias_ref),
                "steps": step_rows,
                "references": [{"mean_output_dps": s.mean_output[out], **({"time_s": [s.t_start_s, s.t_end_s]} if s.t_start_s is not None else {}),
                                **({"line": s.line} if s.line is not None else {})} for s in refs],
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
    js = {"axes": axes_json, "M": M, "M_se": M_se, "requirement_percent": 100 * REQUIREMENT_FRACTION, "source": source}
    return CalibrationResult("rate-transfer", js, _tables(js), _calibration(js), notes)


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
    return [summary, steps, mat]


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
}


def calibrate(ds: Dataset, **opts: Any) -> CalibrationResult:
    """Method ``rate-transfer`` on a Dataset: steps from :func:`find_steps`, then the Eq. 17 fits.

    Options: ``rate_tol_dps`` (deg/s), ``settle_s`` (s), ``min_samples``.
    """
    check_options("rate-transfer", opts, _OPTIONS)
    tol = opt_float(opts, "rate_tol_dps", RATE_TOL_DPS, 0.0, 1e3)
    settle = opt_float(opts, "settle_s", SETTLE_S, 0.0, 1e6)
    min_samples = opt_int(opts, "min_samples", MIN_STEP_SAMPLES, 1, 10**9)
    if not ds.gyro_axes:
        raise InputError("no gyro column (gyro_x_dps, gyro_y_dps, gyro_z_dps)", Location(ds.source), "gyro_z_dps")
    steps = find_steps(ds, tol, settle, min_samples)
    result = analyse_steps(steps, ds.source, tol)
    missing = [REF_RATE[a] for a in AXES if REF_RATE[a] not in ds]
    if missing:
        result.notes.append(f"no {', '.join(missing)}: taken as 0 deg/s (not driven)")
    result.json["n_steps_found"] = len(steps)
    return result


def calibrate_summary_csv(path: str | Path, **opts: Any) -> CalibrationResult:
    """Method ``rate-transfer`` on a summary CSV (columns ``axis``, ``rate_dps``, ``mean_output_dps``;
    one row per step, rate 0 = zero-rate reference). Bad cells raise :class:`InputError` with file:line."""
    check_options("rate-transfer", opts, {})
    steps = read_summary_csv(path)
    return analyse_steps(steps, str(path), 0.0)
