"""``bench watch RUN.h5``: a live view of a run file while the recorder writes it.

Every refresh opens the file with the run-file reader's own opening logic (finished files
normally, files being written as an HDF5 SWMR reader with bounded metadata retries, every failure a
located :class:`InputError`), reads what it needs and closes it again, so the writer is never held
up and a finished run is seen with its final status. Only the tail of each dataset is read: the
last rows of every stream (the trend window is found by a binary search on ``time`` and read with a
stride of at most ``MAX_TREND_ROWS`` rows), the last events, and, for the step list, only the events
added since the previous refresh. A refresh therefore costs the same for a 1 MB and a 10 GB file.

Units: run times in s since the start of the run, wall times in s since the Unix epoch, rates in Hz.
See ``docs/watch.md``.
"""

from __future__ import annotations

import json
import math
import re
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np
from rich import box
from rich.console import Console, Group, RenderableType
from rich.live import Live
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from bench.ctrl_c import CtrlC, ctrl_c_noted
from bench.errors import EXIT_OK, InputError
from bench.quantity_format import fmt_hms, fmt_number, fmt_quantity, fmt_reading, is_status_column, unit_text
from bench.record import layout
from bench.record.reader import (
    STALE_AFTER_S,
    first_row_at_or_after,
    EventRow,
    PendingPrompt,
    TrafficSummary,
    _checked_rows,
    _column_order,
    _iso,
    _open_run,
    _plain,
    _size_limit,
    _stream_groups,
    _unreadable,
    _units,
    event_datasets,
    event_row,
    read_heartbeat,
    step_outcome,
)
from bench.run_mode import banner, mode_word
from bench.terminal_text import printable

TREND_WINDOW_S = 600.0
"""Run time (s) covered by the trend of each signal: the last 10 minutes."""
TREND_POINTS = 40
"""Points (sparkline characters) of a trend; each is the mean of the rows in its time bin."""
MAX_TREND_ROWS = 4000
"""Most rows read per column for a trend; a longer window is read with a stride."""
RATE_WINDOW_S = 10.0
"""Run time (s) over which a stream's data rate is measured, ending at its last row."""
MAX_EVENTS = 8
"""Events listed by default."""
WAIT_FOR_FILE_S = 30.0
"""How long (s) :func:`watch` waits for a run file that does not exist, or has not started recording, yet."""
READ_RETRY_S = 15.0
"""How long (s) :func:`watch` keeps retrying, showing the last good state, when refreshes fail."""
FINAL_STATUSES = layout.STATUSES_FINAL
STATUS_STALE = "stale"
"""Never stored: what watch shows for a ``running`` file whose heartbeat is stale (probably crashed)."""
_LIVE = (layout.STATUS_RUNNING, layout.STATUS_WAITING)
HIDDEN_COLUMNS = ("counter", "board_time")
"""Bookkeeping columns of the sensor board; read but not listed as readings (rows and rate are)."""
SPARK_CHARS = "▁▂▃▄▅▆▇█"
MAX_STATES = 4
"""Distinct status words listed for a window (more are counted)."""

_EVENT_BLOCK = 16384  # events read per block when scanning for steps
_BLOB_SPAN = 4 * 1024 * 1024  # blob bytes read at once when the wanted messages lie this close together
_TAIL_ROWS = 64  # rows read at the end of `time` to find the last complete row
_STEP_KINDS = tuple(k.encode("ascii") for k in layout.STEP_EVENT_KINDS)
_PICKED_KINDS = tuple(dict.fromkeys(_STEP_KINDS + tuple(k.encode("ascii") for k in (layout.EVENT_PROMPT, *layout.PROMPT_CLOSING_KINDS))))
"""Events whose messages the tracker reads: the step events, operator prompts and what answers them."""
_TRAFFIC_KINDS = tuple(k.encode("ascii") for k in layout.TRAFFIC_EVENT_KINDS)
_RUN_START = layout.EVENT_RUN_START.encode("ascii")
_STEP_START = layout.EVENT_STEP_START.encode("ascii")
_STEP_END = layout.EVENT_STEP_END.encode("ascii")
_PROMPT = layout.EVENT_PROMPT.encode("ascii")
_COMMAND = b"command"
_WAIT_REASONS = ("open for writing outside SWMR mode", "locked by the process writing it", "the file is empty")


# ---- state --------------------------------------------------------------------------------------
@dataclass
class StepState:
    """A step from its ``step_start``/``step_end`` events; ``outcome`` is ``running`` until it ends,
    then the first word of the ``step_end`` message (passed | failed | aborted | done)."""

    index: int
    name: str
    type: str
    t_start_s: float | None
    t_end_s: float | None = None
    outcome: str = "running"
    detail: str = ""


@dataclass
class SignalState:
    """One scalar signal: a scalar column, or one component (x, y, z) of a vector column.

    ``value`` is the last row; ``trend`` the mean per time bin over the trend window (NaN for an
    empty bin), ``trend_min``/``trend_max`` its extremes (NaN if it has no finite value), which
    scale the sparkline. ``low``/``high`` are the smallest and largest readings themselves: over
    the rows read for the trend (every row of the window up to ``MAX_TREND_ROWS``, else every k-th)
    and the latest one, so the current value always lies within them (bin means would not).
    A status word (:func:`bench.quantity_format.is_status_column`) is a bit field: it is never
    averaged; ``states`` lists the distinct words seen in the window instead."""

    column: str
    component: str
    units: str
    value: float
    integer: bool
    trend: np.ndarray
    trend_min: float
    trend_max: float
    low: float = math.nan
    high: float = math.nan
    states: tuple[float, ...] = ()

    @property
    def label(self) -> str:
        return f"{self.column} {self.component}" if self.component else self.column


