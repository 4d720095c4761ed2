"""``bench calibrate noise`` and ``bench calibrate moving-average``: random-drift characterisation of
static gyro data (method and equations in ``docs/noise.md``).

* :func:`calibrate` (method ``noise``, NPSAT1 thesis IV.G.3, IEEE Std 952 Annex C): overlapping
  Allan deviation of each gyro axis with chi-squared confidence intervals and local slopes, and the
  terms read off the curve by the book (:func:`bench.analysis.allan.read_noise_terms`): angle random
  walk (deg/√h, the −½ line at τ = 1 s), bias instability (deg/h, the flat line 0.664·B; NPSAT1's
  minimum / 0.664 where no floor is resolved), rate random walk (deg/h/√h, σ = K·√(τ/3)), rate ramp
  (deg/h/h, σ = R·τ/√2) and quantization (deg, σ = √3·Q/τ), each from where the curve has its slope,
  with the range, interval and clusters, or ``null`` with the reason; a quantised output is detected.
* :func:`calibrate_moving_average` (method ``moving-average``, ESTCube-2 thesis 3.3 / 4.1): the
  standard deviation of the N-sample moving average of the static output versus the buffer length
  N, with the σ₁/√N line expected for white noise.

Both use the static part of the data: rows where every ``ref_rate_*_dps`` column present is 0 deg/s
(all rows when there is none), and of those the longest stretch sampled evenly (no time gap larger
than 1.5 sample intervals). Other stretches are left out and said so in a note. For a run file with
a recording window named ``static`` (``procedures/allan_static.yaml``) only that window is used
(option ``window``), so the warm-up transient stays out.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bench.analysis.allan import (
    FLICKER_FLOOR,
    NAMES,
    ONE_SIGMA,
    READ_TERMS,
    SLOPE,
    SLOPE_Z,
    UNITS,
    AllanResult,
    NoiseReadout,
    TermReading,
    analysis_m,
    overlapping_adev,
    read_noise_terms,
    select_m,
)
from bench.analysis.dataset import AXES, GYRO, REF_RATE, Dataset, refuse_nothing_to_fit
from bench.analysis.result import CalibrationResult, ResultTable
from bench.errors import InputError, Location

MIN_SAMPLES = 64
"""Fewest static samples the analyses accept (octave τ up to 16 samples)."""

STATIC_TOLERANCE_DPS = 1e-9
"""|reference rate| at or below this counts as 0 deg/s (static)."""

GAP_FACTOR = 1.5
"""A time step longer than this many nominal sample intervals (or shorter than 1/this) breaks the
evenly sampled stretch."""

DEFAULT_BUFFER_LENGTHS = (1, 2, 4, 8, 16, 32, 40, 64, 100)
"""Moving-average buffer lengths N by default: octaves, ESTCube-2's chosen N = 40, its maximum 100."""

DEG_H_PER_DPS = 3600.0


@dataclass
class StaticData:
    """The static, evenly sampled stretch used by the analyses: ``ds`` (its rows), ``fs`` (Hz),
    ``notes`` for the operator, ``first_row``/``last_row`` (0-based rows of the input dataset)."""

    ds: Dataset
    fs: float
    notes: list[str]
    first_row: int
    last_row: int


# ---- static stretch -----------------------------------------------------------------------------
_WINDOW = re.compile(r"rows in window '([^']*)'")
STATIC_WINDOW = "static"
"""Recording window that ``window="auto"`` selects (``procedures/allan_static.yaml``)."""


def run_windows(ds: Dataset) -> dict[str, tuple[float, float]]:
    """Recording windows of a run file dataset: name -> (start, end) run time (s), from the record
    steps of the run summary; empty for CSV data or when the run file cannot be summarised. A name
    recorded twice keeps its last window."""
    src = ds.source
    if not src or not src.lower().endswith((".h5", ".hdf5")) or not Path(src).is_file():
        return {}
    try:
        from bench.record.reader import read_run_summary

        summary = read_run_summary(Path(src))
    except Exception:  # noqa: BLE001 - no summary simply means no windows to choose from
        return {}
    out: dict[str, tuple[float, float]] = {}
    for st in summary.steps:
        m = _WINDOW.search(st.detail or "")
        if st.type == "record" and m and st.t_start_s is not None and st.t_end_s is not None:
            out[m.group(1)] = (float(st.t_start_s), float(st.t_end_s))
    return out


