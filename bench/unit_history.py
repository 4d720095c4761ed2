"""A unit's history: every run of one serial number, its key figures across runs, and how it sits
among the other units of its part number (``bench unit SN12``, the web station's unit page, the
acceptance data package; ``docs/units-under-test.md``).

* **Runs**: every catalogued run of the serial (the catalogue's rows: procedure, date, station,
  mode, verdict, first failed check, operator), oldest first. Dry-runs and replays are listed and
  marked: they are never acceptance evidence (:mod:`bench.run_mode`).
* **Key figures**: the checks recorded in the run files whose signal is a sensor channel (gyro,
  accelerometer, magnetometer, per axis) and whose statistic reads a property of the sensor: bias,
  scale-factor error, noise (standard deviation, RMS), mean, drift (slope). One figure per channel,
  axis and statistic (``gyro z bias``), one point per check and run, in the check's display units
  (a scale-factor error in %).
* **The lot**: the same figures of every other unit with the same part number: each unit's latest
  value from a real run (a unit with dry-runs only counts with its dry-runs, marked). A unit is an
  *outlier* of its lot when its robust z-score (distance from the lot's median in units of
  1.4826 × the median absolute deviation) exceeds :data:`OUTLIER_Z`; with fewer than
  :data:`MIN_LOT` other units that cannot be told, and the history says so.

The figures come from the checks the procedures recorded: a run without such checks contributes to
the list of runs, not to the figures. Calibrations computed afterwards (``bench calibrate``) are not
in the run files and so not here.

Layer: reads the catalogue (:mod:`bench.catalog`) and run files (:mod:`bench.record`); the CLI, the
web station and :mod:`bench.report.unit_package` present it.
"""

from __future__ import annotations

import math
import re
import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any, Callable

from bench.errors import InputError

SENSOR_COLUMNS = {"gyro": "gyro", "accel": "accelerometer", "mag": "magnetometer"}
"""Sensor columns whose checks are key figures (run-file column -> what it is)."""
FIGURE_STATISTICS = {"bias": "bias", "scale_factor_error": "scale-factor error", "std": "noise (std)", "rms": "noise (rms)",
                     "mean": "mean", "slope": "drift"}
"""Check statistics that read a property of the sensor -> how the figure is named."""
OUTLIER_Z = 3.5
"""Robust z-score beyond which a unit is an outlier of its lot (Iglewicz and Hoaglin's cut-off for
the modified z-score)."""
MIN_LOT = 3
"""Fewest other units of the part number that make a lot to compare with."""
MAD_SCALE = 1.4826
"""Median absolute deviation to standard deviation of a normal distribution."""
FIGURE_EVENT_KINDS = ("check", "step_start", "step_end", "procedure")
"""The only events read from each run file (never the traffic, never the streams)."""


class _Mode:
    """What has a ``mode`` (a run, a value from a run) says whether it is acceptance evidence."""

    mode: str

    @property
    def evidence(self) -> bool:
        from bench.run_mode import is_evidence

        return is_evidence(self.mode)


@dataclass
class RunEntry(_Mode):
    """One run of the unit: the catalogue row's facts (``path`` absolute), ``run_id`` (the web
    station's id, relative to the runs directory, None outside it)."""

    path: str
    run_id: str | None
    procedure: str
    started_utc: datetime | None
    station: str
    mode: str
    status: str
    verdict: str | None
    first_failed_check: str | None
    operator: str
    part: str
    revision: str


@dataclass
class Point(_Mode):
    """One value of a figure: from check ``check`` of the run at ``path``, started ``when`` (UTC)."""

    when: datetime | None
    value: float
    mode: str
    check: str
    procedure: str
    path: str
    run_id: str | None
    outcome: str


@dataclass
class LotValue:
    """Another unit's value of a figure: its latest from a real run, else its latest dry-run value (``evidence`` False)."""

    serial: str
    value: float
    evidence: bool
    when: datetime | None


