"""``bench inspect RUN.h5 --json``: a run file's summary as one JSON object (fields in ``docs/run-file.md``).

Units: run times and durations in s, wall times as ISO 8601 UTC text, ages in s, rates in Hz; check
values in the display units their ``units`` field names.
"""

from __future__ import annotations

import math
import time
from typing import Any

from bench.record import layout
from bench.record.checks import check_counts, check_json, check_results, checks_verdict
from bench.record.reader import EventRow, RunSummary, _iso

JSON_FORMAT = 1
"""Version of the JSON object of ``bench inspect --json`` (field ``json_format``); additions keep it."""


def json_ready(obj: Any) -> Any:
    """``obj`` with every non-finite float (NaN, inf) replaced by None, so ``json.dumps`` writes strict JSON."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {str(k): json_ready(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_ready(v) for v in obj]
    return obj


def event_json(e: EventRow) -> dict[str, Any]:
    """One event: run time ``t_s`` (s), ``kind``, ``source``, 1-based ``step`` (None outside steps), ``message``."""
    return {"t_s": e.t_s, "kind": e.kind, "source": e.source, "step": e.step + 1 if e.step >= 0 else None, "message": e.message}


def summary_json(summary: RunSummary, max_events: int = 40, now_unix: float | None = None) -> dict[str, Any]:
    """The run as a JSON-ready mapping: identity, status (``waiting`` and ``crashed`` included), steps,
    checks, events (counts, traffic per instrument, the last ``max_events`` other events), streams
    with rows and units. ``now_unix`` (s since epoch) for the heartbeat age; default now."""
    a = summary.attrs
    now = time.time() if now_unix is None else now_unix
    w = summary.waiting_for
    checks = check_results(summary)
    counts = check_counts(c.outcome for c in checks)
    hb = summary.heartbeat_unix
    run_times = [t for t in [summary.heartbeat_run_time_s, *(e.t_s for e in summary.events),
                             *(s.t_end_s for s in summary.streams)] if t is not None and math.isfinite(t)]
    return json_ready({
        "json_format": JSON_FORMAT,
        "file": str(summary.path),
        "format_version": a.get(layout.ATTR_FORMAT_VERSION),
        "software_version": a.get(layout.ATTR_SOFTWARE_VERSION, ""),
        "procedure": {"name": a.get(layout.ATTR_PROCEDURE_NAME, ""), "path": a.get(layout.ATTR_PROCEDURE_PATH, "")},
        "config_path": a.get(layout.ATTR_CONFIG_PATH, ""),
        "mode": a.get(layout.ATTR_MODE, ""),
        "operator": a.get(layout.ATTR_OPERATOR, ""),
        "host": a.get(layout.ATTR_HOST, ""),
        "identity": {k: str(a.get(k, "")) for k in layout.IDENTITY_ATTRS},
        "started_utc": a.get(layout.ATTR_STARTED_UTC, ""),
        "ended_utc": a.get(layout.ATTR_ENDED_UTC, ""),
        "status": summary.live_status,
        "stored_status": a.get(layout.ATTR_STATUS, ""),
        "status_detail": summary.status_detail,
        "abort_reason": summary.abort_reason,
        "waiting_for": None if w is None else {
            "prompt": w.text, "id": w.id, "attempt": w.attempt, "step": w.step + 1, "asked_at_run_time_s": w.t_s,
            "asked_utc": _iso(w.wall_unix), "asked_s_ago": max(now - w.wall_unix, 0.0)},
        "heartbeat": {"utc": _iso(hb) if hb is not None and math.isfinite(hb) else None,
                      "age_s": now - hb if hb is not None and math.isfinite(hb) else None,
                      "run_time_s": summary.heartbeat_run_time_s},
        "run_time_s": max(run_times) if run_times else None,
        "warnings": list(summary.warnings),
        "checksums": summary.checksums,
        "instruments": summary.instruments,
        "streams": [{
            "key": s.key, "rows": s.rows, "t_start_s": s.t_start_s, "t_end_s": s.t_end_s, "rate_hz": s.rate_hz, "damage": s.damage,
            "columns": {n: {"units": u, "shape": list(s.shapes.get(n, ()))} for n, u in s.columns.items()},
        } for s in summary.streams],
        "steps": [{
            "step": s.index + 1, "name": s.name, "type": s.type, "outcome": s.outcome, "t_start_s": s.t_start_s,
            "t_end_s": s.t_end_s, "duration_s": s.duration_s, "detail": s.detail,
        } for s in summary.steps],
        "checks": [check_json(c) for c in checks],
        "checks_summary": {**counts, "verdict": checks_verdict(counts)},
        "events": {
            "total": sum(summary.event_counts.values()),
            "by_kind": dict(sorted(summary.event_counts.items())),
            "traffic": {name: {"commands": t.commands, "replies": t.replies, "polls": t.polls, "t_first_s": t.t_first_s,
                               "t_last_s": t.t_last_s} for name, t in summary.traffic.items()},
            "recent": [event_json(e) for e in (summary.meaningful_events[-max_events:] if max_events > 0 else [])],
        },
    })
