"""``bench report RUN.h5 -o report.html``: one self-contained HTML page per run, with inline PNG
figures, that a technician attaches to an acceptance record (``docs/report.md``).

The page opens with the verdict (passed / failed / no verdict / incomplete) and the checks, then the
unit under test and the run, steps, instruments and streams, and the sections that apply to the run:
temperature and pressure, rates, bias vs temperature (``bench.analysis.thermal_cal``, only with a
temperature sweep), rate transfer (``bench.analysis.rate_transfer``, only with rate steps), noise
(``bench.analysis.noise_cal``, only over a static window, :mod:`bench.report.static`), pre/post
comparison (checks with a ``reference``) and the calibration tables. A section that does not apply
is left out and listed once at the end with the reason.

An analysis that applies but is not installed (``ImportError``) or finds the run lacking
(:class:`~bench.errors.InputError`) becomes a note in its section; any other exception propagates. An
unreadable run file raises :class:`InputError` (exit code 2).

Units: run times and durations as H:MM:SS (figure axes too), rates in deg/s, temperatures in °C,
pressure in Torr; scale-factor errors are shown in %.
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
from bench.record.checks import (CheckResult, check_results, display_value, procedure_info, run_verdict,  # noqa: F401 (re-exported)
                                 signal_units)
from bench.record.reader import RunSummary, read_run_summary, read_stream
from bench.report import figures as F
from bench.report import static as S
from bench.operators import describe as describe_operator
from bench.quantity_format import fmt_quantity, fmt_range
from bench.report.html import Cell, esc, figure_png, fmt, hms, page, table
from bench.run_mode import banner, is_evidence, mode_word
from bench.terminal_text import printable

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
TEMP_SWEEP_MIN_C = 5.0
"""Smallest span (°C) of the sensor temperature, over the samples the thermal fit uses, that counts
as a temperature sweep: ten times the 0.5 °C a stable temperature may wander
(:data:`bench.report.static.TEMP_DRIFT_MAX_C`). Over less, a cubic bias polynomial is not determined
(its coefficients come out larger than their standard errors allow to read)."""
MAX_WINDOW_ROWS = 40
"""Most recording windows listed in the noise section's window table (the rest are counted)."""

_WINDOW_RE = re.compile(r"rows in window '(?P<name>.*)'$")
_RATE_SUFFIX = re.compile(r"(?P<rate>[+-](?:\d+\.?\d*|\.\d+)(?:e[+-]?\d+)?)$")
_OUTCOME_CLASS = {"passed": "pass", "done": "pass", "completed": "pass", "failed": "fail", "aborted": "fail",
                  "crashed": "fail", "interrupted": "warn", "running": "warn", "recorded": ""}
NO_VERDICT = layout.OUTCOME_RECORDED
"""Outcome of a check without limits (and without a reference): its value is recorded, it gives no
verdict. Runners before this outcome existed wrote ``passed``; the report shows those as recorded too."""
_VERDICT_CLASS = {"PASSED": "pass", "FAILED": "fail", "INCOMPLETE": "warn", "NO VERDICT": "warn"}


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


@dataclass
class Section:
    """One section of the report: ``title``, and its ``html`` when it applies to the run, else
    ``why`` it does not (then it is only listed under "Not applicable")."""

    title: str
    html: str = ""
    why: str = ""


def build_report(run_path: str | Path) -> str:
    """The whole report of the run file ``run_path`` as one HTML document (figures inlined)."""
    path = Path(run_path)
    summary = read_run_summary(path)
    data = load_run_data(path, summary)
    ds, ds_note = _load_dataset(path, summary)
    sections = report_sections(summary, data, ds, ds_note)
    shown = [(f"{i}. {s.title}", s.html) for i, s in enumerate((s for s in sections if not s.why), start=1)]
    omitted = [s for s in sections if s.why]
    if omitted:
        shown.append(("Not applicable to this run", section_not_applicable(omitted)))
    name = str(summary.attrs.get(layout.ATTR_PROCEDURE_NAME, "")) or path.stem
    generated = datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    mode = str(summary.attrs.get(layout.ATTR_MODE, ""))
    title = f"Run report: {name}" + ("" if is_evidence(mode) else f" ({mode_word(mode)})")
    return page(title, shown, subtitle=f"{printable(path.name)}; report generated {generated} by bench {__version__}",
                banner=banner(mode), watermark="" if is_evidence(mode) else mode_word(mode))