def _window_mask(ds: Dataset, window: str | None, notes: list[str]) -> np.ndarray:
    """Rows inside the chosen recording window (all rows for ``"all"``/``None`` or when ``"auto"``
    finds no ``static`` window)."""
    n = len(ds)
    if window in (None, "all"):
        return np.ones(n, dtype=bool)
    if not isinstance(window, str):
        raise InputError(f"window must be a recording window name, 'auto' or 'all', got {window!r}")
    windows = run_windows(ds)
    name = STATIC_WINDOW if window == "auto" else window
    if name not in windows:
        if window == "auto":
            return np.ones(n, dtype=bool)
        raise InputError(f"{ds.source or 'dataset'}: no recording window {window!r} "
                         f"(windows: {', '.join(windows) or 'none; only run files have windows'})")
    t0, t1 = windows[name]
    t = np.asarray(ds["time_s"], dtype=float)
    notes.append(f"used the run's recording window {name!r} (t = {t0:g}-{t1:g} s)")
    return (t > t0) & (t <= t1)


def static_data(ds: Dataset, skip_s: float = 0.0, axes: Sequence[str] | str | None = None,
                window: str | None = "auto") -> StaticData:
    """Select the longest evenly sampled static stretch of ``ds`` (inside recording ``window`` of a
    run file: ``"auto"`` = the ``static`` window when there is one, ``"all"`` = every row) and drop
    its first ``skip_s`` s.

    Raises :class:`InputError` (naming the source and column) when there is no gyro column, no
    static row, too few samples, or a non-finite gyro value in the stretch.
    """
    src = ds.source or "dataset"
    if "time_s" not in ds.columns:
        raise InputError(f"{src}: the noise analysis needs column 'time_s'")
    use_axes = _axes(ds, axes)
    n = len(ds)
    if n < MIN_SAMPLES:
        raise InputError(f"nothing to fit: {n} row(s); the noise analysis needs at least {MIN_SAMPLES} static samples",
                         Location(src), GYRO[use_axes[0]])
    fs = ds.sample_rate_hz
    if not (math.isfinite(fs) and fs > 0):
        raise InputError(f"{src}: cannot tell the sample rate (sample_rate_hz = {fs!r})", field="time_s")
    fs = float(f"{fs:.10g}")  # 100.00000000009 Hz from rounded time stamps is 100 Hz
    t = np.asarray(ds["time_s"], dtype=float)

    notes: list[str] = []
    in_window = _window_mask(ds, window, notes)
    if not in_window.any():
        raise InputError(f"{src}: recording window {window!r} holds no samples", field="time_s")
    refs = [REF_RATE[a] for a in AXES if REF_RATE[a] in ds.columns]
    if refs:
        static = in_window.copy()
        for c in refs:
            r = np.asarray(ds[c], dtype=float)
            static &= np.isfinite(r) & (np.abs(r) <= STATIC_TOLERANCE_DPS)
        if not static.any():
            raise InputError(f"{src}: no static rows: {', '.join(refs)} are never all 0 deg/s; the noise analysis "
                             "needs a recording with the unit at rest", field=refs[0])
    else:
        static = in_window

    dt = np.diff(t) * fs
    pair = in_window[1:] & in_window[:-1]
    typical = float(np.median(dt[pair])) if pair.any() else 1.0
    if not 1.0 / GAP_FACTOR < typical < GAP_FACTOR:
        raise InputError(f"{src}: time_s steps (median {typical / fs:.6g} s) do not match sample_rate_hz = {fs:g} Hz "
                         f"({1 / fs:.6g} s per sample)", field="time_s")
    even = (dt > 1.0 / GAP_FACTOR) & (dt < GAP_FACTOR)
    link = static[1:] & static[:-1] & even  # row i+1 continues the stretch of row i
    # runs of rows joined by static, evenly spaced steps; keep the longest static one
    breaks = np.flatnonzero(~link) + 1
    starts = np.concatenate([[0], breaks])
    stops = np.concatenate([breaks - 1, [n - 1]])
    lengths = np.where(static[starts], stops - starts + 1, 0)
    j = int(np.argmax(lengths))
    best_len, a0, b0 = int(lengths[j]), int(starts[j]), int(stops[j])
    gaps = int(np.count_nonzero(~even[pair]))
    n_static = int(np.count_nonzero(static))
    n_window = int(np.count_nonzero(in_window))
    if best_len < n_window or gaps:
        parts = []
        if refs and n_static < n_window:
            parts.append(f"{n_window - n_static} moving rows")
        if gaps:
            badness = np.where(pair, np.abs(np.log(np.clip(dt, 1e-12, None))), -1.0)
            k = int(np.argmax(badness))
            parts.append(f"{gaps} uneven time step(s) (worst {np.diff(t)[k]:.6g} s at t = {t[k]:.6g} s, nominal "
                         f"{1 / fs:.6g} s)")
        if n_static > best_len:
            parts.append(f"{n_static - best_len} static samples in other stretches")
        notes.append(f"{src}: analysed the longest evenly sampled static stretch, rows {a0 + 1}-{b0 + 1} "
                     f"(t = {t[a0]:.6g}-{t[b0]:.6g} s, {best_len} samples); left out {n_window - best_len} rows"
                     + (f" ({'; '.join(parts)})" if parts else ""))
    if skip_s:
        if not (math.isfinite(skip_s) and skip_s >= 0):
            raise InputError(f"skip_s must be a number of seconds >= 0, got {skip_s!r}")
        k = int(np.searchsorted(t[a0:b0 + 1], t[a0] + skip_s, side="left"))
        a0 += k
        notes.append(f"skipped the first {skip_s:g} s of the static stretch ({k} samples, warm-up)")
    count = b0 - a0 + 1
    if count < MIN_SAMPLES:
        raise InputError(f"{src}: the longest evenly sampled static stretch has {max(count, 0)} samples after "
                         f"skipping; the noise analysis needs at least {MIN_SAMPLES}", field="time_s")
    seg = ds.select(np.arange(a0, b0 + 1))
    steps = np.diff(seg["time_s"]) * fs
    jitter = float(np.std(steps))
    ratio = float(np.median(steps))
    if abs(ratio - 1) > 0.01:
        notes.append(f"{src}: time_s steps (median {ratio / fs:.6g} s) differ from 1/sample_rate_hz "
                     f"({1 / fs:.6g} s) by {100 * (ratio - 1):+.1f} %; used sample_rate_hz = {fs:g} Hz")
    if jitter > 0.01:
        notes.append(f"{src}: sample times jitter by {100 * jitter:.1f} % of the interval (RMS); the analysis assumes "
                     "even sampling, short-τ results are approximate")
    for a in use_axes:
        col = GYRO[a]
        v = np.asarray(seg[col], dtype=float)
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            row = a0 + int(bad[0])
            loc = Location(src, int(ds.line_numbers[row])) if ds.line_numbers is not None else None
            raise InputError(f"{'' if loc else src + ': '}row {row + 1}: value {v[bad[0]]!r} is not a finite rate",
                             loc, col)
    refuse_nothing_to_fit(seg, [GYRO[a] for a in use_axes], "the noise analysis needs a gyro output that varies "
                          "(a constant output is a dead channel or noise below one output step)")
    return StaticData(seg, float(fs), notes, a0, b0)