@dataclass
class Figure:
    """A key figure across runs: ``name`` (``gyro z bias``), ``signal``, ``statistic``, display
    ``units``; the unit's ``points`` (oldest first); the ``lot`` (other units of the part number);
    the comparison: ``latest`` (the unit's value compared: its latest real one, else its latest),
    ``lot_median``, ``lot_spread`` (1.4826 × MAD), ``z`` (robust z-score), ``verdict`` (``within
    its lot``, ``OUTLIER of its lot``, or why it cannot be told)."""

    name: str
    signal: str
    statistic: str
    units: str
    points: list[Point] = field(default_factory=list)
    lot: list[LotValue] = field(default_factory=list)
    latest: Point | None = None
    lot_median: float | None = None
    lot_spread: float | None = None
    z: float | None = None
    verdict: str = ""

    @property
    def outlier(self) -> bool:
        return self.z is not None and abs(self.z) > OUTLIER_Z


@dataclass
class UnitHistory:
    """Everything ``bench unit SERIAL`` shows: the runs, the figures, the part number(s) the runs
    recorded, the other units of that part number, and notes (what could not be read or told)."""

    serial: str
    part: str
    runs: list[RunEntry]
    figures: list[Figure]
    lot_units: list[str]
    notes: list[str] = field(default_factory=list)

    @property
    def dry_runs(self) -> int:
        return sum(not r.evidence for r in self.runs)


# ---- reading ---------------------------------------------------------------------------------------
def unit_history(serial: str, *, runs_dir: Path, catalog: str | None = None, part: str | None = None,
                 find: Callable[[Any], list[dict[str, Any]]] | None = None, only_runs_dir: bool = False,
                 field: str = "--runs-dir") -> UnitHistory:
    """The history of unit ``serial`` from the catalogue (``catalog``, default ``runs_dir/catalog.sqlite``)
    and the run files its rows name. ``part``: the part number whose units form the lot (default: the
    one the unit's runs recorded, the latest if several). ``find(filter)``, when given, supplies the
    rows of a :class:`~bench.catalog.query.RunFilter` instead of the catalogue (the web station's
    runs index: the catalogue read, never written, with the run files not catalogued yet).
    ``only_runs_dir``: figures are read only from run files inside ``runs_dir`` (the web station: a
    row naming a file elsewhere is listed, its file never read). :class:`InputError` for a serial
    with no run, or no catalogue (named ``field``)."""
    from bench.catalog.query import find_runs, parse_text
    from bench.catalog.store import open_catalog, resolve_url

    serial = parse_text(serial, "SERIAL") or ""
    if "*" in serial:
        raise InputError(f"one serial number, not a pattern: {serial!r} (bench runs --unit 'SN*' lists several)", None, "SERIAL")
    if find is None:
        url = resolve_url(catalog, runs_dir)
        with open_catalog(url, create=False, field=field) as cat:
            return _history(serial, part, lambda f: find_runs(cat, f), runs_dir, only_runs_dir)
    return _history(serial, part, find, runs_dir, only_runs_dir)


def _history(serial: str, part: str | None, find: Callable[[Any], list[dict[str, Any]]], runs_dir: Path,
             only_runs_dir: bool) -> UnitHistory:
    """:func:`unit_history` with its rows from ``find``."""
    from bench.catalog.query import RunFilter

    rows = find(RunFilter(unit=serial))
    if not rows:
        raise InputError(f"no catalogued run of unit {serial!r} (bench runs lists the units; bench catalog rebuild "
                         f"{runs_dir} catalogues run files written elsewhere)", None, "SERIAL")
    parts = [r["unit_part"] for r in rows if r["unit_part"]]
    part = part or (parts[-1] if parts else "")
    lot_rows = [r for r in find(RunFilter(part=part)) if r["unit_serial"] and r["unit_serial"] != serial] if part else []
    notes: list[str] = []
    if len(set(parts)) > 1:
        notes.append(f"the runs of {serial} recorded several part numbers ({', '.join(sorted(set(parts)))}); compared with {part}")
    if not part:
        notes.append(f"no run of {serial} recorded a part number (bench run --part PN): no lot to compare with")
    entries = [_entry(r, runs_dir) for r in rows]
    figures: dict[tuple[str, str], Figure] = {}
    for e in entries:
        for fig_key, name, signal, statistic, units, point in _points(e, notes, only_runs_dir):
            fig = figures.get(fig_key)
            if fig is None:
                fig = figures[fig_key] = Figure(name, signal, statistic, units)
            fig.points.append(point)
    lot: dict[tuple[str, str], dict[str, LotValue]] = {}
    for r in lot_rows:
        e = _entry(r, runs_dir)
        for fig_key, _name, _signal, _stat, _units, point in _points(e, notes, only_runs_dir):
            if fig_key not in figures:
                continue
            have = lot.setdefault(fig_key, {}).get(r["unit_serial"])
            if have is None or _better(point, have):
                lot[fig_key][r["unit_serial"]] = LotValue(r["unit_serial"], point.value, point.evidence, point.when)
    for fig_key, fig in figures.items():
        fig.lot = sorted(lot.get(fig_key, {}).values(), key=lambda v: v.serial)
        compare(fig)
    ordered = sorted(figures.values(), key=lambda f: (list(SENSOR_COLUMNS).index(f.signal.split(".")[1]) if f.signal.count(".") >= 1 and
                                                      f.signal.split(".")[1] in SENSOR_COLUMNS else 9, f.signal, f.statistic))
    return UnitHistory(serial, part, entries, ordered, sorted({r["unit_serial"] for r in lot_rows}), notes)


