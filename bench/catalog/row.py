"""One catalogue row from one run file: everything is computed from the file, nothing is invented.

The row (:data:`bench.catalog.schema.ROW_FIELDS`) is the run's identity (unit, station,
procedure, operator, mode, times), its status as the reader infers it (``crashed`` for a
``running`` file whose heartbeat is stale), a verdict (:func:`verdict`), the first failed step, the
abort reason, and an environment summary from the monitor streams: the lowest pressure (Torr) and
the temperature range (degC), null when the file has no such column.

Hashes: ``procedure_sha256`` of the procedure text stored in the file (its utf-8 bytes),
``file_sha256`` of the whole file once no process writes it any more (status other than
``running``); ``""`` while it runs, since the file still changes.
"""

from __future__ import annotations

import hashlib
import math
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from bench.record import layout
from bench.record.checks import run_verdict
from bench.record.reader import STALE_AFTER_S, RunSummary, StepSummary, read_run_summary, read_stream
from bench.units import registry

VERDICT_PASSED = "passed"
VERDICT_FAILED = "failed"
VERDICT_NONE = "no verdict"
VERDICT_INCOMPLETE = "incomplete"
VERDICTS = (VERDICT_PASSED, VERDICT_FAILED, VERDICT_NONE, VERDICT_INCOMPLETE)
"""Values of the ``verdict`` column (null while the run is running)."""

STATUSES = (layout.STATUS_RUNNING, layout.STATUS_COMPLETED, layout.STATUS_ABORTED, layout.STATUS_FAILED, layout.STATUS_CRASHED)
"""Values of the ``status`` column: the writer's statuses and the reader's ``crashed``."""

CATALOG_EVENT_KINDS = (*layout.STEP_EVENT_KINDS, layout.EVENT_CHECK, "procedure")
"""The only events a row needs (command/reply traffic is never decoded: it can be most of a file)."""

PRESSURE_UNITS = "Torr"
TEMPERATURE_UNITS = "degC"


def run_row(path: Path, *, stale_after_s: float = STALE_AFTER_S, now_unix: float | None = None) -> dict[str, Any]:
    """The catalogue row of the run file at ``path``. ``stale_after_s`` and ``now_unix`` (s) decide
    ``crashed`` as :func:`bench.record.read_run_summary` does. Raises :class:`InputError` for a file
    that is not a readable bench run file."""
    path = Path(path).resolve()
    s = read_run_summary(path, stale_after_s=stale_after_s, now_unix=now_unix, event_kinds=CATALOG_EVENT_KINDS)
    a = s.attrs
    failed = first_failed_step(s.steps)
    p_min, t_min, t_max = environment(path, s)
    return {
        "path": str(path),
        "file_sha256": "" if s.status == layout.STATUS_RUNNING else file_sha256(path),
        "unit_serial": _text(a, layout.ATTR_UNIT_SERIAL),
        "unit_part": _text(a, layout.ATTR_UNIT_PART),
        "unit_revision": _text(a, layout.ATTR_UNIT_REVISION),
        "station": _text(a, layout.ATTR_STATION),
        "procedure_name": _text(a, layout.ATTR_PROCEDURE_NAME),
        "procedure_sha256": hashlib.sha256(s.procedure_text.encode(layout.TEXT_ENCODING, errors="surrogateescape")).hexdigest(),
        "operator": _text(a, layout.ATTR_OPERATOR),
        "mode": _text(a, layout.ATTR_MODE),
        "started_utc": parse_utc(_text(a, layout.ATTR_STARTED_UTC)),
        "ended_utc": parse_utc(_text(a, layout.ATTR_ENDED_UTC)),
        "run_time_s": _finite(s.heartbeat_run_time_s),
        "status": s.status,
        "verdict": verdict(s),
        "first_failed_check": failed.name if failed is not None else None,
        "reason": reason(s),
        "min_pressure_torr": p_min,
        "temp_min_degc": t_min,
        "temp_max_degc": t_max,
    }


def verdict(s: RunSummary) -> str | None:
    """The run's verdict as :func:`bench.record.checks.run_verdict` gives it (the report shows the
    same), in lower case; None while the run is running."""
    if s.status == layout.STATUS_RUNNING:
        return None
    return run_verdict(s).word.lower()


