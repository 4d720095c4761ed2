"""``bench soak``: the procedure library back to back on the simulated lab, with random faults.

Each run is a normal dry-run (virtual time, its own run file) of the next procedure of the library
(a seeded shuffle, repeated) with faults drawn by :mod:`bench.faults` at
``faults_per_hour`` (Poisson, in run time), until the runs add up to ``hours`` of run time. After
each run the soak reads its file back and measures:

* crashes: the runner raised instead of returning a result, or the file could not be finalised;
* unreadable files: the run file does not read back (``bench inspect`` would fail);
* aborts and whether each is explained: its reason names an injected fault's instrument or
  symptom (``FaultClass.explains``), and every instrument reached its safe state;
* data lost, measured, not assumed: rows the recorder accepted (``rows_appended``) but missing
  from the file, plus sensor-board frames that the simulated board sent over a healthy link
  (no injected fault active on it) but that are missing from the file (frame-counter gaps
  outside the fault windows).

Per fault class: injected, survived (the run went on past it), aborted safely (the run stopped
because of it, explained, safe state reached), data lost (rows).
"""

from __future__ import annotations

import json
import math
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import h5py
import numpy as np

from bench.errors import InputError
from bench.faults import FaultSpec, fault_classes
from bench.kinds import registry
from bench.kinds.record import Kind
from bench.record import layout

FAULT_WINDOW_SLACK_S = 10.0
"""Frames missing up to this long (s of run time) after an injected fault on the board's link ended
count as caused by it: the runner notices a fault at its next drain (5 s in a dry-run) and the
board restarts its stream after a reconnection."""


@dataclass
class ClassTally:
    injected: int = 0
    survived: int = 0
    aborted_safely: int = 0
    aborted_unsafely: int = 0
    data_lost_rows: int = 0


@dataclass
class SoakReport:
    """What a soak measured (see the module docstring). Times in s, rows as counts."""

    hours: float
    faults_per_hour: float
    seed: int
    run_time_s: float = 0.0
    wall_time_s: float = 0.0
    runs: int = 0
    aborts: int = 0
    aborts_explained: int = 0
    crashes: int = 0
    unreadable_files: int = 0
    data_lost_rows: int = 0
    by_class: dict[str, ClassTally] = field(default_factory=dict)
    run_log: list[dict[str, Any]] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    @property
    def faults_injected(self) -> int:
        return sum(t.injected for t in self.by_class.values())

    def to_json(self) -> dict[str, Any]:
        """The ``--json`` document (keys as documented in ``docs/reliability.md``)."""
        return {
            "faults_injected": self.faults_injected, "runs": self.runs, "aborts": self.aborts,
            "aborts_explained": self.aborts_explained, "crashes": self.crashes,
            "unreadable_files": self.unreadable_files, "data_lost_rows": self.data_lost_rows,
            "by_class": {k: vars(v) for k, v in sorted(self.by_class.items())},
            "hours": self.hours, "faults_per_hour": self.faults_per_hour, "seed": self.seed,
            "run_time_h": self.run_time_s / 3600.0, "wall_time_s": self.wall_time_s,
            "runs_detail": self.run_log, "problems": self.problems,
        }

    def markdown_table(self) -> str:
        """The reliability table of ``docs/reliability.md``: fault class -> injected -> survived ->
        aborted safely -> data lost."""
        lines = ["| fault class | severity | injected | survived | aborted safely | data lost (rows) |",
                 "|---|---|---|---|---|---|"]
        for name, cls in fault_classes().items():
            t = self.by_class.get(name, ClassTally())
            lines.append(f"| `{name}` | {cls.severity} | {t.injected} | {t.survived} | {t.aborted_safely} | {t.data_lost_rows} |")
        lines.append(f"| **all** | | {self.faults_injected} | {sum(t.survived for t in self.by_class.values())} | "
                     f"{sum(t.aborted_safely for t in self.by_class.values())} | {self.data_lost_rows} |")
        return "\n".join(lines)


class _QuietProgress:
    def start(self, procedure, total_s): ...
    def step(self, n, total, step): ...
    def stop(self, run_time_s): ...
    def message(self, text): ...
    def advance(self, run_time_s, readings=""): ...


