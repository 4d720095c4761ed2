"""Compare a replay with its source: command sequences per link, step outcomes, checks, streams,
how the run ended. Tolerances (docs/replay.md): times 1e-6 s (dry-run sources only; hardware
sources are compared in order, not in time); numbers |a - b| <= 1e-9 * max(|a|, |b|) + 1e-12.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from typing import Collection

import numpy as np

from bench.errors import InputError
from bench.terminal_text import printable
from bench.record import layout
from bench.record.reader import RunSummary, Traffic, open_run_file

TIME_TOL_S = 1e-6
REL_TOL = 1e-9
ABS_TOL = 1e-12
_NUM = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


@dataclass
class Divergence:
    t_s: float
    what: str  # command | step | check | stream | end
    step: int
    step_name: str
    instrument: str
    expected: str
    got: str

    def render(self) -> str:
        """Three lines; texts from the run file with their control characters escaped (a crafted
        message cannot forge lines of the report)."""
        where = f"step {self.step + 1} ({printable(self.step_name)})" if self.step >= 0 else "outside steps"
        inst = f", instrument {printable(self.instrument)}" if self.instrument else ""
        return (f"first divergence at run time {self.t_s:.3f} s, {where}{inst}: {printable(self.what)}\n"
                f"  expected: {printable(self.expected)}\n  got:      {printable(self.got)}")


def close(a: float, b: float) -> bool:
    if a is None or b is None:
        return a is b
    try:
        a, b = float(a), float(b)
    except (TypeError, ValueError, OverflowError):  # not numbers (a crafted check event): equal or not
        return a == b
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return abs(a - b) <= REL_TOL * max(abs(a), abs(b)) + ABS_TOL


def same_text(a: str, b: str) -> bool:
    """Equal, or equal up to numbers that are close (messages print measured values)."""
    if a == b:
        return True
    if _NUM.sub("#", a) != _NUM.sub("#", b):
        return False
    na, nb = _NUM.findall(a), _NUM.findall(b)
    return len(na) == len(nb) and all(close(float(x), float(y)) for x, y in zip(na, nb))


def _cmd_text(name: str, data: bytes, step: int, t: float) -> str:
    return f"{name} [{data.hex(' ')}] in step {step + 1} at {t:.6f} s"


def commands_by_link(traffic: Traffic, drivers: dict[str, str], keys: list | None = None) -> dict[tuple[str, str], Commands]:
    """The commands of ``traffic`` per (instrument, link) (:func:`bench.replay.recording.link_of`),
    in order; instruments not in ``drivers`` (instrument -> driver name) left out. ``keys``: the
    events' links if already worked out (:func:`bench.replay.recording.link_keys`)."""
    from bench.replay.recording import link_keys

    rows: dict[tuple[str, str], list[int]] = {}
    for i, (key, kind) in enumerate(zip(link_keys(traffic, drivers) if keys is None else keys, traffic.kind)):
        if key is not None and kind == "command":
            got = rows.get(key)
            if got is None:
                got = rows[key] = []
            got.append(i)
    return {key: Commands([traffic.t_s[i] for i in ii], [traffic.step[i] for i in ii], [traffic.message[i] for i in ii],
                          [traffic.data[i] for i in ii]) for key, ii in rows.items()}


@dataclass
class Commands:
    """The commands of one link, column-wise: run times (s), steps, names, bytes."""

    t_s: list[float]
    step: list[int]
    message: list[str]
    data: list[bytes]

    def __len__(self) -> int:
        return len(self.t_s)

    def same(self, other: "Commands", n: int, timed: bool) -> bool:
        """Whether the first ``n`` commands of both are the same (names, bytes, steps, and run
        times within :data:`TIME_TOL_S` if ``timed``): whole lists compared at once."""
        if len(self) < n or len(other) < n:
            return False
        if self.message[:n] != other.message[:n] or self.data[:n] != other.data[:n] or self.step[:n] != other.step[:n]:
            return False
        return not timed or not n or bool(np.all(np.abs(np.subtract(self.t_s[:n], other.t_s[:n])) <= TIME_TOL_S))