def _axes(ds: Dataset, axes: Sequence[str] | str | None) -> list[str]:
    src = ds.source or "dataset"
    present = ds.gyro_axes
    if not present:
        raise InputError(f"{src}: no gyro column (expected gyro_x_dps, gyro_y_dps or gyro_z_dps; present: "
                         f"{', '.join(ds.columns) or 'none'})")
    if axes is None:
        return present
    wanted = list(axes.replace(",", " ").split()) if isinstance(axes, str) else list(axes)
    for a in wanted:
        if a not in AXES:
            raise InputError(f"unknown axis {a!r} (use x, y or z)")
        if a not in present:
            raise InputError(f"{src}: no column {GYRO[a]!r} for axis {a} (present: {', '.join(ds.columns)})", field=GYRO[a])
    return wanted


def _numbers(value: Any, name: str) -> list[float] | None:
    if value is None:
        return None
    items = value.replace(",", " ").split() if isinstance(value, str) else (
        list(value) if isinstance(value, Iterable) else [value])
    try:
        out = [float(v) for v in items]
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected numbers, got {value!r}") from None
    if not out or not all(math.isfinite(v) and v > 0 for v in out):
        raise InputError(f"{name}: expected positive numbers, got {value!r}")
    return out


def _check_options(method: str, opts: dict[str, Any]) -> None:
    if opts:
        raise InputError(f"calibrate {method}: unknown option(s) {', '.join(sorted(opts))}")


# ---- LSB (digital output resolution) -----------------------------------------------------------
MAX_LEVELS = 1 << 24
"""A quantised output spans at most this many steps (a 24-bit converter)."""

MIN_STEP_REL = 1e-9
"""A quantisation step is at least this fraction of the largest |value| (well above float resolution,
2.2e-16 relative, whose gaps between distinct float values are not an output step)."""

LEVELS_PROBE = 100_000
"""Samples probed for the distinct output values (the step search and ``output_levels``)."""