def _entry(r: dict[str, Any], runs_dir: Path) -> RunEntry:
    path = Path(r["path"])
    try:
        rid = path.resolve().relative_to(Path(runs_dir).resolve()).as_posix() if path.is_file() else None
    except (ValueError, OSError):
        rid = None
    return RunEntry(str(path), rid, r["procedure_name"], r["started_utc"], r["station"], r["mode"], r["status"], r["verdict"],
                    r["first_failed_check"], r["operator"], r["unit_part"], r["unit_revision"])


def _better(point: Point, have: LotValue) -> bool:
    """Whether ``point`` replaces ``have`` as a unit's lot value: real beats dry-run, then newer."""
    if point.evidence != have.evidence:
        return point.evidence
    return (point.when or datetime.min) >= (have.when or datetime.min)


_CHANNEL = re.compile(r"^[^.]+\.(?P<column>[^.]+)(?:\.(?P<axis>[xyz]))?$")


_CHECKS_CACHE: "OrderedDict[tuple[str, int, int], list[Any]]" = OrderedDict()
_CHECKS_LOCK = threading.Lock()
CHECKS_CACHE_FILES = 4096
"""Run files whose checks are kept in memory between histories (keyed by path, size and mtime: a
file that changes is read again), so a station showing unit pages reads each file once."""


def _checks(path: Path) -> list[Any]:
    """The checks of the run file at ``path`` (:func:`bench.record.checks.check_results`), read once
    per version of the file. :class:`InputError` for an unreadable file."""
    from bench.record import read_run_summary
    from bench.record.checks import check_results

    st = path.stat()
    key = (str(path), st.st_size, st.st_mtime_ns)
    with _CHECKS_LOCK:
        if key in _CHECKS_CACHE:
            _CHECKS_CACHE.move_to_end(key)
            return _CHECKS_CACHE[key]
    checks = check_results(read_run_summary(path, event_kinds=FIGURE_EVENT_KINDS, traffic=False))
    with _CHECKS_LOCK:
        _CHECKS_CACHE[key] = checks
        while len(_CHECKS_CACHE) > CHECKS_CACHE_FILES:
            _CHECKS_CACHE.popitem(last=False)
    return checks


def _points(e: RunEntry, notes: list[str], only_runs_dir: bool = False) -> list[tuple[tuple[str, str], str, str, str, str, Point]]:
    """The key-figure points of run ``e``: its checks on sensor channels with a figure statistic
    (none, with a note, for a file outside the runs directory when ``only_runs_dir``)."""
    from bench.record.checks import display_value

    path = Path(e.path)
    if only_runs_dir and e.run_id is None and path.exists():
        notes.append(f"{path.name}: not in the station's runs directory; its figures are left out")
        return []
    if not path.is_file():
        notes.append(f"{path.name}: the run file is not on this computer; its figures are left out")
        return []
    try:
        checks = _checks(path)
    except (InputError, OSError) as exc:
        notes.append(f"{path.name}: unreadable ({getattr(exc, 'message', exc)}); its figures are left out")
        return []
    out = []
    for c in checks:
        m = _CHANNEL.match(c.signal)
        if c.value is None or not math.isfinite(c.value) or m is None or m.group("column") not in SENSOR_COLUMNS \
                or c.statistic not in FIGURE_STATISTICS:
            continue
        value, units = display_value(c.statistic, c.value, c.units)
        column, axis = m.group("column"), m.group("axis") or ""
        name = " ".join(x for x in (column, axis, FIGURE_STATISTICS[c.statistic]) if x)
        key = (c.signal.split(".", 1)[1], c.statistic)
        out.append((key, name, c.signal, c.statistic, units,
                    Point(e.started_utc, float(value), e.mode, c.name, e.procedure, e.path, e.run_id, c.outcome)))
    return out