@dataclass
class StreamState:
    """One stream: complete ``rows``, the run time of the last row (s), the data rate over the
    last ``RATE_WINDOW_S`` (Hz), the trend span (s), columns (name → units, ``time`` excluded),
    the last row of every column, and the signals."""

    key: str
    rows: int
    t_last_s: float | None
    rate_hz: float | None
    trend_span_s: float
    columns: dict[str, str]
    latest: dict[str, np.ndarray]
    signals: list[SignalState]


@dataclass
class WatchState:
    """What one read of a run file shows. ``status`` is the file's status, except that a
    ``running`` file whose heartbeat is ``stale_after_s`` or older reads ``stale`` (its writer has
    probably crashed), and one that waits for the operator's answer reads ``waiting``.
    ``run_time_s`` is how far the run has got (s). ``events`` are the last events other than
    instrument traffic, which ``traffic`` summarises."""

    path: Path
    procedure: str
    status: str
    status_detail: str
    mode: str
    started_utc: str
    ended_utc: str
    abort_reason: str
    run_time_s: float
    heartbeat_unix: float | None
    heartbeat_age_s: float | None
    steps: list[StepState]
    steps_total: int | None
    current_step: StepState | None
    events: list[EventRow]
    events_total: int
    streams: list[StreamState]
    trend_window_s: float
    warnings: list[str] = field(default_factory=list)
    read_error: str = ""
    read_at_unix: float = 0.0
    waiting_for: PendingPrompt | None = None
    """The operator prompt the run waits on (status ``waiting``), else None."""
    traffic: list[TrafficSummary] = field(default_factory=list)
    """Instrument traffic (``command``/``reply`` events) per instrument; ``events`` leaves it out."""
    events_meaningful: int = 0
    """Events other than instrument traffic (``events_total`` counts every event)."""

    @property
    def final(self) -> bool:
        """True once the writer has closed the file (completed, aborted or failed)."""
        return self.status in FINAL_STATUSES

    @property
    def steps_done(self) -> int:
        """Steps that ended (passed, done, failed or aborted); not running or interrupted ones."""
        return sum(s.outcome not in ("running", "interrupted") for s in self.steps)

    def steps_with(self, outcome: str) -> int:
        return sum(s.outcome == outcome for s in self.steps)

    def stream(self, key: str) -> StreamState:
        for s in self.streams:
            if s.key == key:
                return s
        raise KeyError(f"no stream {key!r} (streams: {', '.join(s.key for s in self.streams) or 'none'})")

    def signal(self, key: str, label: str) -> SignalState:
        """Signal ``label`` (``"gyro x"``, ``"pressure"``) of stream ``key``."""
        for sig in self.stream(key).signals:
            if sig.label == label:
                return sig
        raise KeyError(f"stream {key!r} has no signal {label!r}")


class StepTracker:
    """What the whole event log says, built incrementally: each call reads only the events added
    since the previous one. The step list (from the step events), the operator prompt a live run
    waits on, the instrument traffic per instrument (``command``/``reply`` events, counted) and the
    positions of the last ``keep`` other events. :func:`watch` keeps one across refreshes;
    :func:`snapshot` makes a fresh one (reading every event once, in blocks, decoding only the
    step and prompt events) if none is given."""

    def __init__(self, keep: int = MAX_EVENTS) -> None:
        self.keep = keep
        self.scanned = 0  # events consumed so far
        self.steps: dict[int, StepState] = {}
        self.total: int | None = None
        self.prompt: PendingPrompt | None = None
        """The last ``prompt`` event while no answer, step end, abort or end of run followed it."""
        self.traffic: dict[str, TrafficSummary] = {}
        """Instrument -> its command and reply events so far (``polls`` filled in by :func:`snapshot`)."""
        self.recent: deque[int] = deque(maxlen=max(keep, 0))
        """Row numbers of the last ``keep`` events other than instrument traffic."""
        self.meaningful = 0
        """Events other than instrument traffic so far."""

    def update(self, events: h5py.Dataset, blob: h5py.Dataset, rows: int, blob_len: int) -> None:
        if rows < self.scanned:  # another file under the same name: start over
            self.__init__(self.keep)
        while self.scanned < rows:
            stop = min(rows, self.scanned + _EVENT_BLOCK)
            block = events[self.scanned : stop]
            kinds = block["kind"]
            empty = np.flatnonzero(kinds == b"")
            usable = int(empty[0]) if empty.size else len(block)  # rows the writer has not filled in yet
            picked = np.flatnonzero(np.isin(kinds[:usable], _PICKED_KINDS))
            ends = block["msg_off"][picked].astype(np.int64) + block["msg_len"][picked].astype(np.int64)
            ends += np.where(kinds[picked] == _PROMPT, block["data_len"][picked].astype(np.int64), 0)  # prompt data follows its message
            short = np.flatnonzero(ends > blob_len)
            if short.size:  # message not visible yet: stop before it, read it next time
                usable = int(picked[short[0]])
                picked = picked[: short[0]]
            messages = _read_messages(blob, blob_len, [(int(block["msg_off"][i]), int(block["msg_len"][i])) for i in picked])
            prompts = [i for i in picked if kinds[i] == _PROMPT]
            data = dict(zip(prompts, _read_messages(blob, blob_len, [(int(block["data_off"][i]), int(block["data_len"][i])) for i in prompts])))
            for i, msg in zip(picked, messages):
                self._apply(block[i], msg, data.get(i, ""))
            self._count(block[:usable], self.scanned)
            self.scanned += usable
            if usable < len(block):
                break

    def _count(self, block: np.ndarray, first: int) -> None:
        """Traffic per instrument and the positions of the other events, for ``block`` (rows from ``first``)."""
        traffic = np.isin(block["kind"], _TRAFFIC_KINDS)
        sel = block[traffic]
        for src in np.unique(sel["source"]):
            mine = sel[sel["source"] == src]
            name = bytes(src).decode("utf-8", errors="replace")
            tr = self.traffic.setdefault(name, TrafficSummary(name))
            commands = int(np.count_nonzero(mine["kind"] == _COMMAND))
            tr.commands += commands
            tr.replies += len(mine) - commands
            t0, t1 = float(mine["t_s"].min()), float(mine["t_s"].max())
            tr.t_first_s = t0 if tr.t_first_s is None else min(tr.t_first_s, t0)
            tr.t_last_s = t1 if tr.t_last_s is None else max(tr.t_last_s, t1)
        others = np.flatnonzero(~traffic)
        self.meaningful += len(others)
        if self.recent.maxlen:
            self.recent.extend(first + int(i) for i in others[-self.recent.maxlen:])

    def _apply(self, row: np.void, message: str, data: str) -> None:
        kind = bytes(row["kind"])
        idx = int(row["step"])
        source = bytes(row["source"]).decode("utf-8", errors="replace")
        t = float(row["t_s"])
        if kind == _PROMPT:
            self.prompt = _pending(message, data, t, float(row["wall_unix"]), idx)
        elif kind not in _STEP_KINDS or kind == _STEP_END:
            self.prompt = None  # answered, step over, aborted or ended
        if kind == _RUN_START:
            m = re.search(r"(\d+) steps?\b", message)
            if m:
                self.total = int(m.group(1))
        elif kind == _STEP_START:
            self.steps.pop(idx, None)  # a repeated index replaces the earlier entry, at the end
            self.steps[idx] = StepState(idx, message, source, t)
        elif kind == _STEP_END:
            s = self.steps.get(idx)
            if s is None:
                s = self.steps[idx] = StepState(idx, "", source, None)
            s.outcome, s.detail = step_outcome(message)
            s.t_end_s = t