def soak(config_path: Path, hours: float, faults_per_hour: float, seed: int, runs_dir: Path, *,
         procedures: list[Path], answers: Path | None = None, classes: list[str] | None = None,
         on_run: Callable[[dict[str, Any]], None] | None = None) -> SoakReport:
    """Run ``procedures`` back to back (seeded order) until ``hours`` of run time, injecting faults
    at ``faults_per_hour``; returns the measured :class:`SoakReport`."""
    from bench.validate import load_checked
    from bench.runner.operator import Operator
    from bench.runner.session import start_run

    if not procedures:
        raise InputError("no procedures to soak (the library is empty)", field="--procedures")
    if not (math.isfinite(hours) and hours > 0):
        raise InputError(f"expected a positive number of hours, got {hours!r}", field="--hours")
    if not (math.isfinite(faults_per_hour) and faults_per_hour >= 0):
        raise InputError(f"expected faults per hour >= 0, got {faults_per_hour!r}", field="--faults-per-hour")
    rng = np.random.default_rng(seed)
    report = SoakReport(hours, faults_per_hour, seed)
    operator = Operator.from_file(answers) if answers is not None else Operator(None, None)
    loaded = {p: load_checked(p, config_path, {}) for p in procedures}
    t_wall = time.perf_counter()
    order: list[Path] = []
    while report.run_time_s < hours * 3600.0:
        if not order:
            order = [procedures[i] for i in rng.permutation(len(procedures))]
        path = order.pop(0)
        procedure, config = loaded[path]
        spec = FaultSpec(faults_per_hour, int(rng.integers(2**31)), list(classes or []))
        entry: dict[str, Any] = {"procedure": procedure.name, "faults": []}
        session = None
        try:
            session = start_run(procedure, config, procedure_path=path, config_path=config_path, runs_dir=runs_dir,
                                sim=True, realtime=False, operator=operator, progress=_QuietProgress(), fault_spec=spec)
            try:
                result = session.runner.run()
            finally:
                session.lab.close()
            if session.catalog is not None:
                session.catalog.run_ended()  # the run's catalogue row (a failure only warns)
            entry.update(status=result.status, abort_reason=result.abort_reason, run_time_s=result.run_time_s)
        except Exception as exc:  # noqa: BLE001 - a crash is what the soak is looking for
            report.crashes += 1
            entry.update(status="crash", abort_reason=f"{type(exc).__name__}: {exc}", run_time_s=0.0,
                         traceback=traceback.format_exc())
            report.problems.append(f"run {report.runs + 1} ({procedure.name}): crash {type(exc).__name__}: {exc}")
        report.runs += 1
        if session is not None:
            entry["file"] = str(session.recorder.path)
            _assess(session, entry, report)
        report.run_time_s += max(float(entry.get("run_time_s") or 0.0), 1.0)
        report.run_log.append(entry)
        if on_run is not None:
            on_run(entry)
    report.wall_time_s = time.perf_counter() - t_wall
    return report


def _assess(session, entry: dict[str, Any], report: SoakReport) -> None:
    """Read the run file back and account for every injected fault (see the module docstring)."""
    from bench.record.reader import read_run_summary

    path = session.recorder.path
    injected = [f for f in session.faults if f.injected]
    for f in injected:
        entry["faults"].append({"class": f.cls.name, "target": f.target, "t_s": round(f.t_s, 3),
                                "duration_s": f.duration_s, "error": f.error})
    try:
        summary = read_run_summary(path)
    except InputError as exc:
        report.unreadable_files += 1
        report.problems.append(f"{path}: unreadable: {exc}")
        summary = None
    lost_recorder = _rows_not_written(path)
    lost_board = _board_frames_lost(path, injected, session) if summary is not None else 0
    lost = lost_recorder + lost_board
    entry["data_lost_rows"] = lost
    report.data_lost_rows += lost
    if lost:
        report.problems.append(f"{path}: {lost_recorder} accepted rows missing from the file, {lost_board} board frames lost outside fault windows")
    cause = None
    if entry.get("status") == "aborted":
        report.aborts += 1
        reason = entry.get("abort_reason", "")
        t_abort = float(entry.get("run_time_s") or 0.0)
        for f in sorted(injected, key=lambda f: -f.t_s):
            if f.t_s <= t_abort + 1e-6 and _explains(f, reason, registry.get(session.lab.kinds.get(f.target, ""))):
                cause = f
                break
        safe = summary is not None and _safe_state_reached(summary, session)
        if cause is not None and safe:
            report.aborts_explained += 1
        else:
            report.problems.append(f"{path}: abort {'not explained' if cause is None else 'without a safe state'}: {reason}")
        entry["abort_cause"] = cause.cls.name if cause is not None else None
        entry["safe_state"] = safe
    for f in injected:
        tally = report.by_class.setdefault(f.cls.name, ClassTally())
        tally.injected += 1
        if f is cause:
            if entry.get("safe_state"):
                tally.aborted_safely += 1
            else:
                tally.aborted_unsafely += 1
        elif entry.get("status") != "crash":
            tally.survived += 1
    if injected and lost:
        report.by_class[injected[-1].cls.name].data_lost_rows += lost


