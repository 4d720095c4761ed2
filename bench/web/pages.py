"""The data behind the pages: the catalogue as a filtered table, a run as JSON, a live snapshot.

The runs table is the catalogue of runs (``bench runs``'s query and filters) with the run files of
the runs directory that the catalogue does not list yet (written by ``bench replay``, ``bench
import``, a test, or killed before their row was written), read from the files and catalogued in
the background (:mod:`bench.web.runs_index`: a request never writes the catalogue). A run page is ``bench inspect --json`` (:func:`bench.record.summary_json.summary_json`)
plus the verdict of the report and the plottable channels; the live page reads the file as
``bench watch`` does (only what was added since the last read).
"""

from __future__ import annotations

import threading
import time
from datetime import datetime
from pathlib import Path
from typing import Any

from bench.errors import InputError
from bench.web.paths import run_id

FILTERS = ("unit", "procedure", "status", "verdict", "mode", "since")
"""Query parameters of the runs table (as ``bench runs --unit/--procedure/--status/--verdict/--mode/--since``)."""
MAX_ROWS = 1000
"""Most rows the runs table lists (the latest ones)."""
LIVE_EVENTS = 12


def _json_value(v: Any) -> Any:
    if isinstance(v, datetime):
        return v.strftime("%Y-%m-%dT%H:%M:%SZ")
    if isinstance(v, float) and v != v:
        return None
    return v


def runs_table(runs_dir: Path, index: Any, query: dict[str, str]) -> dict[str, Any]:
    """The rows matching ``query`` (:data:`FILTERS`; empty values ignored) from ``index``
    (:class:`bench.web.runs_index.RunsIndex`), latest :data:`MAX_ROWS`, newest first, each with its
    ``id`` (None for a file outside the runs directory), its mode (:func:`mode_facts`), and for a run
    still writing its file what the file says now (:func:`live_row`: ``waiting`` at a prompt, run
    time); and ``warnings`` (a catalogue that cannot be read, rows not catalogued yet). Bad filter
    values raise :class:`InputError` naming the filter."""
    from bench.catalog.query import RunFilter, parse_mode, parse_since, parse_status, parse_text, parse_verdict
    from bench.quantity_format import fmt_hms, fmt_number

    q = {k: (query.get(k) or "").strip() or None for k in FILTERS}
    f = RunFilter(unit=parse_text(q["unit"], "unit"), procedure=parse_text(q.get("procedure"), "procedure"),
                  status=parse_status(q["status"], "status"), verdict=parse_verdict(q["verdict"], "verdict"),
                  mode=parse_mode(q["mode"], "mode"), since=parse_since(q["since"], field="since"), limit=MAX_ROWS)
    rows, warnings = index.table(f)
    out = []
    for r in reversed(rows):
        item = {k: _json_value(v) for k, v in r.items()}
        path = Path(r["path"])
        item["id"] = run_id(runs_dir, path) if path.is_file() else None
        item.update(mode_facts(r.get("mode")))
        item["verdict_text"] = verdict_text(r.get("verdict"), r.get("mode"))
        if r["status"] == "running" and path.is_file():
            item.update(live_row(path))  # a run written elsewhere (a terminal): waiting? how far?
        item["run_time_text"] = fmt_hms(item.get("run_time_s"))
        p, lo, hi = r["min_pressure_torr"], r["temp_min_degc"], r["temp_max_degc"]
        item["pressure_text"] = fmt_number(p, 2) if p is not None else ""
        item["temperature_text"] = f"{fmt_number(lo, 3)} .. {fmt_number(hi, 3)}" if lo is not None and hi is not None else ""
        out.append(item)
    return {"runs": out, "filters": {k: q[k] or "" for k in FILTERS}, "warnings": warnings}


def mode_facts(mode: str | None) -> dict[str, Any]:
    """What the pages show of a run's mode (:mod:`bench.run_mode`): ``mode_word``, ``evidence``, ``banner``."""
    from bench.run_mode import banner, is_evidence, mode_word

    return {"mode_word": mode_word(mode), "evidence": is_evidence(mode), "banner": banner(mode)}


def verdict_text(verdict: str | None, mode: str | None) -> str:
    """The verdict as the runs table shows it: ``passed``, ``passed (dry-run)``…; ``""`` while running."""
    from bench.run_mode import verdict_text as text

    return text(verdict, mode) if verdict else ""


