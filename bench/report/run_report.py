"""``bench report RUN.h5 -o report.html``: one self-contained HTML page per run, with inline PNG
figures, that a technician attaches to an acceptance record (``docs/report.md``).

Sections (a section whose data the run lacks shows a one-line note instead):

1. summary (procedure, status with abort reason, mode, operator, host, software, times, checks),
2. instruments and recorded streams, 3. steps with outcomes, 4. temperature and pressure,
5. rates, 6. bias vs temperature (``bench.analysis.thermal_cal``), 7. rate transfer
(``bench.analysis.rate_transfer``), 8. Allan deviation (``bench.analysis.noise_cal``),
9. pre/post comparison (checks with a ``reference``, e.g. pre/post-vibe functional tests),
10. calibration tables, 11. pass/fail checks.

The analyses of sections 6-8 are optional: a method that is not installed (``ImportError``) or does
not apply to the run (:class:`~bench.errors.InputError`) becomes a note; any other exception
propagates. An unreadable run file raises :class:`InputError` (exit code 2).

Units: run times in s since the start of the run, rates in deg/s, temperatures in °C, pressure in
Torr; scale-factor errors are shown in %.
"""

from __future__ import annotations

import fnmatch
import importlib
import json
import math
import re
import warnings
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

import numpy as np

from bench import __version__
from bench.analysis.result import CalibrationResult
from bench.errors import InputError
from bench.record import layout
from bench.record.reader import RunSummary, read_run_summary, read_stream
from bench.report import figures as F
from bench.report.html import Cell, esc, figure_png, fmt, page, table

ANALYSES: dict[str, tuple[str, str]] = {
    "thermal": ("bench.analysis.thermal_cal", "thermal calibration"),
    "rate_transfer": ("bench.analysis.rate_transfer", "rate-transfer calibration"),
    "noise": ("bench.analysis.noise_cal", "noise calibration (Allan deviation)"),
}
"""Report key → (module with ``calibrate(ds) -> CalibrationResult``, what it is called in notes)."""

BOARD = "acs_board"
CHAMBER_MONITOR = layout.monitor_key("tvac")
THERMOCOUPLE_MONITOR = layout.monitor_key("thermocouples")
TABLE_MONITOR = layout.monitor_key("rate_table")
AXES = ("x", "y", "z")
BOARD_TEMP_LABELS = ("board temp: gyro die", "board temp: accel die", "board temp: board")
"""Labels of the ACS board's three temperature channels (docs/run-file.md)."""
ZERO_RATE_DPS = 1e-9
"""A reference rate at most this large (deg/s) counts as zero (thermal fit samples)."""

_WINDOW_RE = re.compile(r"rows in window '(?P<name>.*)'$")
_RATE_SUFFIX = re.compile(r"(?P<rate>[+-](?:\d+\.?\d*|\.\d+)(?:e[+-]?\d+)?)$")
_OUTCOME_CLASS = {"passed": "pass", "done": "pass", "completed": "pass", "failed": "fail", "aborted": "fail",
                  "crashed": "fail", "interrupted": "warn", "running": "warn"}


# ---- public API -----------------------------------------------------------------------------------
def write_report(run_path: str | Path, out_path: str | Path) -> Path:
    """Write the report of ``run_path`` to ``out_path`` (UTF-8 HTML); returns ``out_path``.
    :class:`InputError` for an unreadable run file or an unwritable destination."""
    text = build_report(run_path)
    out = Path(out_path)
    try:
        out.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise InputError(f"{out}: cannot write the report: {exc.strerror or exc}") from None
    return out


def build_report(run_path: str | Path) -> str:
    """The whole report of the run file ``run_path`` as one HTML document (figures inlined)."""
    path = Path(run_path)
    summary = read_run_summary(path)
    data = load_run_data(path, summary)
    ds, ds_note = _load_dataset(path, summary)
    results = {key: run_analysis(module, ds, ds_note, what) for key, (module, what) in ANALYSES.items()}

    def analysis(key: str, render: Callable[[CalibrationResult], str]) -> str:
        res = results[key]
        return render(res) if isinstance(res, CalibrationResult) else note(res)

    sections = [
        ("1. Summary", section_summary(summary)),
        ("2. Instruments", section_instruments(summary)),
        ("3. Steps", section_steps(summary)),
        ("4. Temperature and pressure", section_environment(data)),
        ("5. Rates", section_rates(data)),
        ("6. Bias vs temperature", analysis("thermal", lambda r: section_thermal(r.json, ds))),
        ("7. Rate transfer", analysis("rate_transfer", lambda r: section_rate_transfer(r.json))),
        ("8. Allan deviation", analysis("noise", lambda r: section_allan(r.json))),
        ("9. Pre/post comparison", section_pre_post(summary, data)),
        ("10. Calibration tables", section_tables(results)),
        ("11. Pass/fail checks", section_checks(summary)),
    ]
    name = str(summary.attrs.get(layout.ATTR_PROCEDURE_NAME, "")) or path.stem
    generated = datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    return page(f"Run report: {name}", sections, subtitle=f"{path.name}; report generated {generated} by bench {__version__}")