def _pending(message: str, data: str, t_s: float, wall_unix: float, step: int) -> PendingPrompt:
    """The :class:`PendingPrompt` of a ``prompt`` event (data: JSON with ``id`` and ``attempt``)."""
    try:
        info = json.loads(data) if data else {}
    except json.JSONDecodeError:
        info = {}
    info = info if isinstance(info, dict) else {}
    attempt = info.get("attempt", 1)
    return PendingPrompt(message, str(info.get("id", "")), attempt if isinstance(attempt, int) else 1, t_s, wall_unix, step)


# ---- reading ------------------------------------------------------------------------------------
def snapshot(
    path: Path,
    *,
    stale_after_s: float = STALE_AFTER_S,
    trend_window_s: float = TREND_WINDOW_S,
    trend_points: int = TREND_POINTS,
    max_events: int = MAX_EVENTS,
    now_unix: float | None = None,
    tracker: StepTracker | None = None,
) -> WatchState:
    """Read the run file at ``path`` once (complete, aborted, crashed or being written).

    ``stale_after_s`` (s of wall time): heartbeat age from which a ``running`` file reads ``stale``;
    a live run whose last operator prompt is not answered yet reads ``waiting``.
    ``trend_window_s`` (s of run time) and ``trend_points``: each signal's trend. ``max_events``:
    how many of the last events other than instrument traffic to return (at most the tracker's
    ``keep``). ``tracker`` carries the step list, prompt and traffic between calls (only new events
    are read). Raises :class:`InputError` if the file is not a readable bench run file.
    """
    path = Path(path)
    tracker = tracker if tracker is not None else StepTracker(keep=max_events)
    with _open_run(path) as (f, warnings):
        now = time.time() if now_unix is None else now_unix
        limit = _size_limit(path)
        attrs = {k: _plain(v) for k, v in f.attrs.items()}
        hb = read_heartbeat(f, limit)
        hb_unix, hb_run = float(hb[0]), float(hb[1])

        events_ds, blob_ds = event_datasets(f)
        n_events = _checked_rows(events_ds, limit)
        blob_len = _checked_rows(blob_ds, limit)
        tracker.update(events_ds, blob_ds, n_events, blob_len)
        events = _events_at(events_ds, blob_ds, blob_len, list(tracker.recent)[-max_events:] if max_events > 0 else [])

        streams = [
            _read_stream_tail(key, g, limit, trend_window_s, trend_points) for key, g in _stream_groups(f).items()
        ]

    status = str(attrs.get(layout.ATTR_STATUS, ""))
    age = now - hb_unix if math.isfinite(hb_unix) else None
    detail = ""
    if status == layout.STATUS_RUNNING:
        if age is None:
            status, detail = STATUS_STALE, "no valid heartbeat; the writer has probably crashed"
        elif age >= stale_after_s:
            status = STATUS_STALE
            detail = f"no heartbeat for {age:.0f} s (since {_iso(hb_unix)}); the writer has probably crashed"
        else:
            detail = f"heartbeat {max(age, 0.0):.1f} s ago"
            if tracker.prompt is not None:
                status = layout.STATUS_WAITING
                asked = max(now - tracker.prompt.wall_unix, 0.0)
                detail = f"waiting for operator: {tracker.prompt.text} (asked {asked:.0f} s ago); {detail}"
    elif status in FINAL_STATUSES:
        detail = f"ended {attrs.get(layout.ATTR_ENDED_UTC, '') or '?'}"
    polls = {s.key: s.rows for s in streams}
    traffic = [TrafficSummary(**{**vars(t), "polls": polls.get(layout.monitor_key(t.instrument), 0)}) for t in tracker.traffic.values()]
    times = [hb_run] + [e.t_s for e in events] + [s.t_last_s for s in streams if s.t_last_s is not None] + \
        [t.t_last_s for t in traffic if t.t_last_s is not None]
    times = [t for t in times if math.isfinite(t)]
    steps = [StepState(**vars(s)) for s in tracker.steps.values()]  # copies: the tracker keeps its own
    running = [s for s in steps if s.outcome == "running"]
    current = running[-1] if running else None
    if status not in _LIVE:  # a step left open by a closed or crashed run did not finish
        for s in running:
            s.outcome = "interrupted"
        current = None
    return WatchState(
        path=path,
        procedure=str(attrs.get(layout.ATTR_PROCEDURE_NAME, "")),
        status=status,
        status_detail=detail,
        mode=str(attrs.get(layout.ATTR_MODE, "")),
        started_utc=str(attrs.get(layout.ATTR_STARTED_UTC, "")),
        ended_utc=str(attrs.get(layout.ATTR_ENDED_UTC, "")),
        abort_reason=str(attrs.get(layout.ATTR_ABORT_REASON, "")),
        run_time_s=max(times) if times else 0.0,
        heartbeat_unix=hb_unix if math.isfinite(hb_unix) else None,
        heartbeat_age_s=age,
        steps=steps,
        steps_total=tracker.total,
        current_step=current,
        events=events,
        events_total=n_events,
        streams=streams,
        waiting_for=tracker.prompt if status == layout.STATUS_WAITING else None,
        traffic=traffic,
        events_meaningful=tracker.meaningful,
        trend_window_s=trend_window_s,
        warnings=list(warnings),
        read_at_unix=now,
    )