def live_row(path: Path) -> dict[str, Any]:
    """For a catalogue row still ``running``: what its file says now: ``status`` (``waiting`` at an
    operator prompt, ``crashed`` once its heartbeat is stale), ``run_time_s`` (s, from the heartbeat)
    and ``waiting_for`` (the prompt). Nothing when the file cannot be read."""
    from bench.record import read_run_summary

    try:
        summary = read_run_summary(path, event_kinds=(), traffic=False)
    except (InputError, OSError):
        return {}
    w = summary.waiting_for
    return {"status": summary.live_status, "run_time_s": summary.heartbeat_run_time_s,
            "waiting_for": w.text if w is not None else ""}


def run_page(path: Path) -> dict[str, Any]:
    """A run as the run page shows it: ``bench inspect --json`` with the report's ``verdict``
    (word and reasons) and every plottable ``channels`` entry."""
    from bench.record import read_run_summary
    from bench.record.checks import check_results, run_verdict
    from bench.record.reader import _open_run
    from bench.record.summary_json import summary_json
    from bench.web.decimate import channels

    from bench.event_text import event_text
    from bench.inspect_view import check_limits, check_value, check_what, operator_text
    from bench.quantity_format import fmt_hms, fmt_seconds

    summary = read_run_summary(path, traffic=False)
    out = summary_json(summary, max_events=200)
    checks = check_results(summary)
    v = run_verdict(summary, checks)
    out["verdict"] = {"word": v.word, "reasons": v.reasons}
    out.update(mode_facts(out.get("mode")))
    out["operator_text"] = operator_text(summary.attrs)
    for c, j in zip(checks, out["checks"]):  # one formatter for every view: units on every number
        j.update(value_text=check_value(c), limits_text=check_limits(c), what=check_what(c))
    for st in out["steps"]:
        st["duration_text"] = fmt_seconds(st["duration_s"]) if st.get("duration_s") is not None else ""
    for e in out.get("events", {}).get("recent", []):
        e["text"] = event_text(e["kind"], e["source"], e["message"])
        e["t_text"] = fmt_hms(e["t_s"])
    with _open_run(path) as (f, _warnings):
        out["channels"] = channels(f)
    out["file_name"] = path.name
    out["file_bytes"] = path.stat().st_size
    return out


class LiveReader:
    """Snapshots of live run files for the live page, one :class:`bench.watch.StepTracker` per file so
    each read only decodes the events added since the last (thread-safe)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._trackers: dict[str, Any] = {}

    def snapshot(self, path: Path) -> dict[str, Any]:
        """The run's state now: status (``waiting`` while a prompt is open), run time, current step,
        steps, latest events, stream rows and last times."""
        from bench.watch import StepTracker, snapshot

        key = str(path)
        with self._lock:
            tracker = self._trackers.setdefault(key, StepTracker(keep=LIVE_EVENTS))
            s = snapshot(path, max_events=LIVE_EVENTS, tracker=tracker, trend_points=2)
        cur = s.current_step
        from bench.event_text import event_text

        return {
            "status": s.status, "status_detail": s.status_detail, "run_time_s": s.run_time_s, "abort_reason": s.abort_reason,
            "ended_utc": s.ended_utc, "file_bytes": _size(path),
            "final": s.final, "steps_total": s.steps_total, "steps_done": s.steps_done,
            "current_step": None if cur is None else {"step": cur.index + 1, "name": cur.name, "type": cur.type},
            "steps": [{"step": x.index + 1, "name": x.name, "type": x.type, "outcome": x.outcome, "t_start_s": x.t_start_s,
                       "t_end_s": x.t_end_s} for x in s.steps],
            "waiting_for": None if s.waiting_for is None else {"prompt": s.waiting_for.text, "id": s.waiting_for.id},
            "events": [{"t_s": e.t_s, "kind": e.kind, "source": e.source, "message": e.message,
                        "text": event_text(e.kind, e.source, e.message)} for e in s.events],
            "streams": [{"key": st.key, "rows": st.rows, "t_last_s": st.t_last_s, "rate_hz": st.rate_hz} for st in s.streams],
            "read_at_unix": time.time(),
        }


def _size(path: Path) -> int | None:
    try:
        return path.stat().st_size
    except OSError:
        return None