def run_analysis(module: str, ds: Any, ds_note: str, what: str = "") -> CalibrationResult | str:
    """``module.calibrate(ds)``, or a one-line note why it is absent: no dataset (``ds_note``), the
    module cannot be imported, or it raised :class:`InputError` (the run lacks what it needs).
    Every other exception propagates."""
    what = what or module
    if ds is None:
        return f"No {what}: {ds_note}"
    try:
        mod = importlib.import_module(module)
        return mod.calibrate(ds)
    except ImportError as exc:
        return f"No {what}: {module} is not available ({exc})."
    except InputError as exc:
        return f"No {what}: {exc}"


def note(text: str) -> str:
    """A one-line note paragraph (why a section is empty, remarks)."""
    return f'<p class="note">{esc(text)}</p>'


# ---- data ---------------------------------------------------------------------------------------
@dataclass
class Window:
    """A recording window (from its record step): ``name``, run-time span ``t0``..``t1`` (s), the
    commanded rate parsed from the name (deg/s, ``None`` for zero references and others) and the
    mean board gyro output over the span (deg/s per axis, ``None`` without board data)."""

    name: str
    t0: float
    t1: float
    rate_dps: float | None = None
    gyro_mean_dps: np.ndarray | None = None


@dataclass
class RunData:
    """What the time-series sections plot, already reduced (:func:`figures.envelope`)."""

    temperatures: list[F.Series] = field(default_factory=list)
    pressure: F.Series | None = None
    gyro: list[F.Series] = field(default_factory=list)
    reference: list[F.Series] = field(default_factory=list)
    windows: list[Window] = field(default_factory=list)


def load_run_data(path: Path, summary: RunSummary) -> RunData:
    """Read the monitors and the board stream of the run and reduce them for plotting; window means
    are computed from the full-rate board data first."""
    streams = {s.key: s for s in summary.streams}
    data = RunData()

    def series(label: str, t: np.ndarray, y: np.ndarray) -> F.Series:
        return F.Series(label, *F.envelope(*F.break_gaps(t, y)))

    if CHAMBER_MONITOR in streams and streams[CHAMBER_MONITOR].rows:
        mon = read_stream(path, CHAMBER_MONITOR)
        for col, label in (("air_temp", "chamber air"), ("mount_temp", "chamber mount")):
            if col in mon:
                data.temperatures.append(series(label, mon["time"], mon[col]))
        if "pressure" in mon:
            data.pressure = series("chamber pressure", mon["time"], mon["pressure"])
    if THERMOCOUPLE_MONITOR in streams and streams[THERMOCOUPLE_MONITOR].rows:
        mon = read_stream(path, THERMOCOUPLE_MONITOR)
        for col in (c for c in mon if c != "time"):
            data.temperatures.append(series(f"thermocouple {col}", mon["time"], mon[col]))
    if BOARD in streams and streams[BOARD].rows:
        board = read_stream(path, BOARD)
        t = np.asarray(board["time"], dtype=float)
        if "temp" in board:
            temp = np.asarray(board["temp"], dtype=float).reshape(t.size, -1)
            for k in range(temp.shape[1]):
                label = BOARD_TEMP_LABELS[k] if k < len(BOARD_TEMP_LABELS) else f"board temp {k}"
                data.temperatures.append(series(label, t, temp[:, k]))
        if "gyro" in board:
            gyro = np.asarray(board["gyro"], dtype=float).reshape(t.size, -1)
            for k in range(min(gyro.shape[1], 3)):
                data.gyro.append(series(f"gyro {AXES[k]}", t, gyro[:, k]))
        else:
            gyro = None
        data.windows = _windows(summary, t, gyro)
        del board
    else:
        data.windows = _windows(summary, np.zeros(0), None)
    if TABLE_MONITOR in streams and streams[TABLE_MONITOR].rows:
        mon = read_stream(path, TABLE_MONITOR)
        if "rate" in mon:
            data.reference.append(series("rate table rate", mon["time"], mon["rate"]))
    for key in streams:
        if key.startswith("stepper_bench") and streams[key].rows:
            mon = read_stream(path, key)
            if "angle" in mon and mon["time"].size > 1:
                t = np.asarray(mon["time"], dtype=float)
                angle = np.unwrap(np.asarray(mon["angle"], dtype=float), period=360.0)
                ok = np.concatenate([[True], np.diff(t) > 0])
                if ok.sum() > 1:
                    data.reference.append(series("stepper bench rate (from angle)", t[ok], np.gradient(angle[ok], t[ok])))
    return data