def _read_messages(blob: h5py.Dataset, blob_len: int, ranges: list[tuple[int, int]]) -> list[str]:
    """Messages ``blob[off:off+n]`` (utf-8), cut to what is visible; nearby ones read in one go."""
    ranges = [(off, max(0, min(n, blob_len - off))) if off < blob_len else (off, 0) for off, n in ranges]
    wanted = [(off, n) for off, n in ranges if n > 0]
    if not wanted:
        return ["" for _ in ranges]
    lo = min(off for off, _ in wanted)
    hi = max(off + n for off, n in wanted)
    if hi - lo <= _BLOB_SPAN:
        buf = np.asarray(blob[lo:hi], dtype=np.uint8).tobytes()
        raw = [buf[off - lo : off - lo + n] if n else b"" for off, n in ranges]
    else:
        raw = [np.asarray(blob[off : off + n], dtype=np.uint8).tobytes() if n else b"" for off, n in ranges]
    return [r.decode("utf-8", errors="replace") for r in raw]


def _events_at(events: h5py.Dataset, blob: h5py.Dataset, blob_len: int, rows: list[int]) -> list[EventRow]:
    """The events at row numbers ``rows`` (ascending), with their messages and data as far as visible."""
    if not rows:
        return []
    block = events[rows]
    block = block[block["kind"] != b""]  # rows extended but not written yet
    msgs = _read_messages(blob, blob_len, [(int(r["msg_off"]), int(r["msg_len"])) for r in block])
    data = [(int(r["data_off"]), int(r["data_len"])) for r in block]
    raw = [
        np.asarray(blob[off : min(off + n, blob_len)], dtype=np.uint8).tobytes() if n and off < blob_len else b""
        for off, n in data
    ]
    return [event_row(r, m, d) for r, m, d in zip(block, msgs, raw)]


def _read_stream_tail(key: str, g: h5py.Group, limit: int, window_s: float, points: int) -> StreamState:
    names = _column_order(g)
    cols = [n for n in names if n != layout.TIME]
    units = {n: _units(g[n]) for n in cols}
    n = min(_checked_rows(g[c], limit) for c in names)
    tds = g[layout.TIME]
    if n > 0:
        start = max(0, n - _TAIL_ROWS)
        tail = np.asarray(tds[start:n], dtype=np.float64)
        nonzero = np.flatnonzero(tail != 0.0)
        if nonzero.size and tail[-1] == 0.0:  # extended by the writer, data not visible yet
            n = start + int(nonzero[-1]) + 1
    if n == 0:
        return StreamState(key, 0, None, None, 0.0, units, {}, [])
    t_last = float(tds[n - 1])
    i0 = first_row_at_or_after(tds, t_last - window_s, 0, n - 1) if math.isfinite(t_last) else n - 1
    ir = first_row_at_or_after(tds, t_last - RATE_WINDOW_S, i0, n - 1) if math.isfinite(t_last) else n - 1
    t_ir = float(tds[ir])
    rate = (n - 1 - ir) / (t_last - t_ir) if n - 1 > ir and t_last > t_ir else None
    step = max(1, math.ceil((n - i0) / MAX_TREND_ROWS))
    t_w = np.asarray(tds[i0:n:step], dtype=np.float64)
    t0 = float(t_w[0])
    span = t_last - t0 if math.isfinite(t_last - t0) else 0.0
    points = max(1, min(points, len(t_w)))  # a short stream: one point per row, no gaps
    bins = _bin_index(t_w, t0, t_last, points)
    latest: dict[str, np.ndarray] = {}
    signals: list[SignalState] = []
    for c in cols:
        ds = g[c]
        last = np.asarray(ds[n - 1])
        latest[c] = last
        if c in HIDDEN_COLUMNS:
            continue
        integer = ds.dtype.kind in "biu"
        vals = np.asarray(ds[i0:n:step], dtype=np.float64).reshape(len(t_w), -1)
        flat = last.astype(np.float64).reshape(-1)
        labels = ["x", "y", "z"] if flat.size == 3 and ds.ndim == 2 else ([""] if flat.size == 1 else [f"[{i}]" for i in range(flat.size)])
        status = is_status_column(c)
        for j, label in enumerate(labels):
            column = vals[:, j]
            rows_seen = np.append(column[np.isfinite(column)], flat[j] if math.isfinite(flat[j]) else np.empty(0))
            if status:  # a bit field: the words seen, never a mean
                words = tuple(float(w) for w in np.unique(rows_seen)[:MAX_STATES + 1])
                signals.append(SignalState(c, label, units[c], float(flat[j]), True, np.full(points, np.nan), math.nan, math.nan,
                                           states=words))
                continue
            trend = _bin_means(column, bins, points)
            finite = trend[np.isfinite(trend)]
            signals.append(
                SignalState(
                    c, label, units[c], float(flat[j]), integer, trend,
                    float(finite.min()) if finite.size else math.nan, float(finite.max()) if finite.size else math.nan,
                    float(rows_seen.min()) if rows_seen.size else math.nan, float(rows_seen.max()) if rows_seen.size else math.nan,
                )
            )
    return StreamState(key, n, t_last, rate, span, units, latest, signals)