def compare(src: RunSummary, rep: RunSummary, src_traffic: Traffic, rep_traffic: Traffic, drivers: dict[str, str], *,
            timed: bool, prefix_only: bool, src_keys: list | None = None) -> list[Divergence]:
    """Every divergence, ordered by run time. ``src_traffic``/``rep_traffic``: the commands of
    source and replay (:func:`bench.record.reader.read_traffic`); ``src_keys``: the links of the
    source's events if known. ``timed``: compare event times (dry-run sources). ``prefix_only``:
    the source stopped without an end (crashed): compare what it holds."""
    names = {s.index: s.name for s in src.steps} | {s.index: s.name for s in rep.steps}
    out: list[Divergence] = []

    a, b = commands_by_link(src_traffic, drivers, src_keys), commands_by_link(rep_traffic, drivers)
    none = Commands([], [], [], [])
    for key in sorted(set(a) | set(b)):
        ca, cb = a.get(key, none), b.get(key, none)
        n = len(ca) if prefix_only else max(len(ca), len(cb))
        if ca.same(cb, n, timed):
            continue
        for i in range(n):
            x = i if i < len(ca) else None
            y = i if i < len(cb) else None
            if x is not None and y is not None:
                if (ca.message[x] == cb.message[y] and ca.data[x] == cb.data[y] and ca.step[x] == cb.step[y]
                        and (not timed or abs(ca.t_s[x] - cb.t_s[y]) <= TIME_TOL_S)):
                    continue
            ref, j = (ca, x) if x is not None else (cb, y)
            out.append(Divergence(
                ref.t_s[j] if x is None or y is None else min(ca.t_s[x], cb.t_s[y]), "command", ref.step[j], names.get(ref.step[j], ""),
                " ".join(key).strip(),
                _cmd_text(ca.message[x], ca.data[x], ca.step[x], ca.t_s[x]) if x is not None else "(no more commands recorded)",
                _cmd_text(cb.message[y], cb.data[y], cb.step[y], cb.t_s[y]) if y is not None else "(the replay sent no such command)"))

    sa, sb = {s.index: s for s in src.steps}, {s.index: s for s in rep.steps}
    for i in sorted(set(sa) | set(sb)):
        x, y = sa.get(i), sb.get(i)
        if prefix_only and (x is None or x.outcome in ("interrupted", "running")):
            continue
        if x is not None and y is not None:
            # a check step's detail is its check's value and limits as text: the check itself (its
            # recorded data) is compared below, so runs recorded with older wording still replay
            ok = (x.type, x.name, x.outcome) == (y.type, y.name, y.outcome) and (x.type == "check" or same_text(x.detail, y.detail))
            if ok and timed:
                ok = all(p is None and q is None or (p is not None and q is not None and abs(p - q) <= TIME_TOL_S)
                         for p, q in ((x.t_start_s, y.t_start_s), (x.t_end_s, y.t_end_s)))
            if ok:
                continue
        ref = x or y
        desc = (lambda s: f"{s.type} {s.name!r} {s.outcome}" + (f": {s.detail}" if s.detail else "")
                + f" ({s.t_start_s:.6f}..{(s.t_end_s if s.t_end_s is not None else float('nan')):.6f} s)" if s else "(not executed)")
        out.append(Divergence(ref.t_end_s if ref.t_end_s is not None else (ref.t_start_s or 0.0), "step outcome", i, ref.name, "", desc(x), desc(y)))

    def checks(summary: RunSummary) -> dict[str, tuple[float, dict]]:
        d = {}
        for e in summary.events:
            if e.kind == "check":
                try:
                    info = json.loads(e.data.decode("utf-8"))
                except (UnicodeDecodeError, json.JSONDecodeError, RecursionError):
                    info = {}
                d[e.source] = (e.t_s, e.step, info if isinstance(info, dict) else {})
        return d

    ca, cb = checks(src), checks(rep)
    for name in sorted(set(ca) | set(cb)):
        x, y = ca.get(name), cb.get(name)
        if prefix_only and x is None:
            continue
        if x is not None and y is not None:
            p, q = x[2], y[2]
            if all(p.get(k) == q.get(k) for k in ("signal", "statistic", "window", "outcome", "min", "max", "reference", "basis")) \
                    and close(p.get("value"), q.get("value")):
                continue
        ref = x or y
        fmt = (lambda c: f"{c[2].get('outcome')}: {c[2].get('statistic')} of {c[2].get('signal')} = {c[2].get('value')!r}" if c else "(no such check)")
        out.append(Divergence(ref[0], f"check {name}", ref[1], names.get(ref[1], ""), "", fmt(x), fmt(y)))

    if not prefix_only and (src.status, src.abort_reason) != (rep.status, rep.abort_reason):
        t = max(max((e.t_s for e in rep.events), default=0.0), max(rep_traffic.t_s, default=0.0))
        out.append(Divergence(t, "end of run", -1, "", "", f"{src.status}" + (f": {src.abort_reason}" if src.abort_reason else ""),
                              f"{rep.status}" + (f": {rep.abort_reason}" if rep.abort_reason else "")))
    out.sort(key=lambda d: (d.t_s, 0 if d.what == "command" else 1))
    return out