def _windows(summary: RunSummary, t: np.ndarray, gyro: np.ndarray | None) -> list[Window]:
    """Recording windows named by record steps (``... rows in window 'NAME'``) with their means."""
    out = []
    for s in summary.steps:
        m = _WINDOW_RE.search(s.detail)
        if not m or s.t_start_s is None or s.t_end_s is None:
            continue
        w = Window(m.group("name"), float(s.t_start_s), float(s.t_end_s))
        r = _RATE_SUFFIX.search(w.name)
        if r:
            try:
                w.rate_dps = float(r.group("rate"))
            except ValueError:
                pass
        if gyro is not None and t.size:
            i0, i1 = np.searchsorted(t, [w.t0, w.t1], side="left")
            if i1 > i0:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN axis gives NaN: skipped later
                    w.gyro_mean_dps = np.nanmean(gyro[i0:i1], axis=0)
        out.append(w)
    return out


def _load_dataset(path: Path, summary: RunSummary) -> tuple[Any, str]:
    """The analysis dataset of the run, or ``(None, why not)``."""
    if not any(s.key == BOARD and s.rows for s in summary.streams):
        return None, "the run has no ACS board data (the analyses need the sensor outputs)."
    from bench.analysis.dataset import load_dataset

    try:
        return load_dataset(path), ""
    except InputError as exc:
        return None, str(exc)


# ---- formatting helpers ---------------------------------------------------------------------------
def hms(seconds: float | None) -> str:
    """``seconds`` (s) as ``H:MM:SS``, or ``S.s s`` under a minute; ``-`` for None or NaN."""
    if seconds is None or not math.isfinite(seconds):
        return "-"
    if abs(seconds) < 60:
        return f"{seconds:.1f} s"
    s = int(round(seconds))
    return f"{'-' if s < 0 else ''}{abs(s) // 3600}:{abs(s) // 60 % 60:02d}:{abs(s) % 60:02d}"


def _outcome(text: str) -> Cell:
    return Cell(text, _OUTCOME_CLASS.get(text.lower(), ""))


def _run_time_s(summary: RunSummary) -> float | None:
    times = [e.t_s for e in summary.events if math.isfinite(e.t_s)]
    times += [s.t_end_s for s in summary.steps if s.t_end_s is not None]
    times += [s.t_end_s for s in summary.streams if s.t_end_s is not None]
    if summary.heartbeat_run_time_s is not None and math.isfinite(summary.heartbeat_run_time_s):
        times.append(summary.heartbeat_run_time_s)
    return max(times) if times else None


def _procedure_info(summary: RunSummary) -> dict[str, Any]:
    """The ``procedure`` event's data: parameters in force, clock (virtual/wall), ..."""
    for e in summary.events:
        if e.kind == "procedure" and e.data:
            try:
                info = json.loads(e.data.decode("utf-8"))
            except (UnicodeDecodeError, json.JSONDecodeError):
                return {}
            return info if isinstance(info, dict) else {}
    return {}


def _utc(text: str) -> datetime | None:
    try:
        return datetime.strptime(text, "%Y-%m-%dT%H:%M:%SZ").replace(tzinfo=timezone.utc)
    except (TypeError, ValueError):
        return None


def _procedure_title(text: str) -> str:
    import yaml

    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError:
        return ""
    return str(doc.get("title") or "") if isinstance(doc, dict) else ""