def report_sections(summary: RunSummary, data: "RunData", ds: Any, ds_note: str) -> list[Section]:
    """Every section in report order, each rendered only when it applies (analyses run only then)."""
    checks = check_results(summary)
    results: dict[str, CalibrationResult | str] = {}

    def analysis(key: str, data_set: Any, render: Callable[[CalibrationResult], str]) -> str:
        module, what = ANALYSES[key]
        res = results[key] = run_analysis(module, data_set, ds_note, what)
        return render(res) if isinstance(res, CalibrationResult) else note(res)

    def section(title: str, why: str, render: Callable[[], str]) -> Section:
        return Section(title, why=why) if why else Section(title, render())

    board_why = "" if ds is not None else ds_note
    out = [
        Section("Verdict and checks", section_verdict(summary, checks)),
        Section("Unit under test and run", section_summary(summary)),
        section("Steps", "" if summary.steps else "no steps were executed.", lambda: section_steps(summary, checks)),
        section("Instruments and streams", "" if summary.instruments or summary.streams else "no instruments or streams recorded.",
                lambda: section_instruments(summary)),
        section("Temperature and pressure", "" if data.temperatures or data.pressure is not None else
                "no temperature or pressure recorded (no chamber, thermocouple or board stream).", lambda: section_environment(data)),
        section("Rates", "" if data.gyro or data.reference else "no gyro output or table rate recorded.", lambda: section_rates(data)),
        section("Bias vs temperature", board_why or why_no_sweep(ds),
                lambda: analysis("thermal", ds, lambda r: section_thermal(r.json, ds))),
        section("Rate transfer", board_why or why_no_rate_steps(data),
                lambda: analysis("rate_transfer", ds, lambda r: section_rate_transfer(r.json))),
        section("Noise (Allan deviation)", board_why, lambda: section_noise(data.window_checks, ds, analysis)),
        section("Pre/post comparison", "" if any(c.reference for c in checks) else
                "no check compares with a reference (no pre/post functional tests).", lambda: section_pre_post(summary, data)),
    ]
    ran = {k: r for k, r in results.items() if isinstance(r, CalibrationResult) and (r.tables or r.notes)}
    out.append(section("Calibration tables", "" if ran else "no analysis ran on this run, or none returned a table.",
                       lambda: section_tables(ran)))
    return out


def section_not_applicable(omitted: list[Section]) -> str:
    """The sections left out, one line each: "<section>: not applicable: <why>"."""
    items = "".join(f'<li class="note">{esc(s.title)}: not applicable: {esc(s.why)}</li>' for s in omitted)
    return f'<ul id="not-applicable">{items}</ul>'


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
    """A recording window of the board: ``name`` (a record step's window, else ``step N (name)`` for
    another step that recorded, e.g. ``wait_until_stable`` with ``record``), run-time span
    ``t0``..``t1`` (s), the commanded rate parsed from the name (deg/s, ``None`` for zero references
    and others), the mean board gyro output over the span (deg/s per axis, ``None`` without board
    data), the board ``samples`` in it and the ``step_type`` that recorded it."""

    name: str
    t0: float
    t1: float
    rate_dps: float | None = None
    gyro_mean_dps: np.ndarray | None = None
    samples: int = 0
    step_type: str = "record"


@dataclass
class RunData:
    """What the time-series sections plot, already reduced (:func:`figures.envelope`), the recording
    windows and whether each is static (:mod:`bench.report.static`)."""

    temperatures: list[F.Series] = field(default_factory=list)
    pressure: F.Series | None = None
    gyro: list[F.Series] = field(default_factory=list)
    reference: list[F.Series] = field(default_factory=list)
    windows: list[Window] = field(default_factory=list)
    window_checks: list[S.WindowCheck] = field(default_factory=list)