def detect_lsb(values: np.ndarray, probe: int = LEVELS_PROBE) -> float | None:
    """The output resolution (deg/s) of a quantised output (a digital gyro register such as 16 bits,
    or a CSV printed with few decimals); ``None`` for continuous (float) data or an output with fewer
    than three distinct values.

    The step is the smallest gap between distinct values of the first ``probe`` samples. The output
    counts as quantised when it has few levels for its samples (distinct values ≤ half the samples
    probed), the step is well above float resolution (≥ 10⁻⁹ of the largest |value|), the values span
    at most 2²⁴ steps, and every value lies within 10⁻⁶ step of the grid.
    """
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    head = v[:probe]
    u = np.unique(head)
    if u.size < 3 or u.size > head.size // 2:
        return None
    d = np.diff(u)
    step = float(d.min())
    span = float(u[-1] - u[0])
    if step < MIN_STEP_REL * float(np.max(np.abs(u))) or span / step > MAX_LEVELS:
        return None
    k = d / step
    if np.max(np.abs(k - np.round(k))) > 1e-6:
        return None
    off = (v - u[0]) / step
    if np.max(np.abs(off - np.round(off))) > 1e-6:
        return None
    return span / round(span / step)


# ---- noise (Allan deviation) --------------------------------------------------------------------
@dataclass
class AxisNoise:
    """One axis: the Allan deviation at the displayed τ (``allan``), the read-out on the analysis grid
    (``readout``: dense τ, local slopes, :class:`TermReading` per term), the output step ``lsb_dps``
    (``None`` when not quantised), ``levels`` the number of distinct values among the first
    LEVELS_PROBE samples, and the ARW with the step's white noise taken off (Sheppard), ``None`` when
    not applicable."""

    allan: AllanResult
    readout: NoiseReadout
    lsb_dps: float | None
    levels: int
    arw_lsb_corrected_deg_per_sqrt_h: float | None

    def reading(self, term: str) -> TermReading:
        return self.readout.readings[term]

    def value(self, term: str) -> float | None:
        """The reading in its customary unit (:data:`UNITS`), ``None`` when not reported."""
        r = self.reading(term)
        return r.customary(r.value)

    @property
    def slope(self) -> np.ndarray:
        """Local slope at the displayed τ."""
        return self.readout.slope[self._display]

    @property
    def slope_u(self) -> np.ndarray:
        return self.readout.slope_u[self._display]

    @property
    def _display(self) -> np.ndarray:
        return np.searchsorted(self.readout.allan.m, self.allan.m)


def analyse_axis(rate: np.ndarray, fs: float, taus: Sequence[float] | None = None,
                 confidence: float = ONE_SIGMA) -> AxisNoise:
    """Allan deviation of one static rate series (deg/s at ``fs`` Hz) at the displayed ``taus``
    (default octaves) and on the analysis grid (four τ per octave, τ = 1 s and the displayed τ), and
    the read-outs by the book (:func:`bench.analysis.allan.read_noise_terms`)."""
    y = np.asarray(rate, dtype=float)
    n = int(y.size)
    shown = select_m(n, fs, taus)
    grid = analysis_m(n, fs, shown)
    readout = read_noise_terms(overlapping_adev(y, fs, grid / fs, confidence=confidence))
    allan = readout.allan.subset(np.searchsorted(readout.allan.m, shown))
    levels = int(np.unique(y[:LEVELS_PROBE]).size)
    lsb = detect_lsb(y, LEVELS_PROBE)
    corrected = None
    arw = readout.readings["arw"]
    if lsb is not None and arw.value is not None:
        # Sheppard: rounding to the LSB adds independent white error of variance LSB²/12 per sample
        # when the noise is at least half an LSB; it raises N² by LSB²/(12 f_s).
        n2 = arw.value ** 2 - lsb ** 2 / (12.0 * fs)
        sigma_true = math.sqrt(max(n2, 0.0) * fs)
        if n2 > 0 and sigma_true >= lsb / 2:
            corrected = math.sqrt(n2) * 60.0
    return AxisNoise(allan, readout, lsb, levels, corrected)