# ---- 1-3: summary, instruments, steps -------------------------------------------------------------
def section_summary(summary: RunSummary) -> str:
    """Procedure, status (coloured, with the abort reason), mode, operator, host, software, start/end
    UTC, duration (run time; wall time too when the clock was virtual), run file, check counts."""
    a = summary.attrs
    info = _procedure_info(summary)
    status = summary.status.upper()
    title = _procedure_title(summary.procedure_text)
    rows: list[list[Any]] = [
        ["procedure", f"{a.get(layout.ATTR_PROCEDURE_NAME, '')}" + (f": {title}" if title else "")],
        ["procedure file", str(a.get(layout.ATTR_PROCEDURE_PATH, ""))],
        ["status", Cell(status + (f": {summary.status_detail}" if summary.status_detail else ""), _OUTCOME_CLASS.get(summary.status, "warn"))],
    ]
    if summary.abort_reason:
        rows.append(["abort reason", Cell(summary.abort_reason, "fail")])
    for w in summary.warnings:
        rows.append(["warning", Cell(w, "warn")])
    mode = str(a.get(layout.ATTR_MODE, ""))
    rows += [
        ["mode", {layout.MODE_SIM: "sim (dry-run, simulated instruments)", layout.MODE_HARDWARE: "hardware",
                  layout.MODE_REPLAY: "replay"}.get(mode, mode)],
        ["operator", str(a.get(layout.ATTR_OPERATOR, ""))],
        ["host", str(a.get(layout.ATTR_HOST, ""))],
        ["software", f"bench {a.get(layout.ATTR_SOFTWARE_VERSION, '')} (run-file format {a.get(layout.ATTR_FORMAT_VERSION, '')})"],
        ["lab config", str(a.get(layout.ATTR_CONFIG_PATH, ""))],
        ["started (UTC)", str(a.get(layout.ATTR_STARTED_UTC, ""))],
        ["ended (UTC)", str(a.get(layout.ATTR_ENDED_UTC, "")) or "-"],
    ]
    run_time = _run_time_s(summary)
    t0, t1 = _utc(str(a.get(layout.ATTR_STARTED_UTC, ""))), _utc(str(a.get(layout.ATTR_ENDED_UTC, "")))
    wall = (t1 - t0).total_seconds() if t0 and t1 else None
    clock = info.get("clock")
    if clock == "virtual" or mode == layout.MODE_SIM:
        duration = f"{hms(run_time)} run time (virtual clock); {hms(wall)} wall-clock"
    else:
        duration = hms(run_time if run_time is not None else wall)
    rows.append(["duration", duration])
    size = summary.path.stat().st_size if summary.path.exists() else 0
    rows.append(["run file", f"{summary.path.resolve()} ({size / 1e6:.1f} MB)"])
    checks = check_results(summary)
    counts = {k: sum(1 for c in checks if c.outcome == k) for k in ("passed", "failed")}
    other = [s for s in summary.steps if s.type != "check" and s.outcome in ("failed", "aborted", "interrupted")]
    verdict = f"{counts['passed']} passed, {counts['failed']} failed" if checks else "no checks in this run"
    rows.append(["checks", Cell(verdict, "fail" if counts["failed"] else ("pass" if checks else ""))])
    if other:
        rows.append(["other steps", Cell(", ".join(f"{s.index + 1} {s.name}: {s.outcome}" for s in other), "fail")])
    planned = info.get("steps")
    rows.append(["steps", f"{len(summary.steps)} of {planned} executed" if isinstance(planned, int) else f"{len(summary.steps)} executed"])
    out = table(["item", "value"], rows, left=2)
    params = info.get("parameters")
    if isinstance(params, dict) and params:
        out += table(["parameter", "value"], [[k, json.dumps(v) if not isinstance(v, str) else v] for k, v in params.items()],
                     title="Procedure parameters in force", left=2)
    return out


def section_instruments(summary: RunSummary) -> str:
    """Identity of every instrument (vendor, model, serial, firmware, the rest) and recorded streams."""
    if not summary.instruments:
        return note("No instruments recorded in this run file.")
    main = ("vendor", "model", "serial", "firmware")
    rows = []
    for name, ident in summary.instruments.items():
        rest = ", ".join(f"{k}={v}" for k, v in ident.items() if k not in main and v != "")
        rows.append([name, *(ident.get(k, "") for k in main), rest])
    out = table(["instrument", *main, "other identity"], rows, left=6)
    srows = []
    for s in summary.streams:
        span = f"{s.t_start_s:.1f} .. {s.t_end_s:.1f}" if s.t_start_s is not None and s.t_end_s is not None else "-"
        cols = ", ".join(f"{n}{list(s.shapes[n]) if s.shapes.get(n) else ''} ({u})" for n, u in s.columns.items())
        srows.append([s.key, cols, s.rows, span, s.rate_hz])
    if srows:
        out += table(["stream", "columns (units)", "rows", "run time span (s)", "mean rate (Hz)"], srows,
                     title="Recorded streams", left=2)
    return out