def _explains(f, reason: str, kind: Kind | None) -> bool:
    """Whether the abort ``reason`` is what fault ``f`` on an instrument of ``kind`` explains: it
    names the instrument (or what messages call its kind: "chamber"), a hazard's words, or a
    stream's silence."""
    low = reason.lower()
    if f.cls.name == "disk_full":
        return any(w in low for w in f.cls.explains)
    return f.target.lower() in low or (kind is not None and kind.what.lower() in low) or \
        (f.cls.severity == "hazard" and any(w.lower() in low for w in f.cls.explains)) or \
        (kind is not None and kind.streams and "no frames" in low)


def _safe_state_reached(summary, session) -> bool:
    names = set(session.lab.instruments)
    reached = {e.source for e in summary.events if e.kind == "safe_state" and "failed" not in e.message}
    return names <= reached


def _rows_not_written(path: Path) -> int:
    """Rows the recorder accepted (``rows_appended``) that are not in the file."""
    try:
        with h5py.File(path, "r") as f:
            lost = 0
            for key in _stream_keys(f):
                g = f[layout.stream_path(key)]
                if layout.ATTR_ROWS_APPENDED in g.attrs:
                    datasets = [g[n] for n in g if isinstance(g[n], h5py.Dataset)]
                    rows = min(d.shape[0] for d in datasets) if datasets else 0
                    lost += max(int(g.attrs[layout.ATTR_ROWS_APPENDED]) - rows, 0)
            return lost
    except (OSError, KeyError, ValueError):
        return 0


def _stream_keys(f: h5py.File) -> list[str]:
    out: list[str] = []
    f[layout.STREAMS].visititems(lambda name, obj: out.append(name) if isinstance(obj, h5py.Group) and layout.TIME in obj else None)
    return out


def _board_frames_lost(path: Path, injected, session) -> int:
    """Board frames missing from the file (frame-counter gaps) outside the windows of faults on the board's link."""
    board = [n for n, k in session.lab.kinds.items() if getattr(registry.get(k), "streams", False)]
    if not board:
        return 0
    name = board[0]
    from bench.record.reader import read_stream

    try:
        stream = read_stream(path, name)
    except InputError:
        return 0  # no board stream in this run (or unreadable: counted as such)
    if "counter" not in stream:
        return 0
    counter = stream["counter"].astype(np.int64)
    t = stream["time"]
    if counter.size < 2:
        return 0
    windows = [(f.t_s, f.t_s + (f.duration_s or 0.0) + FAULT_WINDOW_SLACK_S) for f in injected if f.target == name]
    modulus = 65536  # the board's frame counter is 16 bits (docs/acs-board-protocol.md)
    step = np.diff(counter) % modulus
    lost = 0
    for i in np.nonzero((step > 1) & (step < modulus // 2))[0]:
        t0, t1 = float(t[i]), float(t[i + 1])
        if any(a <= t1 and t0 <= b for a, b in windows):
            continue
        lost += int(step[i] - 1)
    return lost


def write_json(report: SoakReport, path: Path) -> None:
    path.write_text(json.dumps(report.to_json(), indent=2) + "\n")