def calibrate(ds: Dataset, *, taus: Sequence[float] | str | None = None, confidence: float = ONE_SIGMA,
              skip_s: float = 0.0, axes: Sequence[str] | str | None = None, window: str | None = "auto",
              **opts: Any) -> CalibrationResult:
    """Method ``noise``: Allan-deviation noise read-outs of every gyro axis of ``ds``.

    Options: ``taus`` averaging times (s) shown in the tables and JSON arrays (default octaves
    m = 1, 2, 4, … ≤ n/4 samples; the read-outs always use the dense analysis grid), ``confidence``
    level of the ADEV intervals (default 0.683, ±1σ), ``skip_s`` seconds dropped at the start of the
    static stretch (warm-up; default 0), ``axes`` subset of x, y, z, ``window`` the run file's
    recording window (default ``"auto"``: ``static`` when recorded, else every row; ``"all"``: every
    row).
    JSON shape: see ``docs/noise.md``. Raises :class:`InputError` for bad data or options.
    """
    _check_options("noise", opts)
    if not (isinstance(confidence, (int, float)) and 0 < confidence < 1):
        raise InputError(f"confidence must lie between 0 and 1, got {confidence!r}")
    tau_list = _numbers(taus, "taus")
    sd = static_data(ds, float(skip_s), axes, window)
    use_axes = _axes(ds, axes)
    notes = list(sd.notes)
    if window in ("auto", "all") and _board_windows(ds):
        notes.append("this run changes the board's moving average between its N<k> windows: the Allan deviation "
                     "mixes them (use the moving-average method, or window=N1)")
    out_axes: dict[str, Any] = {}
    rows: list[list[Any]] = []
    detail: list[list[Any]] = []
    per_axis: dict[str, AxisNoise] = {}
    for a in use_axes:
        rate = np.asarray(sd.ds[GYRO[a]], dtype=float)
        res = analyse_axis(rate, sd.fs, tau_list, float(confidence))
        per_axis[a] = res
        out_axes[a] = _axis_json(res)
        notes.extend(_axis_notes(a, res, sd.fs))
        n_read, b = res.reading("arw"), res.reading("bias_instability")
        b_cell = f"{_cell(res.value('bias_instability'))} (estimate)" if b.estimate_only else _cell(res.value("bias_instability"))
        rows.append([a, _cell(res.value("arw")), _cell(n_read.tau_s if n_read.value is not None else None), b_cell,
                     _cell(b.tau_s if b.value is not None else None), _cell(res.value("rrw")),
                     _cell(res.value("quantization")), _cell(res.value("rate_ramp")),
                     ", ".join(t for t in READ_TERMS if res.reading(t).resolved) or "-"])
        for t in READ_TERMS:
            r = res.reading(t)
            if r.value is None:
                continue
            detail.append([a, NAMES[t], _sig(r.customary(r.value)), _sig(r.customary(r.ci[0])), _sig(r.customary(r.ci[1])),
                           UNITS[t][0], _sig(r.tau_s), f"{_sig(r.tau_range_s[0])}-{_sig(r.tau_range_s[1])}",
                           r.n_terms, r.clusters, f"{r.slope:+.2f} ± {r.slope_u:.2f}"])
    src = ds.source or "dataset"
    n_static = len(sd.ds)
    tables = [
        ResultTable(
            f"Gyro noise from {src} ({n_static} static samples at {sd.fs:g} Hz, "
            f"{n_static / sd.fs / 3600:.3g} h; IEEE Std 952 / NPSAT1 read-outs, '-' = not reported, see notes)",
            ["axis", "ARW (deg/√h)", "at τ (s)", "bias instability (deg/h)", "at τ (s)", "RRW (deg/h/√h)",
             "quantization (deg)", "rate ramp (deg/h/h)", "terms resolved"],
            rows),
        ResultTable(f"Read-outs: value, {100 * confidence:.0f} % interval from the curve's at the read point, where read",
                    ["axis", "term", "value", "low", "high", "unit", "read at τ (s)", "τ range (s)", "overlapping clusters",
                     "independent clusters", "local slope"], detail),
        _adev_table(per_axis, float(confidence)),
    ]
    t = sd.ds["time_s"]
    payload = {
        "axes": out_axes,
        "sample_rate_hz": sd.fs,
        "confidence": float(confidence),
        "slope_z": SLOPE_Z,
        "static_samples": n_static,
        "static_t_s": [float(t[0]), float(t[-1])],
    }
    return CalibrationResult("noise", payload, tables, None, notes)


def _cell(v: float | None) -> Any:
    return "-" if v is None else _sig(v)


def _pair(v: tuple[float, float] | None, factor: float = 1.0) -> list[float] | None:
    return None if v is None else [float(v[0]) * factor, float(v[1]) * factor]


def _term_json(r: TermReading) -> dict[str, Any]:
    unit, f = UNITS[r.term]
    out: dict[str, Any] = {
        "value": r.customary(r.value),
        "unit": unit,
        "reason": r.reason,
        "read": r.how or ("slope region" if r.value is not None else None),
        "estimate_only": r.estimate_only,
        "tau_s": r.tau_s if r.value is not None else None,
        "tau_range_s": _pair(r.tau_range_s),
        "ci": _pair(r.ci, f),
        "n_terms": r.n_terms if r.value is not None else None,
        "clusters": r.clusters if r.value is not None else None,
        "slope_at_read": r.slope if r.value is not None else None,
        "slope_uncertainty": r.slope_u if r.value is not None else None,
        "slope_range_s": _pair(r.slope_range_s),
        "upper_bound": r.customary(r.upper_bound),
    }
    if r.term == "arw":
        out["not_at_1s"] = r.not_at_1s if r.value is not None else None
        alt = r.alternative
        out["where_slope"] = None if alt is None else {
            "value": alt["value"] * f, "ci": _pair(alt["ci"], f), "tau_s": alt["tau_s"],
            "tau_range_s": _pair(alt["tau_range_s"]), "slope_at_read": alt["slope"], "slope_uncertainty": alt["slope_u"],
            "slope_range_s": _pair(alt["slope_range_s"])}
    return out