def section_steps(summary: RunSummary) -> str:
    """One row per executed step: number, name, type, start (run time), duration, outcome, message."""
    if not summary.steps:
        return note("No steps were executed.")
    rows = [[s.index + 1, s.name, s.type, hms(s.t_start_s), hms(s.duration_s), _outcome(s.outcome), s.detail] for s in summary.steps]
    body = table(["#", "step", "type", "start (run time)", "duration", "outcome", "message"], rows, left=7)
    return f'<div id="steps">{body}</div>'


# ---- 4-5: time series -----------------------------------------------------------------------------
def section_environment(data: RunData) -> str:
    """Chamber air/mount, thermocouple and board temperatures (°C) and pressure (Torr, log) vs time."""
    if not data.temperatures and data.pressure is None:
        return note("No temperature or pressure recorded in this run (no chamber, thermocouple or board stream).")
    return figure_png(F.fig_environment(data.temperatures, data.pressure),
                      "Temperatures (°C) and chamber pressure (Torr, log scale) vs run time; long series drawn as min/max envelopes.")


def section_rates(data: RunData) -> str:
    """Gyro outputs x/y/z (deg/s) and the table or bench rate (deg/s) vs time."""
    if not data.gyro and not data.reference:
        return note("No gyro output or table rate recorded in this run.")
    return figure_png(F.fig_rates(data.gyro, data.reference),
                      "Gyro outputs and reference rate (deg/s) vs run time; long series drawn as min/max envelopes.")


# ---- 6-8: analyses ----------------------------------------------------------------------------------
def _thermal_selection() -> tuple[float, float]:
    """(zero-rate tolerance in deg/s, warm-up in s) the thermal calibration uses, so the plot marks
    the same samples as fitted; defaults when the module is not available."""
    try:
        from bench.analysis import thermal_cal
    except ImportError:
        return ZERO_RATE_DPS, 0.0
    return float(getattr(thermal_cal, "RATE_TOL_DPS", ZERO_RATE_DPS)), float(getattr(thermal_cal, "WARMUP_S", 0.0))


def zero_rate_samples(ds: Any, rate_tol_dps: float = ZERO_RATE_DPS, warmup_s: float = 0.0
                      ) -> tuple[np.ndarray | None, dict[str, np.ndarray], np.ndarray | None]:
    """Temperatures (°C), gyro outputs (deg/s per axis) of the samples whose reference rates are all
    zero (|rate| ≤ ``rate_tol_dps``; every sample when the run has no reference rate), and which of
    them come ``warmup_s`` or more after power-on (``power_on_s``): the ones a thermal fit uses.
    ``(None, {}, None)`` without a dataset or a temperature column."""
    if ds is None or "temp_c" not in ds:
        return None, {}, None
    refs = [f"ref_rate_{a}_dps" for a in AXES if f"ref_rate_{a}_dps" in ds]
    mask = np.ones(len(ds), dtype=bool)
    for r in refs:
        mask &= np.abs(np.asarray(ds[r], dtype=float)) <= rate_tol_dps
    temp = np.asarray(ds["temp_c"], dtype=float)[mask]
    gyro = {a: np.asarray(ds[f"gyro_{a}_dps"], dtype=float)[mask] for a in AXES if f"gyro_{a}_dps" in ds}
    fitted = np.ones(temp.size, dtype=bool)
    if "power_on_s" in ds and warmup_s > 0:
        fitted = np.asarray(ds["power_on_s"], dtype=float)[mask] >= warmup_s
    return temp, gyro, fitted


def section_thermal(cal_json: dict[str, Any], ds: Any = None) -> str:
    """Zero-rate gyro output vs temperature per axis with the thermal calibration's bias polynomial
    (``axes.<a>.poly_degc``, ascending, deg/s vs °C) and residuals; ``ds`` supplies the samples."""
    axes = cal_json.get("axes") or {}
    axes = {a: v for a, v in axes.items() if isinstance(v, dict) and v.get("poly_degc") is not None}
    if not axes:
        return note("The thermal calibration returned no bias polynomial.")
    temp, gyro, fitted = zero_rate_samples(ds, *_thermal_selection())
    out = ""
    if temp is not None and temp.size == 0:
        out += note("No zero-rate samples in this run: only the fitted polynomials are drawn.")
        temp = None
    rows = []
    for a, v in axes.items():
        c = list(v["poly_degc"])
        se = list(v.get("poly_se") or [])
        terms = ", ".join(f"c{k} = {fmt(float(ck))}" + (f" ± {fmt(float(se[k]), 2)}" if k < len(se) and se[k] is not None else "")
                          for k, ck in enumerate(c))
        rng = v.get("temp_range_c")
        rows.append([a, terms, f"{rng[0]:.1f} … {rng[1]:.1f}" if rng and len(rng) == 2 else "", v.get("residual_rms_dps")])
    out += table(["axis", "bias polynomial b(T) = Σ cₖ Tᵏ (deg/s, T in °C)", "fit range (°C)", "residual RMS (deg/s)"], rows, left=2)
    out += figure_png(F.fig_thermal(axes, temp, gyro, fitted),
                      "Zero-rate gyro output vs sensor temperature (points: samples, grey: not fitted, black dots: bin means) "
                      "with the fitted bias polynomial over its fit range; below, residuals of the fitted samples.")
    return out