def compare_streams(src_path, rep_path, src: RunSummary, rep: RunSummary, prefix_only: bool, timed: bool = True, *,
                    keys: Collection[str] | None = None, got: str = "replay") -> list[Divergence]:
    """Rows of every recorded stream (only ``keys`` when given): same count (a prefix for crashed
    sources) and values within the tolerance (NaN equals NaN); per stream, the first column that
    differs, named with its first differing row, run time and values. Read in blocks so long
    recordings stay cheap in memory. ``timed`` False (a wall-clock source): the ``time`` column, a
    wall-clock artefact, is not compared. ``got``: what ``rep_path`` is, in messages (``replay``,
    ``re-simulation``). Both files are opened as every reader opens them (bounded on a damaged
    file); :class:`InputError` naming the source when its data cannot be read."""
    out = []
    keys_b = {s.key: s for s in rep.streams}
    todo = []
    for s in src.streams:
        if keys is not None and s.key not in keys:
            continue
        r = keys_b.get(s.key)
        instrument = layout.split_stream_key(s.key)[0]
        if r is None:
            out.append(Divergence(s.t_start_s or 0.0, f"stream {s.key}", -1, "", instrument, f"{s.rows} rows", f"(no such stream in the {got})"))
            continue
        rows = s.rows
        if prefix_only and not timed:
            rows = min(s.rows, r.rows)  # a wall-clock source cut by a crash: where the cut falls is not reproducible
        elif (s.rows != r.rows and not prefix_only) or r.rows < s.rows:
            out.append(Divergence(s.t_end_s or 0.0, f"stream {s.key}", -1, "", instrument, f"{s.rows} rows", f"{r.rows} rows ({got})"))
            continue
        todo.append((s.key, instrument, rows))
    if not todo:
        return out
    with open_run_file(src_path) as fa, open_run_file(rep_path) as fb:
        for key, instrument, rows in todo:
            d = _first_difference(src_path, fa[layout.stream_path(key)], fb[layout.stream_path(key)], key, rows, timed, got)
            if d is not None:
                t, column, row, a, b = d
                out.append(Divergence(t, f"stream {key} column {column}", -1, "", instrument,
                                      f"{_value(a)} (recorded, row {row} at run time {t:.6f} s)", f"{_value(b)} ({got})"))
    return out


def _first_difference(src_path, ga, gb, key: str, rows: int, timed: bool, got: str):
    """``(t_s, column, row, recorded value, other value)`` of the first row (over the columns in
    order, the first column that differs) where the stream groups ``ga`` (source) and ``gb``
    differ beyond the tolerance; None when they agree."""
    block = 1 << 18
    for name in ga:
        if name == layout.TIME and not timed:
            continue
        if name not in gb:
            return (float(ga[layout.TIME][0]) if rows else 0.0), name, 0, "(a column)", f"(no such column in the {got})"
        for i in range(0, rows, block):
            j = min(i + block, rows)
            rb = gb[name][i:j]
            try:
                ra = ga[name][i:j]
                if ra.dtype == rb.dtype and ra.shape == rb.shape and np.array_equal(ra, rb):
                    continue  # equal values (a faithful replay): no tolerance needed
                xa = np.asarray(ra, dtype=float)
            except Exception as exc:  # noqa: BLE001 - a damaged chunk (checksum) or an unreadable dtype
                raise InputError(f"{src_path}: cannot be replayed: stream {key} column {name} rows {i}..{j - 1} cannot be read "
                                 f"({' '.join(str(exc).split())[:200]})") from None
            xb = np.asarray(rb, dtype=float)
            if xa.shape != xb.shape:
                return float(ga[layout.TIME][i]), name, i, f"shape {xa.shape[1:]}", f"shape {xb.shape[1:]}"
            if not np.allclose(xa, xb, rtol=REL_TOL, atol=ABS_TOL, equal_nan=True):
                bad = int(np.nonzero(~np.isclose(xa, xb, rtol=REL_TOL, atol=ABS_TOL, equal_nan=True).reshape(len(xa), -1).all(axis=1))[0][0])
                return float(ga[layout.TIME][i + bad]), name, i + bad, xa[bad], xb[bad]
    return None


def _value(v) -> str:
    """A stream value as a message shows it: plain numbers (``35.12``, ``[0.1, -0.2, 9.81]``)."""
    if isinstance(v, str):
        return v
    a = np.asarray(v, dtype=float)
    return f"{a.item():.10g}" if a.ndim == 0 else "[" + ", ".join(f"{x:.10g}" for x in a.ravel()) + "]"