# ---- the lot -----------------------------------------------------------------------------------------
def compare(fig: Figure) -> None:
    """Fill ``fig``'s comparison with its lot (see the module's docstring)."""
    if not fig.points:
        return
    real = [p for p in fig.points if p.evidence]
    fig.latest = (real or fig.points)[-1]
    values = [v.value for v in fig.lot]
    if len(values) < MIN_LOT:
        fig.verdict = (f"cannot tell: {len(values)} other unit(s) of the part number with this figure (a lot needs {MIN_LOT})"
                       if values else "cannot tell: no other unit of the part number has this figure")
        if values:
            fig.lot_median = _median(values)
        return
    med = _median(values)
    mad = _median([abs(v - med) for v in values])
    fig.lot_median, fig.lot_spread = med, MAD_SCALE * mad
    if mad == 0:
        fig.z = 0.0 if fig.latest.value == med else math.copysign(math.inf, fig.latest.value - med)
    else:
        fig.z = (fig.latest.value - med) / (MAD_SCALE * mad)
    dry = "" if fig.latest.evidence else " (from a dry-run: not evidence)"
    lot_dry = sum(not v.evidence for v in fig.lot)
    lot_note = f"; {lot_dry} of the {len(values)} lot values from dry-runs" if lot_dry else ""
    if fig.outlier:
        fig.verdict = f"OUTLIER of its lot{dry}{lot_note}"
    else:
        fig.verdict = f"within its lot{dry}{lot_note}"


def _median(values: list[float]) -> float:
    v = sorted(values)
    n = len(v)
    return v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])


# ---- JSON --------------------------------------------------------------------------------------------
def history_json(h: UnitHistory) -> dict[str, Any]:
    """The history as JSON (``bench unit --json``, the web station's ``/api/unit``): times as
    ``YYYY-MM-DDTHH:MM:SSZ``, values in each figure's display ``units`` and as text with them."""
    from bench.quantity_format import fmt_quantity
    from bench.run_mode import mode_word, verdict_text

    def utc(t: datetime | None) -> str | None:
        return t.strftime("%Y-%m-%dT%H:%M:%SZ") if t is not None else None

    return {
        "serial": h.serial, "part": h.part, "lot_units": h.lot_units, "notes": h.notes, "dry_runs": h.dry_runs,
        "runs": [{"path": r.path, "id": r.run_id, "procedure": r.procedure, "started_utc": utc(r.started_utc), "station": r.station,
                  "mode": r.mode, "mode_word": mode_word(r.mode), "evidence": r.evidence, "status": r.status, "verdict": r.verdict,
                  "verdict_text": verdict_text(r.verdict, r.mode) if r.verdict else "", "first_failed_check": r.first_failed_check,
                  "operator": r.operator, "part": r.part, "revision": r.revision} for r in h.runs],
        "figures": [{
            "name": f.name, "signal": f.signal, "statistic": f.statistic, "units": f.units,
            "points": [{"utc": utc(p.when), "value": p.value, "text": fmt_quantity(p.value, f.units), "mode": p.mode, "evidence": p.evidence,
                        "check": p.check, "procedure": p.procedure, "id": p.run_id, "outcome": p.outcome} for p in f.points],
            "lot": [{"serial": v.serial, "value": v.value, "text": fmt_quantity(v.value, f.units), "evidence": v.evidence,
                     "utc": utc(v.when)} for v in f.lot],
            "latest": None if f.latest is None else {"value": f.latest.value, "text": fmt_quantity(f.latest.value, f.units),
                                                     "evidence": f.latest.evidence},
            "lot_median": f.lot_median, "lot_median_text": fmt_quantity(f.lot_median, f.units) if f.lot_median is not None else "",
            "lot_spread": f.lot_spread, "z": None if f.z is None or not math.isfinite(f.z) else f.z,
            "outlier": f.outlier, "verdict": f.verdict,
        } for f in h.figures],
    }