def load_run_data(path: Path, summary: RunSummary) -> RunData:
    """Read the monitors and the board stream of the run and reduce them for plotting; window means
    and the static test of every window are computed from the full-rate data first."""
    streams = {s.key: s for s in summary.streams}
    data = RunData()
    temps: list[S.Trace] = []  # temperatures that make a window not static (°C)
    rates: list[S.Trace] = []  # table rates (deg/s)
    angles: list[S.Trace] = []  # table tilt and bench angle (deg)

    def series(label: str, t: np.ndarray, y: np.ndarray) -> F.Series:
        return F.Series(label, *F.envelope(*F.break_gaps(t, y)))

    if CHAMBER_MONITOR in streams and streams[CHAMBER_MONITOR].rows:
        mon = read_stream(path, CHAMBER_MONITOR)
        for col, label in (("air_temp", "chamber air"), ("mount_temp", "chamber mount")):
            if col in mon:
                data.temperatures.append(series(label, mon["time"], mon[col]))
        if "air_temp" in mon:
            temps.append(S.Trace("chamber air temperature", np.asarray(mon["time"], float), np.asarray(mon["air_temp"], float)))
        if "pressure" in mon:
            data.pressure = series("chamber pressure", mon["time"], mon["pressure"])
    if THERMOCOUPLE_MONITOR in streams and streams[THERMOCOUPLE_MONITOR].rows:
        mon = read_stream(path, THERMOCOUPLE_MONITOR)
        for col in (c for c in mon if c != "time"):
            data.temperatures.append(series(f"thermocouple {col}", mon["time"], mon[col]))
    if TABLE_MONITOR in streams and streams[TABLE_MONITOR].rows:
        mon = read_stream(path, TABLE_MONITOR)
        tm = np.asarray(mon["time"], dtype=float)
        if "rate" in mon:
            data.reference.append(series("rate table rate", tm, mon["rate"]))
            rates.append(S.Trace("rate table", tm, np.asarray(mon["rate"], dtype=float)))
        if "tilt" in mon:
            angles.append(S.Trace("rate table tilt", tm, np.asarray(mon["tilt"], dtype=float)))
    for key in streams:
        if key.startswith("stepper_bench") and streams[key].rows:
            mon = read_stream(path, key)
            if "angle" in mon and mon["time"].size > 1:
                t = np.asarray(mon["time"], dtype=float)
                angle = np.unwrap(np.asarray(mon["angle"], dtype=float), period=360.0)
                angles.append(S.Trace("stepper bench", t, angle))
                ok = np.concatenate([[True], np.diff(t) > 0])
                if ok.sum() > 1:
                    data.reference.append(series("stepper bench rate (from angle)", t[ok], np.gradient(angle[ok], t[ok])))
    t = np.zeros(0)
    gyro = None
    if BOARD in streams and streams[BOARD].rows:
        board = read_stream(path, BOARD)
        t = np.asarray(board["time"], dtype=float)
        if "temp" in board:
            temp = np.asarray(board["temp"], dtype=float).reshape(t.size, -1)
            for k in range(temp.shape[1]):
                label = BOARD_TEMP_LABELS[k] if k < len(BOARD_TEMP_LABELS) else f"board temp {k}"
                data.temperatures.append(series(label, t, temp[:, k]))
            temps.insert(0, S.Trace("sensor temperature", t, temp[:, 0].copy()))
        if "gyro" in board:
            gyro = np.asarray(board["gyro"], dtype=float).reshape(t.size, -1)
            for k in range(min(gyro.shape[1], 3)):
                data.gyro.append(series(f"gyro {AXES[k]}", t, gyro[:, k]))
        del board
    data.windows = _windows(summary, t, gyro)
    data.window_checks = [S.check_window(w.name, w.t0, w.t1, w.samples, commanded_rate_dps=w.rate_dps, step_type=w.step_type,
                                         rates=rates, angles=angles, temperatures=temps) for w in data.windows]
    return data