def _axis_json(res: AxisNoise) -> dict[str, Any]:
    al, b, arw = res.allan, res.reading("bias_instability"), res.reading("arw")
    return {
        "arw_deg_per_sqrt_h": res.value("arw"),
        "bias_instability_deg_per_h": res.value("bias_instability"),
        "rrw_deg_per_h_per_sqrt_h": res.value("rrw"),
        "quantization_deg": res.value("quantization"),
        "rate_ramp_deg_per_h_per_h": res.value("rate_ramp"),
        "taus_s": al.taus_s.tolist(),
        "adev_dps": al.adev.tolist(),
        "adev_lo_dps": al.adev_lo.tolist(),
        "adev_hi_dps": al.adev_hi.tolist(),
        "n_terms": al.n_terms.tolist(),
        "edf": al.edf.tolist(),
        "slope": [None if not math.isfinite(v) else float(v) for v in res.slope],
        "slope_uncertainty": [None if not math.isfinite(v) else float(v) for v in res.slope_u],
        "arw_slope_at_read": arw.slope if arw.value is not None else None,
        "bias_instability_tau_s": b.tau_s,
        "bias_instability_raw_deg_per_h": (float(np.min(res.readout.allan.adev)) / FLICKER_FLOOR * DEG_H_PER_DPS
                                           if res.readout.allan.adev.size else None),
        "bias_instability_fit_deg_per_h": res.value("bias_instability"),
        "detected": {t: res.reading(t).resolved for t in READ_TERMS},
        "terms": {t: _term_json(res.reading(t)) for t in READ_TERMS},
        "lsb_dps": res.lsb_dps,
        "output_levels": res.levels,
        "arw_lsb_corrected_deg_per_sqrt_h": res.arw_lsb_corrected_deg_per_sqrt_h,
    }


def _axis_notes(a: str, res: AxisNoise, fs: float) -> list[str]:
    al = res.allan
    out: list[str] = []
    if not np.any(al.adev > 0):
        return [f"{a}: the output does not change over the static stretch (below one output step?): no noise to analyse"]
    arw, b = res.reading("arw"), res.reading("bias_instability")
    if arw.value is not None:
        v = arw.customary(arw.value)
        if arw.how == "slope region":
            why = arw.not_at_1s or "the −½ line could not be read at τ = 1 s"
            out.append(f"{a}: ARW {v:.4g} deg/√h read at τ = {arw.tau_s:.3g} s where the slope is −½ ({why})")
        if not arw.at_slope:
            shape = "rises" if arw.slope > SLOPE["arw"] else "falls faster than −½"
            text = (f"{a}: ARW {v:.4g} deg/√h is the −½ line read at τ = {arw.tau_s:.3g} s (NPSAT1), but the curve {shape} "
                    f"there (slope {arw.slope:+.2f} ± {arw.slope_u:.2f})")
            if arw.slope > SLOPE["arw"]:
                text += (": correlated noise. The reading is the largest white noise the curve allows from 1 s on; below "
                         "1 s the curve lies under the −½ line (output filter or correlated noise)")
            alt = arw.alternative
            if alt is not None:
                lo, hi = alt["slope_range_s"]
                text += (f". Where the curve itself falls as −½ (τ = {lo:.3g}-{hi:.3g} s) the −½ line touching it "
                         f"from below (at τ = {alt['tau_s']:.3g} s) gives {alt['value'] * 60:.4g} deg/√h "
                         "(`terms.arw.where_slope`): over integration times beyond that τ the noise grows like an angle "
                         "random walk of that size. The curve cannot tell white noise behind a filter from a correlated "
                         "(Gauss-Markov-like) process")
            out.append(text)
    if b.value is not None and b.estimate_only:
        bv = b.customary(b.value)
        if b.how == "minimum, no flat region":
            out.append(f"{a}: no flat region: the slope passes 0 within less than an octave around the minimum "
                       f"(τ = {b.tau_s:.3g} s); the bias instability {bv:.4g} deg/h (minimum / 0.664) is an estimate only, "
                       "an upper bound (NPSAT1 Table 13)")
        else:
            lo, hi = b.slope_range_s
            out.append(f"{a}: bias instability {bv:.4g} deg/h (minimum / 0.664 at τ = {b.tau_s:.3g} s) is an estimate only: "
                       f"the curve is flat within its uncertainty at τ = {lo:.3g}-{hi:.3g} s, but too few clusters there to "
                       f"tell a floor from a bend (slope {b.slope:+.2f} ± {b.slope_u:.2f} at the minimum; ±½ not excluded "
                       "at 2σ); record longer to resolve it")
    if b.value is None and b.upper_bound is not None:
        out.append(f"{a}: bias instability not reported: {b.reason}; B < {b.customary(b.upper_bound):.4g} deg/h")
    missing = [f"{NAMES[t]} ({res.reading(t).reason})" for t in READ_TERMS
               if t != "bias_instability" and res.reading(t).value is None and res.reading(t).reason]
    if missing:
        out.append(f"{a}: not reported: " + "; ".join(missing))
    q = res.reading("quantization")
    if q.value is not None:
        out.append(f"{a}: quantization noise (−1 slope) dominates at short τ; it is read separately and not counted in "
                   "the ARW")
    if res.lsb_dps is not None:
        lsb = res.lsb_dps
        out.append(f"{a}: the output is quantised: {res.levels} distinct values on a grid of {lsb:.4g} deg/s "
                   "(output resolution, e.g. a digital register)")
        first = res.readout.allan  # the analysis grid starts at m = 1: σ(τ₀) is the sample-to-sample noise
        sigma = float(first.adev[0])
        if first.m[0] == 1 and sigma < lsb:
            out.append(f"{a}: output resolution {lsb:.4g} deg/s exceeds the sample-to-sample noise "
                       f"({sigma:.3g} deg/s): the output is quantization-limited and the ARW is not reliable")
        elif arw.value is not None:
            share = lsb ** 2 / 12.0 / (arw.value ** 2 * fs)
            if share > 0.02:
                corrected = res.arw_lsb_corrected_deg_per_sqrt_h
                out.append(f"{a}: output resolution {lsb:.4g} deg/s adds white noise LSB²/12 = {100 * share:.0f} % of the "
                           "white-noise variance; the sensor ARW without it is "
                           + (f"{corrected:.4g} deg/√h" if corrected is not None else "not resolvable"))
    return out