def section_rate_transfer(cal_json: dict[str, Any]) -> str:
    """Input/output and percent-error plots per axis from the rate-transfer calibration's steps,
    scale-factor error and bias per axis, and the matrix ``M`` when present."""
    axes = {a: v for a, v in (cal_json.get("axes") or {}).items() if isinstance(v, dict)}
    if not any(v.get("steps") for v in axes.values()):
        return note("The rate-transfer calibration returned no rate steps.")
    rows = [[a, 100 * F._num(v.get("scale_factor_error")), v.get("bias_dps"), len(v.get("steps") or [])] for a, v in axes.items()]
    out = table(["axis", "scale-factor error (%)", "bias (deg/s)", "rate steps"], rows)
    m = cal_json.get("M")
    if isinstance(m, list) and m and all(isinstance(r, list) for r in m):
        out += table(["M", *AXES[: len(m[0])]], [[AXES[i] if i < 3 else i, *r] for i, r in enumerate(m)],
                     title="Scale-factor / misalignment matrix M (output = M · input + bias)")
    out += figure_png(F.fig_rate_transfer(axes),
                      "Mean output vs commanded rate with the fitted line; below, output error vs |rate| against the zero-rate "
                      "reference and raw (filled: + rates, open: − rates).")
    out += _rate_transfer_residuals(axes, cal_json.get("common_mode"))
    return out


def _rate_transfer_residuals(axes: dict[str, Any], common: Any) -> str:
    """The steps off their axis' line (residual against the line fitted without the step's rate, σ,
    t) and the common-mode rates, when the calibration reports them (``off`` / ``common_mode``)."""
    tested = [v for v in axes.values() if any("off" in s for s in v.get("steps") or [])]
    if not tested:
        return ""
    rows = [[a, "0 (ref)" if s.get("rate_dps") is None else s.get("rate_dps"), s.get("deleted_residual_dps"), s.get("sigma_dps"),
             s.get("t")] for a, v in axes.items() for s in (v.get("steps") or []) + (v.get("references") or []) if s.get("off")]
    if rows:
        out = table(["axis", "rate (deg/s)", "off the line by (deg/s)", "σ (deg/s)", "t"], rows,
                    title="Steps off the line (externally studentised; Bonferroni 1 % per axis)")
    else:
        out = note("No step is off its axis' line (externally studentised residuals, Bonferroni 1 % per axis).")
    if isinstance(common, list) and common:
        out += table(["rate (deg/s)", "axis", "mean off the line by (deg/s)", "σ (deg/s)", "z"],
                     [[c.get("rate_dps"), a, v.get("deleted_residual_dps"), v.get("sigma_dps"), v.get("z")]
                      for c in common for a, v in (c.get("axes") or {}).items()],
                     title="Common-mode rates: off on every axis measured at the rate (a reference or table effect)")
    elif isinstance(common, list):
        out += note("No common-mode rate (none off on every axis measured at it).")
    return out


def section_allan(cal_json: dict[str, Any]) -> str:
    """Allan deviation per axis, log-log, with ARW (−½), bias-instability (0) and RRW (+½) lines."""
    axes = {a: v for a, v in (cal_json.get("axes") or {}).items() if isinstance(v, dict)}
    if not any(v.get("taus_s") for v in axes.values()):
        return note("The noise calibration returned no Allan deviation.")
    rows = [[a, v.get("arw_deg_per_sqrt_h"), v.get("bias_instability_deg_per_h"), v.get("rrw_deg_per_h_per_sqrt_h")]
            for a, v in axes.items()]
    out = table(["axis", "ARW (deg/√h)", "bias instability (deg/h)", "RRW (deg/h/√h)"], rows)
    out += figure_png(F.fig_allan(axes),
                      "Allan deviation vs cluster time τ with its confidence band and the noise terms: angle random walk "
                      "(slope −½), bias instability (flat, 0.664·B) and rate random walk (slope +½).")
    return out