def _windows(summary: RunSummary, t: np.ndarray, gyro: np.ndarray | None) -> list[Window]:
    """Recording windows with their board samples (``t0 < t <= t1``) and means: the windows named by
    record steps (``... rows in window 'NAME'``), other steps during which the board recorded (named
    ``step N (name)``), and, for a board recording without any such window, the whole recording."""
    out = []
    for s in summary.steps:
        if s.t_start_s is None or s.t_end_s is None:
            continue
        m = _WINDOW_RE.search(s.detail)
        w = Window(m.group("name") if m else f"step {s.index + 1} ({s.name})", float(s.t_start_s), float(s.t_end_s),
                   step_type=s.type or "record")
        i0, i1 = np.searchsorted(t, [w.t0, w.t1], side="right")
        w.samples = int(i1 - i0)
        if not m and (w.samples == 0 or w.t1 <= w.t0):
            continue  # a step that did not record
        r = _RATE_SUFFIX.search(w.name) if m else None
        if r:
            try:
                w.rate_dps = float(r.group("rate"))
            except ValueError:
                pass
        if gyro is not None and i1 > i0:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN axis gives NaN: skipped later
                w.gyro_mean_dps = np.nanmean(gyro[i0:i1], axis=0)
        out.append(w)
    if not out and t.size > 1:
        w = Window("the whole recording", float(t[0]) - 1e-9, float(t[-1]), samples=int(t.size), step_type="")
        if gyro is not None:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                w.gyro_mean_dps = np.nanmean(gyro, axis=0)
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
def _outcome(text: str) -> Cell:
    return Cell(text, _OUTCOME_CLASS.get(text.lower(), ""))


def _run_time_s(summary: RunSummary) -> float | None:
    times = [e.t_s for e in summary.events if math.isfinite(e.t_s)]
    times += [s.t_end_s for s in summary.steps if s.t_end_s is not None]
    times += [s.t_end_s for s in summary.streams if s.t_end_s is not None]
    if summary.heartbeat_run_time_s is not None and math.isfinite(summary.heartbeat_run_time_s):
        times.append(summary.heartbeat_run_time_s)
    return max(times) if times else None


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


# ---- verdict, unit and run, steps, instruments ---------------------------------------------------
IDENTITY_LABELS = {layout.ATTR_UNIT_SERIAL: "unit serial", layout.ATTR_UNIT_PART: "unit part",
                   layout.ATTR_UNIT_REVISION: "unit revision", layout.ATTR_STATION: "station"}
"""Root attributes naming the unit under test and the station (absent in older files: read as "")."""


def section_verdict(summary: RunSummary, checks: list["CheckResult"]) -> str:
    """The verdict with its reasons, then one row per check (and built-in test): name, signal,
    statistic, window, value with its unit, limits, outcome."""
    v = run_verdict(summary, checks)
    mode = str(summary.attrs.get(layout.ATTR_MODE, ""))
    evidence = is_evidence(mode)
    word = v.word if evidence else f"{v.word} ({mode_word(mode)})"
    css = _VERDICT_CLASS[v.word] if evidence or v.word != "PASSED" else "warn"  # a simulated pass is never green
    out = f'<p class="verdict {css}" id="verdict">{esc(word)}</p>'
    reasons = ([] if evidence else [banner(mode)]) + v.reasons
    out += "<ul>" + "".join(f"<li>{esc(r)}</li>" for r in reasons) + "</ul>"
    if not checks:
        return out
    rows = []
    for c in checks:
        units = signal_units(summary, c.signal)
        val, u = display_value(c.statistic, c.value, units)
        lo = display_value(c.statistic, c.minimum, units)[0]
        hi = display_value(c.statistic, c.maximum, units)[0]
        value = fmt_quantity(val, u)
        outcome = Cell("recorded (no limits: no verdict)", "") if c.outcome == NO_VERDICT else _outcome(c.outcome)
        if not evidence and c.outcome == "passed":
            outcome = Cell(f"passed ({mode_word(mode).lower()})", "warn")
        rows.append([c.step + 1, c.name, c.signal, c.statistic, c.window, value, limits_text(lo, hi, u, c.reference), outcome])
    return out + table(["#", "check", "signal", "statistic", "window", "value", "limits", "outcome"], rows, left=5)