def _adev_table(per_axis: dict[str, AxisNoise], confidence: float) -> ResultTable:
    axes = list(per_axis)
    ref = per_axis[axes[0]].allan
    headers = ["τ (s)", "terms"]
    for a in axes:
        headers += [f"σ_{a} (deg/s)", f"{a} {100 * confidence:.0f} % low", f"{a} high", f"{a} slope"]
    rows = []
    for k in range(ref.taus_s.size):
        row: list[Any] = [_sig(ref.taus_s[k]), int(ref.n_terms[k])]
        for a in axes:
            al = per_axis[a].allan
            s = per_axis[a].slope[k]
            row += [_sig(al.adev[k]), _sig(al.adev_lo[k]), _sig(al.adev_hi[k]),
                    f"{s:+.2f}" if math.isfinite(s) else "-"]
        rows.append(row)
    return ResultTable("Overlapping Allan deviation (chi-squared intervals, edf for the noise type of the local slope)",
                       headers, rows)


def _sig(v: float, digits: int = 4) -> float:
    return float(f"{float(v):.{digits}g}")


# ---- moving average (ESTCube-2) -----------------------------------------------------------------
def moving_average_std(rate: np.ndarray, buffer_lengths: Sequence[int]) -> tuple[np.ndarray, np.ndarray, float]:
    """Sample standard deviation (ddof = 1, deg/s) of the N-sample moving average of ``rate`` for
    each N (only outputs with a full buffer, as with ESTCube-2's pre-filled buffer), the number of
    outputs, and the raw standard deviation σ₁ (N = 1)."""
    y = np.asarray(rate, dtype=float)
    y = y - y.mean()
    c = np.concatenate([[0.0], np.cumsum(y)])
    stds, counts = [], []
    for nb in buffer_lengths:
        ma = (c[nb:] - c[:-nb]) / nb
        stds.append(float(np.std(ma, ddof=1)))
        counts.append(ma.size)
    return np.array(stds), np.array(counts), float(np.std(y, ddof=1))