# ---- 9: pre/post comparison -------------------------------------------------------------------------
@dataclass
class CheckResult:
    """One check of the run: from its ``check`` event (name, signal, statistic, window pattern,
    value, limits, reference check) and its step's outcome and message."""

    name: str
    step: int
    outcome: str
    signal: str = ""
    statistic: str = ""
    window: str = ""
    value: float | None = None
    minimum: float | None = None
    maximum: float | None = None
    reference: str | None = None
    basis: str = ""
    message: str = ""


def check_results(summary: RunSummary) -> list[CheckResult]:
    """Every check step (and built-in test) in step order, with what its event recorded."""
    data: dict[int, dict[str, Any]] = {}
    for e in summary.events:
        if e.kind == "check" and e.data:
            try:
                d = json.loads(e.data.decode("utf-8"))
            except (UnicodeDecodeError, json.JSONDecodeError):
                continue
            if isinstance(d, dict):
                data[e.step] = d
    out = []
    for s in summary.steps:
        if s.type not in ("check", "bit"):
            continue
        d = data.get(s.index, {})
        out.append(CheckResult(
            name=s.name, step=s.index, outcome=s.outcome, signal=str(d.get("signal", "")), statistic=str(d.get("statistic", s.type)),
            window=str(d.get("window", "")), value=_float(d.get("value")), minimum=_float(d.get("min")),
            maximum=_float(d.get("max")), reference=d.get("reference") or None, basis=str(d.get("basis", "")), message=s.detail,
        ))
    return out


def _float(v: Any) -> float | None:
    try:
        return None if v is None else float(v)
    except (TypeError, ValueError):
        return None


def signal_units(summary: RunSummary, signal: str) -> str:
    """Units of ``INSTRUMENT.COLUMN[.AXIS]`` from the run's stream columns, ``""`` if unknown."""
    parts = signal.split(".")
    if len(parts) < 2:
        return ""
    inst, col = parts[0], parts[1]
    for s in summary.streams:
        if (s.key == inst or s.key.startswith(inst + "/")) and col in s.columns:
            return s.columns[col]
    return ""


def display_value(statistic: str, value: float | None, units: str) -> tuple[float | None, str]:
    """A check value in display units: scale-factor errors in %, slopes per s, counts bare."""
    if statistic == "scale_factor_error":
        return (None if value is None else 100.0 * value), "%"
    if statistic == "slope":
        return value, f"{units}/s" if units else "1/s"
    if statistic in ("count", "bit"):
        return value, ""
    return value, units


def _stage(check: CheckResult) -> str:
    """Stage label of a check from its window pattern: ``post_z_x_*`` of signal ``...gyro.x`` →
    ``post_z``; ``pre_z_*`` → ``pre``; the check name when the pattern says nothing."""
    axis = check.signal.rsplit(".", 1)[-1] if check.signal.count(".") >= 2 else ""
    w = check.window.rstrip("*").rstrip("_")
    if axis and w.endswith(axis):
        w = w[: -len(axis)].rstrip("_")
    return w or check.name