def limits_text(lo: float | None, hi: float | None, units: str, reference: str | None = None) -> str:
    """Limits of a check in display units: ``lo … hi units``, ``≥ lo``, ``≤ hi``, ``none``; a
    comparison with an earlier check names it (its tolerance is not recorded in the run file)."""
    if reference:
        return f"vs {reference} (tolerance: procedure parameters)"
    return fmt_range(lo, hi, units)


def section_summary(summary: RunSummary) -> str:
    """The unit under test (serial, part, revision) and the station, then the run: procedure, status
    (coloured, with the abort reason), mode, operator, host, software, start/end UTC, duration (run
    time; wall time too when the clock was virtual), run file, steps executed of planned."""
    a = summary.attrs
    info = procedure_info(summary)
    status = summary.status.upper()
    title = _procedure_title(summary.procedure_text)
    rows: list[list[Any]] = [[label, str(a.get(key, "") or "") or Cell("not recorded", "note")] for key, label in IDENTITY_LABELS.items()]
    rows += [
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
        ["mode", Cell(f"{mode_word(mode)} ({mode})" + ("" if is_evidence(mode) else f": {banner(mode)}"),
                      "" if is_evidence(mode) else "warn")],
        ["operator", describe_operator(str(a.get(layout.ATTR_OPERATOR, "")), str(a.get(layout.ATTR_OPERATOR_ORIGIN, "") or ""))],
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
    rows.append(["duration (h:mm:ss)", duration])
    size = summary.path.stat().st_size if summary.path.exists() else 0
    rows.append(["run file", f"{printable(summary.path.resolve())} ({size / 1e6:.1f} MB)"])  # a name need not be UTF-8
    other = [s for s in summary.steps if s.type not in ("check", "bit") and s.outcome in ("failed", "aborted", "interrupted")]
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
    out = ""
    if summary.instruments:
        main = ("vendor", "model", "serial", "firmware")
        rows = []
        for name, ident in summary.instruments.items():
            rest = ", ".join(f"{k}={v}" for k, v in ident.items() if k not in main and v != "")
            rows.append([name, *(ident.get(k, "") for k in main), rest])
        out += table(["instrument", *main, "other identity"], rows, left=6)
    else:
        out += note("No instruments recorded in this run file.")
    srows = []
    for s in summary.streams:
        span = f"{hms(s.t_start_s)} – {hms(s.t_end_s)}" if s.t_start_s is not None and s.t_end_s is not None else "-"
        cols = ", ".join(f"{n}{list(s.shapes[n]) if s.shapes.get(n) else ''} ({u})" for n, u in s.columns.items())
        srows.append([s.key, cols, s.rows, span, s.rate_hz])
    if srows:
        out += table(["stream", "columns (units)", "rows", "run time span (h:mm:ss)", "mean rate (Hz)"], srows,
                     title="Recorded streams", left=2)
    return out


def section_steps(summary: RunSummary, checks: list["CheckResult"] | None = None) -> str:
    """One row per executed step: number, name, type, start and duration (H:MM:SS run time), outcome
    (a check's as in the checks table: ``recorded`` when it has no limits), message."""
    outcome = {c.step: c.outcome for c in checks or []}
    rows = [[s.index + 1, s.name, s.type, hms(s.t_start_s), hms(s.duration_s), _outcome(outcome.get(s.index, s.outcome)), s.detail]
            for s in summary.steps]
    body = table(["#", "step", "type", "start (h:mm:ss)", "duration (h:mm:ss)", "outcome", "message"], rows, left=7)
    return f'<div id="steps">{body}</div>'


# ---- time series -----------------------------------------------------------------------------------
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


# ---- analyses ----------------------------------------------------------------------------------------
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


def why_no_sweep(ds: Any) -> str:
    """Why the run has no temperature sweep for the thermal calibration (``""`` when it has one):
    the sensor temperature of the samples the fit uses (zero rate, after the warm-up) must span at
    least :data:`TEMP_SWEEP_MIN_C`."""
    temp, _, fitted = zero_rate_samples(ds, *_thermal_selection())
    if temp is None:
        return "the run has no sensor temperature."
    span = S.finite_span(temp[fitted] if fitted is not None else temp)
    if span is None:
        return "no zero-rate samples after the warm-up (the thermal fit's samples)."
    if span[1] - span[0] < TEMP_SWEEP_MIN_C:
        return (f"no temperature sweep: the sensor temperature of the zero-rate samples after the warm-up spans "
                f"{span[1] - span[0]:.1f} °C ({span[0]:.1f} … {span[1]:.1f} °C); a sweep spans at least {TEMP_SWEEP_MIN_C:g} °C.")
    return ""


def why_no_rate_steps(data: RunData) -> str:
    """Why the rate-transfer section does not apply (``""`` when it does): no recording window at a
    commanded rate (from its name) nor with the table or bench turning (its monitor)."""
    if any(w.rate_dps for w in data.windows):
        return ""
    if any(c.motion_dps is not None and c.motion_dps > S.STATIC_RATE_DPS for c in data.window_checks):
        return ""
    return "no rate steps were run (no recording window at a commanded rate or with the table or bench turning)."


def static_subset(ds: Any, window: S.WindowCheck) -> Any:
    """The rows of dataset ``ds`` inside ``window``, as a dataset whose source names the window (so
    the noise analysis does not select a recording window of the run file again)."""
    t = np.asarray(ds["time_s"], dtype=float)
    sub = ds.select(S.in_window(t, window.t0, window.t1))
    sub.source = f"{ds.source}, window '{window.name}'"
    return sub


def section_noise(checks: list[S.WindowCheck], ds: Any,
                  analysis: Callable[[str, Any, Callable[[CalibrationResult], str]], str]) -> str:
    """Noise from the longest static recording window only (:mod:`bench.report.static`): the Allan
    deviation section of that window, or why there is none; then every window with its motion,
    temperature drift and verdict. ``analysis(key, dataset, render)`` runs the noise calibration."""
    chosen = S.longest_static(checks)
    if chosen is None:
        out = note(f"No noise analysis: {S.no_static_reason(checks)}. Noise over a moving table or a drifting "
                   "temperature would measure the motion or the drift, not the sensor.")
    else:
        others = sum(1 for c in checks if c.static) - 1
        out = note(f"Noise of the static window '{chosen.name}' ({hms(chosen.t0)} – {hms(chosen.t1)}, {chosen.samples} samples)"
                   + (f"; {others} other static window(s), none longer" if others else "")
                   + f"; static: table and bench at rest (≤ {S.STATIC_RATE_DPS:g} deg/s), temperature drift ≤ {S.TEMP_DRIFT_MAX_C:g} °C.")
        out += analysis("noise", static_subset(ds, chosen), lambda r: section_allan(r.json))
    rows = []
    for c in checks[:MAX_WINDOW_ROWS]:
        verdict_cell = Cell("used", "pass") if c is chosen else (Cell("static", "") if c.static else Cell("; ".join(c.reasons), "l"))
        rows.append([c.name, hms(c.t0), hms(c.duration_s), c.samples, c.motion_dps, c.temp_drift_c, verdict_cell])
    if rows:
        out += table(["window", "start (h:mm:ss)", "duration (h:mm:ss)", "samples", "table/bench rate (deg/s)",
                      "temperature drift (°C)", "static?"], rows, title="Recording windows judged for noise")
    if len(checks) > MAX_WINDOW_ROWS:
        rest = checks[MAX_WINDOW_ROWS:]
        out += note(f"{len(rest)} more windows not listed ({sum(1 for c in rest if c.static)} of them static).")
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


# ---- checks and the pre/post comparison ----------------------------------------------------------------
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


# ---- calibration tables ------------------------------------------------------------------------------
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
    return out or note("No calibration ran on this run (see the analysis sections for why).")