def calibrate_moving_average(ds: Dataset, buffer_lengths: Sequence[int] | str = DEFAULT_BUFFER_LENGTHS, *,
                             skip_s: float = 0.0, axes: Sequence[str] | str | None = None,
                             window: str | None = "auto", **opts: Any) -> CalibrationResult:
    """Method ``moving-average``: standard deviation of the moving-averaged static output versus
    the buffer length N (ESTCube-2 3.3, 4.1), per gyro axis, with the white-noise line σ₁/√N.

    Two sources of the averaged output:

    * ``"software"``: the N-sample boxcar applied here to the static stretch (see
      :func:`static_data`) for each N in ``buffer_lengths``; lengths longer than the stretch minus one
      sample are left out (with a note);
    * ``"board"``: a run of ``procedures/moving_average_sweep.yaml`` recorded windows ``N1``, ``N2``, …
      with the board's own moving average set to N; with ``window="auto"`` (default) those windows are
      used as they are (the std of each window's samples) and ``buffer_lengths`` is not applied.

    JSON: ``{"axes": {"x": {"n": [...], "std_dps": [...], "white_noise_std_dps": [...], "outputs": [...]}},
    "sample_rate_hz": f, "static_samples": n, "mode": "software" | "board"}``.
    """
    _check_options("moving-average", opts)
    raw = _numbers(buffer_lengths, "buffer_lengths")
    assert raw is not None
    if any(v != int(v) for v in raw):
        raise InputError(f"buffer_lengths must be whole numbers of samples, got {buffer_lengths!r}")
    lengths = sorted({int(v) for v in raw})
    use_axes = _axes(ds, axes)
    board = _board_windows(ds) if window == "auto" else {}
    notes: list[str] = []
    out_axes: dict[str, Any] = {}
    cols: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    if board:
        usable = sorted(board)
        fs = ds.sample_rate_hz
        t = np.asarray(ds["time_s"], dtype=float)
        masks = [(t > board[k][0]) & (t <= board[k][1]) for k in usable]
        counts = np.array([int(np.count_nonzero(m)) for m in masks])
        if np.any(counts < 2):
            bad = [f"N{k}" for k, c in zip(usable, counts) if c < 2]
            raise InputError(f"{ds.source}: recording window(s) {', '.join(bad)} hold fewer than 2 samples")
        notes.append(f"board moving average: used the run's {len(usable)} recording windows N{usable[0]}-N{usable[-1]} "
                     "(the board averaged; buffer_lengths not applied)")
        n_static = int(counts.sum())
        for a in use_axes:
            v = np.asarray(ds[GYRO[a]], dtype=float)
            std = np.array([float(np.std(v[m], ddof=1)) for m in masks])
            white = std[0] * np.sqrt(usable[0] / np.array(usable, dtype=float))
            cols[a] = (std, white)
            out_axes[a] = {"n": list(usable), "std_dps": std.tolist(), "white_noise_std_dps": white.tolist(),
                           "outputs": counts.tolist()}
        mode = "board"
    else:
        sd = static_data(ds, float(skip_s), axes, window)
        notes.extend(sd.notes)
        fs = sd.fs
        n_static = len(sd.ds)
        usable = [v for v in lengths if v <= n_static - 1]
        if len(usable) < len(lengths):
            notes.append(f"buffer lengths {', '.join(str(v) for v in lengths if v > n_static - 1)} exceed the "
                         f"{n_static}-sample static stretch and were left out")
        if not usable:
            raise InputError(f"{ds.source or 'dataset'}: no buffer length fits the {n_static}-sample static stretch")
        for a in use_axes:
            std, counts, s1 = moving_average_std(sd.ds[GYRO[a]], usable)
            white = s1 / np.sqrt(np.array(usable, dtype=float))
            cols[a] = (std, white)
            out_axes[a] = {"n": list(usable), "std_dps": std.tolist(), "white_noise_std_dps": white.tolist(),
                           "outputs": counts.tolist()}
        mode = "software"
    for a in use_axes:
        std, white = cols[a]
        over = [nb for nb, sv, wv in zip(usable, std, white) if wv > 0 and sv > 1.2 * wv]
        if over:
            notes.append(f"{a}: from N = {over[0]} the std is more than 20 % above the white-noise line: correlated "
                         "noise (drift, bias instability, filtering) limits what a longer buffer gains")
    headers = ["N"]
    for a in use_axes:
        headers += [f"std {a} (deg/s)", f"{a} white σ₁/√N (deg/s)"]
    rows = [[nb] + [_sig(v) for a in use_axes for v in (cols[a][0][k], cols[a][1][k])] for k, nb in enumerate(usable)]
    how = "board moving average, one window per N" if mode == "board" else "moving average applied to the static stretch"
    tables = [ResultTable(f"Moving-average buffer length vs output noise from {ds.source or 'dataset'} "
                          f"({how}; {n_static} samples at {fs:g} Hz)", headers, rows)]
    payload = {"axes": out_axes, "sample_rate_hz": float(fs), "static_samples": n_static, "mode": mode}
    return CalibrationResult("moving-average", payload, tables, None, notes)


_BOARD_WINDOW = re.compile(r"^N(\d+)$")


def _board_windows(ds: Dataset) -> dict[int, tuple[float, float]]:
    """Windows ``N<k>`` of a moving-average sweep run: buffer length k -> (start, end) run time (s)."""
    out: dict[int, tuple[float, float]] = {}
    for name, span in run_windows(ds).items():
        m = _BOARD_WINDOW.match(name)
        if m and int(m.group(1)) >= 1:
            out[int(m.group(1))] = span
    return out