def section_pre_post(summary: RunSummary, data: RunData | None = None) -> str:
    """Checks that compare with a reference check (pre/post-vibe functional tests): reference and
    later values, difference and outcome per check, values per stage, and the output error of every
    recording window per stage (from the board data, bias of the stage's fit removed)."""
    checks = check_results(summary)
    by_name = {c.name: c for c in checks}
    comps = [c for c in checks if c.reference]
    if not comps:
        return note("No checks in this run compare with a reference (no pre/post functional tests).")
    vib = [s for s in summary.steps if s.type == "vibrate"]
    out = note(f"{len(comps)} comparisons with earlier results; {len(vib)} vibration step(s) in the run." if vib
               else f"{len(comps)} comparisons with earlier results.")
    rows = []
    panels: dict[str, tuple[str, dict[str, list[F.StagePoint]]]] = {}
    for c in comps:
        ref = by_name.get(c.reference or "")
        units = signal_units(summary, c.signal)
        val, u = display_value(c.statistic, c.value, units)
        rval = display_value(c.statistic, ref.value if ref else None, units)[0]
        diff = None if val is None or rval is None else val - rval
        rows.append([c.name, c.signal, c.statistic, c.reference, rval, val, diff, u, _outcome(c.outcome)])
        if val is None:
            continue
        label, lines = panels.setdefault(c.statistic, (f"{c.statistic.replace('_', ' ')} ({u})" if u else c.statistic, {}))
        pts = lines.setdefault(c.signal, [])
        if ref is not None and rval is not None and not any(p.outcome is None for p in pts):
            pts.insert(0, F.StagePoint(_stage(ref), rval, None))
        pts.append(F.StagePoint(_stage(c), val, c.outcome))
    out += table(["check", "signal", "statistic", "reference check", "reference value", "value", "difference", "units", "outcome"],
                 rows, left=4)
    out += figure_png(F.fig_pre_post(panels), "Check values per stage (first point: the reference); red circles: change beyond tolerance.")
    errs = _stage_errors(comps, by_name, data)
    if errs:
        out += figure_png(F.fig_stage_errors(errs),
                          "Output error per recording window and stage (filled: + rates, open: − rates): (mean output − stage bias − rate) / rate, "
                          "stage bias from a straight-line fit over the stage's windows.")
    return out


def _stage_errors(comps: list[CheckResult], by_name: dict[str, CheckResult], data: RunData | None) -> dict[str, dict[str, tuple[np.ndarray, np.ndarray]]]:
    """Per board gyro signal and stage: (commanded rates, percent errors) of the windows the checks used."""
    if data is None or not data.windows:
        return {}
    out: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]] = {}
    for c in comps:
        for chk in (by_name.get(c.reference or ""), c):
            if chk is None or not chk.signal.startswith(f"{BOARD}.gyro.") or not chk.window:
                continue
            axis = chk.signal.rsplit(".", 1)[-1]
            if axis not in AXES:
                continue
            k = AXES.index(axis)
            stage = _stage(chk)
            if stage in out.get(chk.signal, {}):
                continue
            ws = [w for w in data.windows if fnmatch.fnmatchcase(w.name, chk.window) and w.gyro_mean_dps is not None
                  and w.rate_dps is not None and k < w.gyro_mean_dps.size]
            rates = np.array([w.rate_dps for w in ws], dtype=float)
            means = np.array([w.gyro_mean_dps[k] for w in ws], dtype=float)
            ok = np.isfinite(means)
            rates, means = rates[ok], means[ok]
            if np.unique(rates).size < 2:
                continue
            _, bias = np.polyfit(rates, means, 1)
            nz = rates != 0
            out.setdefault(chk.signal, {})[stage] = (rates[nz], 100.0 * (means[nz] - bias - rates[nz]) / rates[nz])
    return out


# ---- 10-11: tables and checks -------------------------------------------------------------------------
def section_tables(results: dict[str, CalibrationResult | str]) -> str:
    """Every :class:`~bench.analysis.result.ResultTable` (and note) of the analyses that ran."""
    out = ""
    for key, res in results.items():
        if not isinstance(res, CalibrationResult):
            continue
        what = ANALYSES.get(key, (key, key))[1]
        for t in res.tables:
            out += table(list(t.headers), t.rows, title=f"{what}: {t.title}")
        if res.notes:
            out += "<ul>" + "".join(f'<li class="note">{esc(what)}: {esc(n)}</li>' for n in res.notes) + "</ul>"
    return out or note("No calibration ran on this run (see sections 6-8 for why).")


def section_checks(summary: RunSummary) -> str:
    """Every check (and built-in test) with its value, limits, reference and outcome."""
    checks = check_results(summary)
    if not checks:
        return note("This run has no checks.")
    rows = []
    for c in checks:
        units = signal_units(summary, c.signal)
        val, u = display_value(c.statistic, c.value, units)
        lo = display_value(c.statistic, c.minimum, units)[0]
        hi = display_value(c.statistic, c.maximum, units)[0]
        rows.append([c.step + 1, c.name, _outcome(c.outcome), c.signal, c.statistic, c.window, c.reference or "",
                     val, lo, hi, u, Cell(c.message, "l")])
    n_fail = sum(1 for c in checks if c.outcome != "passed")
    head = Cell(f"{len(checks) - n_fail} of {len(checks)} checks passed", "fail" if n_fail else "pass")
    verdict = f'<p class="{head.cls}">{esc(head.value)}</p>'
    body = table(["#", "check", "outcome", "signal", "statistic", "window", "reference", "value", "min", "max", "units", "message"],
                 rows, left=7)
    return verdict + body