def first_failed_step(steps: Iterable[StepSummary]) -> StepSummary | None:
    """The first step (in execution order) whose outcome is ``failed``."""
    return next((st for st in steps if st.outcome == "failed"), None)


def reason(s: RunSummary) -> str | None:
    """Why the run stopped: the abort reason the writer stored, or for a crashed file when its
    writer stopped (from the heartbeat, so the text does not depend on when it is read)."""
    if s.abort_reason:
        return s.abort_reason
    if s.status == layout.STATUS_CRASHED:
        hb = s.heartbeat_unix
        if hb is None or not math.isfinite(hb):
            return "writer stopped: no valid heartbeat"
        at = f" (run time {s.heartbeat_run_time_s:.1f} s)" if _finite(s.heartbeat_run_time_s) is not None else ""
        return f"writer stopped: no heartbeat since {datetime.fromtimestamp(hb, timezone.utc).strftime(layout.UTC_FORMAT)}{at}"
    return None


def environment(path: Path, s: RunSummary) -> tuple[float | None, float | None, float | None]:
    """``(min pressure Torr, min temperature degC, max temperature degC)`` over every column of
    the monitor streams (``<instrument>/monitor``) whose units are a pressure or a temperature;
    None for what no stream has. NaN readings (an open thermocouple) are skipped."""
    pressures: list[np.ndarray] = []
    temps: list[np.ndarray] = []
    for st in s.streams:
        if layout.split_stream_key(st.key)[1] != layout.MONITOR_STREAM or st.rows == 0:
            continue
        kinds = {c: quantity_kind(u) for c, u in st.columns.items() if not st.shapes.get(c)}
        wanted = [c for c, k in kinds.items() if k is not None]
        if not wanted:
            continue
        data = read_stream(path, st.key, wanted)
        for c in wanted:
            values = np.asarray(data[c], dtype=np.float64)
            if kinds[c] == "pressure":
                pressures.append(_convert(values, st.columns[c], PRESSURE_UNITS))
            else:
                temps.append(_convert(values, st.columns[c], TEMPERATURE_UNITS))
    t_min, t_max = _extreme(temps, np.min), _extreme(temps, np.max)
    return _extreme(pressures, np.min), t_min, t_max


def quantity_kind(units: str) -> str | None:
    """``pressure``, ``temperature`` (an absolute one: not a ``delta_`` difference) or None for
    the pint units ``units``."""
    if not units or "delta" in units:
        return None
    ureg = registry()
    try:
        dim = ureg.Unit(units).dimensionality
    except Exception:  # noqa: BLE001 - pint raises several types for unknown units
        return None
    if dim == ureg.Unit(PRESSURE_UNITS).dimensionality:
        return "pressure"
    if dim == ureg.Unit("kelvin").dimensionality:
        return "temperature"
    return None


def _convert(values: np.ndarray, units: str, to: str) -> np.ndarray:
    if units == to:
        return values
    return np.asarray(registry().Quantity(values, units).to(to).magnitude, dtype=np.float64)


def _extreme(arrays: list[np.ndarray], fn: Any) -> float | None:
    finite = [a[np.isfinite(a)] for a in arrays]
    finite = [a for a in finite if a.size]
    return float(fn(np.concatenate(finite))) if finite else None


def file_sha256(path: Path) -> str:
    """sha256 (hex) of the file's bytes (read in chunks, never whole into memory)."""
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


def parse_utc(text: str) -> datetime | None:
    """A run file's ``YYYY-MM-DDTHH:MM:SSZ`` as a naive UTC datetime; None for ``""`` or anything else."""
    if not text:
        return None
    try:
        return datetime.strptime(text, layout.UTC_FORMAT)
    except ValueError:
        return None


def _text(attrs: dict[str, Any], name: str) -> str:
    """A root attribute as text, ``""`` when absent (older files lack the unit and station attributes)."""
    v = attrs.get(name, "")
    return "" if v is None else str(v)


def _finite(v: float | None) -> float | None:
    return float(v) if v is not None and math.isfinite(v) else None