def _bin_index(t: np.ndarray, t0: float, t1: float, points: int) -> np.ndarray:
    """Time bin (0..points-1) of every row; a span of zero puts everything in the last bin."""
    if not (t1 > t0) or not math.isfinite(t1 - t0):
        return np.full(t.shape, points - 1, dtype=np.int64)
    idx = np.floor((t - t0) / (t1 - t0) * points)
    idx = np.where(np.isfinite(idx), idx, points - 1)
    return np.clip(idx, 0, points - 1).astype(np.int64)


def _bin_means(v: np.ndarray, bins: np.ndarray, points: int) -> np.ndarray:
    """Mean of the finite values in each bin, NaN for a bin without any; a single point when all rows
    fall at one instant."""
    ok = np.isfinite(v)
    sums = np.bincount(bins[ok], weights=v[ok], minlength=points)
    counts = np.bincount(bins[ok], minlength=points)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    if points > 0 and bins.size and int(bins.max()) == int(bins.min()):
        return means[-1:]  # one instant only: one point
    return means


# ---- rendering ----------------------------------------------------------------------------------
def sparkline(values: np.ndarray | list[float], lo: float | None = None, hi: float | None = None) -> str:
    """One character ▁..█ per value, scaled from ``lo`` to ``hi`` (default: the finite min and max);
    a blank for NaN; ``▄`` throughout when all values are equal."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    finite = np.isfinite(v)
    if not finite.any():
        return " " * v.size
    lo = float(v[finite].min()) if lo is None else lo
    hi = float(v[finite].max()) if hi is None else hi
    top = len(SPARK_CHARS) - 1
    if not hi > lo:
        idx = np.full(v.shape, top // 2 + 1 if top > 1 else 0)
    else:
        idx = np.clip(np.rint((np.where(finite, v, lo) - lo) / (hi - lo) * top), 0, top).astype(int)
    return "".join(SPARK_CHARS[i] if ok else " " for i, ok in zip(idx, finite))


def format_value(value: float, integer: bool = False, name: str = "") -> str:
    """A reading as text, without its units (:func:`bench.quantity_format.fmt_reading`): status
    words in hex, integers whole, other numbers with 5 significant digits."""
    return fmt_reading(value, "", name, integer=integer, digits=5)


_STATUS_STYLE = {
    layout.STATUS_RUNNING: "bold black on cyan", layout.STATUS_COMPLETED: "bold black on green",
    layout.STATUS_ABORTED: "bold white on red", layout.STATUS_FAILED: "bold white on red", STATUS_STALE: "bold black on yellow",
    layout.STATUS_WAITING: "bold white on magenta",
}
_OUTCOME_STYLE = {"passed": "green", "done": "green", "failed": "red", "aborted": "red", "interrupted": "yellow", "running": "cyan",
                  layout.OUTCOME_RECORDED: "blue"}
PANEL_CHROME = 4
"""Columns the panel takes around its content (border and padding, 2 each side)."""
COLUMN_GAP = 3
"""Blank columns between two columns of the readings table: 1 of padding each side and the (blank) divider."""
MIN_TREND_CHARS = 10
"""Narrowest trend worth showing next to min and max (characters); narrower drops min and max first."""
DEFAULT_WIDTH = 120
"""Width (characters) :func:`build` lays out for when none is given."""


def build(state: WatchState, width: int | None = None, height: int | None = None) -> RenderableType:
    """The view of ``state`` as one rich renderable for a terminal ``width`` characters wide (used
    by :func:`render` and the live display). Every reading keeps its value and units whole; the
    trend gets the columns left over (min and max go first on a narrow terminal).

    With a ``height`` (the terminal's rows, the live display) the view fits it: when the full
    layout is taller, the compact one shows every stream (vectors and channels of one kind on one
    row each), then as many of the last events as still fit, one line each; nothing is cut off
    below the screen."""
    width = width or DEFAULT_WIDTH
    full = _layout(state, width, compact=False, events=len(state.events), traffic=True)
    if height is None or _height(full, width) <= height:
        return full
    view = full
    for tight in (False, True):  # tight: no table header, the status and step lines one line each
        for k in range(len(state.events), -1, -1):
            view = _layout(state, width, compact=True, events=k, traffic=False, tight=tight)
            if _height(view, width) <= height:
                return view
    return view


def _height(renderable: RenderableType, width: int) -> int:
    """Rows ``renderable`` takes on a terminal ``width`` characters wide."""
    console = Console(width=width, record=False, file=_NullFile(), color_system=None)
    return len(console.render_lines(renderable, console.options.update(width=width), pad=False))


class _NullFile:
    def write(self, _text: str) -> int:
        return 0

    def flush(self) -> None:
        pass


def _layout(state: WatchState, width: int, *, compact: bool, events: int, traffic: bool, tight: bool = False) -> RenderableType:
    parts: list[RenderableType] = []
    loud = banner(state.mode)
    if loud:
        parts.append(Text(f" {loud} ", style="bold black on yellow"))
    head = Text()
    head.append(f" {state.status.upper()} ", style=_STATUS_STYLE.get(state.status, "bold reverse"))
    head.append(f"  {printable(state.procedure)}", style="bold")
    head.append(f"   run time {fmt_hms(state.run_time_s)}")
    if not compact:
        head.append(f" ({state.run_time_s:.1f} s)")
    if state.mode:
        head.append(f"   mode {mode_word(state.mode)}", style="dim")
    detail = Text(printable(state.status_detail), style={STATUS_STALE: "red", layout.STATUS_WAITING: "bold magenta"}.get(state.status, "dim"))
    if state.abort_reason:
        detail.append(f"   abort reason: {printable(state.abort_reason)}", style="red")
    step = _step_line(state)
    if tight:
        for line in (head, detail, step):
            line.no_wrap, line.overflow = True, "ellipsis"
    parts += [head, detail, step]
    for w in state.warnings:
        parts.append(Text(f"warning: {printable(w)}", style="yellow"))
    if state.read_error:
        parts.append(Text(f"refresh failed, showing the last good read: {printable(state.read_error)}", style="yellow"))
    parts.extend(_readings(state, width - PANEL_CHROME, compact=compact, header=not tight))
    if events > 0 or not compact:
        parts.append(_events_table(state, events, one_line=compact, traffic_below=traffic and bool(state.traffic)))
    if traffic and state.traffic:
        parts.append(Text("instrument traffic (kept for replay): " + "; ".join(printable(t.describe()) for t in state.traffic), style="dim"))
    title = Text.assemble("bench watch ", (printable(state.path.name), "dim"))
    return Panel(Group(*parts), title=title, title_align="left", box=box.ROUNDED, padding=(0, 1), width=width)


def render(state: WatchState, console: Console) -> None:
    """Print the view of ``state`` for the console's width: status and run time, current step, key
    readings with trends, last events, instrument traffic."""
    console.print(build(state, console.width))


def _step_line(state: WatchState) -> Text:
    t = Text()
    total = f"/{state.steps_total}" if state.steps_total is not None else ""
    cur = state.current_step
    if cur is not None:
        t.append(f"step {cur.index + 1}{total}  ", style="bold")
        t.append(printable(cur.name or "?"), style="bold cyan")
        t.append(f" ({printable(cur.type)})" if cur.type else "")
        if cur.t_start_s is not None:
            t.append(f"  started at {fmt_hms(cur.t_start_s)}, running {fmt_hms(max(state.run_time_s - cur.t_start_s, 0.0))}")
    elif state.steps:
        last = state.steps[-1]
        t.append("last step  " if state.status not in _LIVE else "between steps; last  ", style="bold")
        t.append(f"{last.index + 1}{total} {printable(last.name)} ")
        t.append(last.outcome, style=_OUTCOME_STYLE.get(last.outcome, ""))
        if last.detail:
            t.append(f": {last.detail}")
    else:
        t.append("no step started yet", style="dim")
    counts = [f"{state.steps_done}{total} finished"]
    for outcome in ("failed", "aborted", "interrupted"):
        k = state.steps_with(outcome)
        if k:
            counts.append(f"{k} {outcome}")
    t.append("   steps: " + ", ".join(counts), style="red" if state.steps_with("failed") or state.steps_with("aborted") else "")
    return t


def resample(values: np.ndarray, points: int) -> np.ndarray:
    """``values`` in ``points`` bins (each the mean of its finite values, NaN if none); unchanged
    when it has no more than ``points`` values."""
    v = np.asarray(values, dtype=np.float64)
    if points <= 0:
        return v[:0]
    if v.size <= points:
        return v
    out = np.full(points, np.nan)
    for i, chunk in enumerate(np.array_split(v, points)):
        finite = chunk[np.isfinite(chunk)]
        if finite.size:
            out[i] = finite.mean()
    return out


@dataclass
class _Row:
    """One reading as text: label, value, units, min, max, and its trend (or, for a status word, the
    words seen, in ``note``)."""

    label: str
    value: str
    units: str
    lo: str
    hi: str
    trend: np.ndarray
    note: str = ""


def _states_note(sig: SignalState) -> str:
    words = [fmt_reading(w, "", sig.column) for w in sig.states[:MAX_STATES]]
    more = f" (+{len(sig.states) - MAX_STATES} more)" if len(sig.states) > MAX_STATES else ""
    return ("seen: " + ", ".join(words) + more) if len(words) > 1 else ("steady" if words else "")


def _reading_rows(stream: StreamState) -> list[_Row]:
    rows = []
    prev = ""
    for sig in stream.signals:
        label = sig.label if sig.column != prev else f"{' ' * len(sig.column)} {sig.component}"
        prev = sig.column
        lo = format_value(sig.low, sig.integer, sig.column) if math.isfinite(sig.low) else ""
        hi = format_value(sig.high, sig.integer, sig.column) if math.isfinite(sig.high) else ""
        rows.append(_Row(label, format_value(sig.value, sig.integer, sig.column), unit_text(sig.units), lo, hi, sig.trend,
                         _states_note(sig) if is_status_column(sig.column) else ""))
    return rows


_CHANNEL = re.compile(r"^([A-Za-z_]+?)(\d+)$")


def _compact_rows(stream: StreamState) -> list[_Row]:
    """One row per column: a vector's components side by side (``+0.012 -0.004 +5.001``), and the
    numbered channels of one kind and unit (``ch101..ch104``) together; scalars keep their trend."""
    rows: list[_Row] = []
    by_column: dict[str, list[SignalState]] = {}
    for sig in stream.signals:
        by_column.setdefault(sig.column, []).append(sig)
    pending: list[SignalState] = []

    def flush() -> None:
        if len(pending) >= 2:
            label = f"{pending[0].column}..{pending[-1].column}"
            rows.append(_Row(label, " ".join(format_value(s.value, s.integer, s.column) for s in pending), unit_text(pending[0].units),
                             "", "", np.nanmean([s.trend for s in pending], axis=0) if all(s.trend.size for s in pending) else np.empty(0)))
        elif pending:
            rows.extend(_reading_rows(StreamState(stream.key, 0, None, None, 0.0, {}, {}, pending)))
        pending.clear()

    for column, sigs in by_column.items():
        m = _CHANNEL.match(column)
        if len(sigs) == 1 and m and not is_status_column(column):
            if pending and (_CHANNEL.match(pending[0].column).group(1) != m.group(1) or pending[0].units != sigs[0].units):  # type: ignore[union-attr]
                flush()
            pending.append(sigs[0])
            continue
        flush()
        if len(sigs) > 1:
            values = " ".join(fmt_number(x.value, 4) if not x.integer else format_value(x.value, True, column) for x in sigs)
            rows.append(_Row(column, values, unit_text(sigs[0].units), "", "", np.empty(0)))
        else:
            rows.extend(_reading_rows(StreamState(stream.key, 0, None, None, 0.0, {}, {}, sigs)))
    flush()
    return rows


def _readings(state: WatchState, width: int, *, compact: bool = False, header: bool = True) -> list[RenderableType]:
    """Per stream a header line (key, rows, rate, last row) and a table of its signals, all tables
    with the same column widths: label, value and units whole, then the trend in what is left of
    ``width`` (characters), min and max only when the trend still gets :data:`MIN_TREND_CHARS`.
    ``compact``: one row per column (:func:`_compact_rows`), no blank line between streams;
    ``header``: the column headings above the first table."""
    if not state.streams:
        return [Text("no streams", style="dim")]
    by_stream = [(s, _compact_rows(s) if compact else _reading_rows(s)) for s in state.streams]
    rows = [r for _, rs in by_stream for r in rs]
    window = f"{state.trend_window_s / 60:g} min" if state.trend_window_s >= 60 else f"{state.trend_window_s:g} s"
    w = {name: max([len(head)] + [len(getattr(r, name)) for r in rows])
         for name, head in (("label", "reading"), ("value", "value"), ("units", "units"), ("lo", "min"), ("hi", "max"))}
    fixed = w["label"] + w["value"] + w["units"] + 2 * COLUMN_GAP
    trend = width - fixed - COLUMN_GAP - (w["lo"] + w["hi"] + 2 * COLUMN_GAP)
    extremes = trend >= MIN_TREND_CHARS and not compact
    if not extremes:
        trend = width - fixed - COLUMN_GAP
    trend = min(trend, TREND_POINTS)
    trend_head = next((h for h in (f"trend, last {window}", f"last {window}", "trend") if len(h) <= trend), "")
    out: list[RenderableType] = []
    for i, (s, rs) in enumerate(by_stream):
        head = Text(("\n" if i and not compact else "") + printable(s.key), style="bold")
        head.append(f"  {s.rows:,} rows", style="dim")
        if s.rate_hz is not None:
            head.append(f"  {fmt_quantity(s.rate_hz, 'Hz', 4)}", style="dim")
        if s.rows == 0 or s.t_last_s is None:
            head.append("  no rows yet", style="dim")
        else:
            lag = state.run_time_s - s.t_last_s
            info = f"  last row {fmt_hms(s.t_last_s)}" + (f", {fmt_seconds_behind(lag)} behind" if lag >= 0.05 else "")
            if s.trend_span_s < 0.95 * state.trend_window_s and not compact:
                info += f", trend {s.trend_span_s:.0f} s"
            head.append(info, style="dim")
        out.append(head)
        if not rs:
            continue
        t = Table(box=box.SIMPLE_HEAD, show_header=i == 0 and header, padding=(0, 1), pad_edge=False, show_edge=False, expand=False)
        t.add_column("reading", no_wrap=True, width=w["label"])
        t.add_column("value", justify="right", no_wrap=True, width=w["value"])
        t.add_column("units", no_wrap=True, width=w["units"])
        if trend > 0:
            t.add_column(trend_head, no_wrap=True, width=trend, overflow="ellipsis")
        if extremes:
            t.add_column("min", justify="right", no_wrap=True, width=w["lo"])
            t.add_column("max", justify="right", no_wrap=True, width=w["hi"])
        for r in rs:
            cells: list[RenderableType] = [Text(printable(r.label)), Text(r.value), Text(printable(r.units), style="dim")]
            if trend > 0:
                cells.append(Text(printable(r.note), style="dim") if r.note else Text(sparkline(resample(r.trend, trend)), style="cyan"))
            if extremes:
                cells += [Text(r.lo), Text(r.hi)]
            t.add_row(*cells)
        out.append(t)
    return out


def fmt_seconds_behind(lag_s: float) -> str:
    """How far a stream's last row lags the run: ``0.4 s``, ``1:17:55``."""
    return f"{lag_s:.1f} s" if lag_s < 60 else fmt_hms(lag_s)


def _events_table(state: WatchState, shown: int, one_line: bool = False, traffic_below: bool = True) -> Table:
    from bench.event_text import event_text

    events = state.events[-shown:] if shown > 0 else []
    what = "instrument traffic summarised below" if traffic_below else "instrument traffic not listed"
    t = Table(title=f"last {len(events)} of {state.events_meaningful:,} events ({what})", title_justify="left",
              box=box.SIMPLE_HEAD, padding=(0, 1), pad_edge=False, show_edge=False, show_header=not one_line)
    t.add_column("run time", justify="right", no_wrap=True, min_width=max([8] + [len(fmt_hms(e.t_s)) for e in events]))
    t.add_column("kind", no_wrap=True, min_width=len(layout.EVENT_STEP_START))
    t.add_column("source", no_wrap=True, max_width=16, overflow="ellipsis")
    t.add_column("step", justify="right", no_wrap=True)
    t.add_column("message", overflow="ellipsis" if one_line else "fold", no_wrap=one_line, ratio=1)
    for e in events:
        style = "red" if e.kind in ("error", "fault", "abort") else ("bold" if e.kind in (layout.EVENT_STEP_START, layout.EVENT_STEP_END) else "")
        t.add_row(fmt_hms(e.t_s), Text(printable(e.kind), style=style), Text(printable(e.source)), str(e.step + 1) if e.step >= 0 else "",
                  Text(event_text(e.kind, e.source, e.message)))
    return t


# ---- watching -----------------------------------------------------------------------------------
def watch(
    path: Path,
    console: Console,
    *,
    interval_s: float = 1.0,
    once: bool = False,
    max_updates: int | None = None,
    wait_s: float | None = None,
    stale_after_s: float = STALE_AFTER_S,
    max_events: int = MAX_EVENTS,
) -> int:
    """Show the run file at ``path``: once (``once=True``), or refreshed every ``interval_s`` (s)
    with a live display until the run ends (completed, aborted or failed: the final state stays on
    screen) or Ctrl-C. ``max_updates`` stops after that many reads (tests). A file that does not
    exist, or has not started recording, is waited for up to ``wait_s`` s (default 30 s when
    watching, 0 with ``once``). Returns ``EXIT_OK``; raises :class:`InputError` (one line) for a file
    that is not a readable bench run file, or when refreshes keep failing for ``READ_RETRY_S``.
    """
    path = Path(path)
    if not interval_s > 0:
        raise InputError(f"the refresh interval must be > 0 s, got {interval_s!r}", None, "--interval")
    wait = (0.0 if once else WAIT_FOR_FILE_S) if wait_s is None else float(wait_s)
    tracker = StepTracker(keep=max_events)
    read = lambda: snapshot(path, stale_after_s=stale_after_s, max_events=max_events, tracker=tracker)  # noqa: E731
    with ctrl_c_noted() as ctrl_c:
        try:
            return _watch(path, console, read, ctrl_c, interval_s=interval_s, once=once, max_updates=max_updates, wait_s=wait)
        except KeyboardInterrupt:
            return EXIT_OK


def _watch(path: Path, console: Console, read, ctrl_c: CtrlC, *, interval_s: float, once: bool, max_updates: int | None,
           wait_s: float) -> int:
    """The body of :func:`watch`; ends at the run's end, after ``max_updates`` reads, or at a Ctrl-C
    that a finaliser swallowed (``ctrl_c.pressed``, checked after each refresh)."""
    state = _first_read(path, console, wait_s, read, ctrl_c)
    if once or state.final or (max_updates is not None and max_updates <= 1):
        render(state, console)
        return EXIT_OK
    updates = 1
    failing_since: float | None = None
    with Live(build(state, console.width, console.height), console=console, auto_refresh=False, transient=False) as live:
        next_at = time.monotonic() + interval_s
        while max_updates is None or updates < max_updates:
            time.sleep(max(0.0, next_at - time.monotonic()))
            next_at = max(next_at + interval_s, time.monotonic())
            try:
                state = read()
                failing_since = None
            except InputError as exc:
                now = time.monotonic()
                failing_since = now if failing_since is None else failing_since
                if now - failing_since >= READ_RETRY_S:
                    raise
                state.read_error = exc.one_line()
            updates += 1
            live.update(build(state, console.width, console.height), refresh=True)  # the size again: the terminal may have been resized
            if state.final or ctrl_c.pressed:
                break
    return EXIT_OK


def _first_read(path: Path, console: Console, wait_s: float, read, ctrl_c: CtrlC) -> WatchState:
    """First snapshot; waits up to ``wait_s`` for a file that does not exist or is still being set up
    (a Ctrl-C a finaliser swallowed ends the wait: ``KeyboardInterrupt`` again)."""
    deadline = time.monotonic() + wait_s
    told = False
    while True:
        if ctrl_c.pressed:
            raise KeyboardInterrupt
        if path.exists():
            try:
                return read()
            except InputError as exc:
                if not any(r in exc.message for r in _WAIT_REASONS) or time.monotonic() >= deadline:
                    raise
                reason = "recording to start"
        elif time.monotonic() >= deadline:
            waited = f" (waited {wait_s:g} s for it to appear)" if wait_s > 0 else ""
            raise _unreadable(path, f"no such file{waited}")
        else:
            reason = "it to appear"
        if not told:
            console.print(f"waiting up to {wait_s:g} s for {printable(path)}: waiting for {printable(reason)} …", style="dim", markup=False)
            told = True
        time.sleep(min(0.2, max(0.0, deadline - time.monotonic())))
