"""A stream's column over a run-time range, reduced to what a plot of ``px`` pixels can show.

The browser never receives a whole stream: :func:`decimate` returns, per pixel column of the
requested time range, the first run time, the minimum and the maximum of each component (a
min/max envelope: no spike is lost, however many rows a pixel covers), or the rows themselves when
there are no more than :data:`RAW_FACTOR` per pixel. :func:`xy_pairs` gives the means of two
channels over common time bins, for X–Y plots.

Reading is bounded: the rows of the range are found by binary search on the monotonic ``time``
column (O(log n) point reads), and a range of many rows per pixel is reduced from a per-file cache
of block statistics (:data:`BLOCK_ROWS` rows per block: first time, min, max, sum, count), built
once per column and extended with the new rows of a live file. A request then reads only the
partial blocks at its two edges. Units: run times in s.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from bench.errors import InputError
from bench.record import layout
from bench.record.reader import _checked_rows, _column_order, first_row_at_or_after, _open_run, _size_limit, _stream_groups, _units

BLOCK_ROWS = 64
"""Rows per block of the cached statistics."""
RAW_FACTOR = 2
"""At most this many rows per pixel are sent as they are; more are reduced to per-pixel min/max."""
BLOCKS_FROM_ROWS_PER_PX = 2 * BLOCK_ROWS
"""From this many rows per pixel on, whole blocks come from the cache (the raw reads are at most
this many rows per pixel)."""
READ_ROWS = 1 << 18
"""Rows read at once while building the block cache."""
MAX_PX = 8192
CACHE_ENTRIES = 128
HIDDEN_COLUMNS = ("counter", "board_time")
"""Bookkeeping columns of the sensor board, not offered as channels (as in ``bench watch``)."""


def component_labels(shape: tuple[int, ...]) -> list[str]:
    """Labels of the components of a column whose rows have ``shape``: ``[""]`` for a scalar,
    ``x, y, z`` for a 3-vector, ``[0]``, ``[1]``… otherwise."""
    size = int(np.prod(shape)) if shape else 1
    if not shape or size == 1:
        return [""]
    if shape == (3,):
        return ["x", "y", "z"]
    return [f"[{i}]" for i in range(size)]


def channels(f: h5py.File) -> list[dict[str, Any]]:
    """Every plottable column of every stream: ``key``, ``column``, ``units``, ``components``."""
    out = []
    for key, g in _stream_groups(f).items():
        for name in _column_order(g):
            if name == layout.TIME or name in HIDDEN_COLUMNS or g[name].dtype.kind not in "biuf":
                continue
            out.append({"key": key, "column": name, "units": _units(g[name]), "components": component_labels(g[name].shape[1:])})
    return out


@dataclass
class _Blocks:
    """Statistics of the first ``rows`` rows, ``BLOCK_ROWS`` rows per block (components last)."""

    t_first: np.ndarray
    vmin: np.ndarray
    vmax: np.ndarray
    vsum: np.ndarray
    count: np.ndarray

    @property
    def rows(self) -> int:
        return len(self.t_first) * BLOCK_ROWS


@dataclass
class Bins:
    """Per-bin statistics: ``t`` first run time in the bin (s), ``vmin``/``vmax``/``vsum``/``count``
    per component (shape ``(bins, components)``); ``rows`` in the range; ``raw``: one bin per row."""

    t: np.ndarray
    vmin: np.ndarray
    vmax: np.ndarray
    vsum: np.ndarray
    count: np.ndarray
    rows: int
    raw: bool
    rows_read: int


class StreamCache:
    """Block statistics per (file, stream, column), least recently used dropped beyond
    :data:`CACHE_ENTRIES`; thread-safe. ``rows_read`` counts the rows read from files (benchmarks)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._blocks: OrderedDict[tuple, _Blocks] = OrderedDict()
        self.rows_read = 0

    def blocks(self, ident: tuple, tds: h5py.Dataset, vds: h5py.Dataset, n: int) -> _Blocks:
        """The statistics of every whole block of the first ``n`` rows, extended as needed."""
        with self._lock:
            have = self._blocks.pop(ident, None)
        width = int(np.prod(vds.shape[1:])) if vds.ndim > 1 else 1
        if have is None:
            empty = np.empty((0, width))
            have = _Blocks(np.empty(0), empty, empty.copy(), empty.copy(), np.empty((0, width), dtype=np.int64))
        whole = n // BLOCK_ROWS * BLOCK_ROWS
        parts = [have]
        start = have.rows
        while start < whole:
            stop = min(whole, start + READ_ROWS)
            t = np.asarray(tds[start:stop], dtype=np.float64)
            v = np.asarray(vds[start:stop], dtype=np.float64).reshape(len(t), width)
            self.rows_read += stop - start
            nb = len(t) // BLOCK_ROWS
            vb = v.reshape(nb, BLOCK_ROWS, width)
            finite = np.isfinite(vb)
            parts.append(_Blocks(t[::BLOCK_ROWS].copy(), np.fmin.reduce(vb, axis=1), np.fmax.reduce(vb, axis=1),
                                 np.where(finite, vb, 0.0).sum(axis=1), finite.sum(axis=1)))
            start = stop
        if len(parts) > 1:
            have = _Blocks(*(np.concatenate([getattr(p, a) for p in parts]) for a in ("t_first", "vmin", "vmax", "vsum", "count")))
        with self._lock:
            self._blocks[ident] = have
            while len(self._blocks) > CACHE_ENTRIES:
                self._blocks.popitem(last=False)
        return have


def _complete_rows(tds: h5py.Dataset, n: int) -> int:
    """Rows whose time is written: a live writer extends datasets before it fills them (zeros)."""
    if n == 0:
        return 0
    start = max(0, n - 64)
    tail = np.asarray(tds[start:n], dtype=np.float64)
    nonzero = np.flatnonzero(tail != 0.0)
    if tail[-1] == 0.0 and nonzero.size:
        return start + int(nonzero[-1]) + 1
    return n


def _bin_of(t: np.ndarray, t0: float, t1: float, px: int) -> np.ndarray:
    if not t1 > t0:
        return np.zeros(t.shape, dtype=np.int64)
    return np.clip(np.floor((t - t0) / (t1 - t0) * px), 0, px - 1).astype(np.int64)


def _reduce(bins: np.ndarray, t: np.ndarray, vmin: np.ndarray, vmax: np.ndarray, vsum: np.ndarray,
            count: np.ndarray) -> tuple[np.ndarray, ...]:
    """Fold rows (or blocks) with ascending bin numbers into one entry per occupied bin."""
    if len(bins) == 0:
        w = vmin.shape[1]
        return np.empty(0), np.empty((0, w)), np.empty((0, w)), np.empty((0, w)), np.empty((0, w), dtype=np.int64)
    starts = np.flatnonzero(np.diff(bins, prepend=bins[0] - 1))
    return (t[starts], np.fmin.reduceat(vmin, starts, axis=0), np.fmax.reduceat(vmax, starts, axis=0),
            np.add.reduceat(vsum, starts, axis=0), np.add.reduceat(count, starts, axis=0))


def _raw_stats(t: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, ...]:
    finite = np.isfinite(v)
    return t, v, v, np.where(finite, v, 0.0), finite.astype(np.int64)


def column_bins(f: h5py.File, path: Path, key: str, column: str, t0: float | None, t1: float | None, px: int,
                cache: StreamCache) -> tuple[Bins, dict[str, Any]]:
    """Statistics of ``key``/``column`` over run times ``t0``..``t1`` (s; None: the stream's first or
    last row) in ``px`` bins, and the stream's description (``units``, ``components``, ``rows``,
    ``t_first_s``, ``t_last_s``, ``t0_s``, ``t1_s``). :class:`InputError` for an unknown stream or column."""
    groups = _stream_groups(f)
    if key not in groups:
        raise InputError(f"no stream {key!r} (streams: {', '.join(groups) or 'none'})")
    g = groups[key]
    if column == layout.TIME or column not in _column_order(g):
        raise InputError(f"stream {key!r} has no column {column!r}")
    limit = _size_limit(path)
    tds, vds = g[layout.TIME], g[column]
    if vds.dtype.kind not in "biuf":
        raise InputError(f"column {column!r} of {key!r} is not numeric")
    n = _complete_rows(tds, min(_checked_rows(tds, limit), _checked_rows(vds, limit)))
    width = int(np.prod(vds.shape[1:])) if vds.ndim > 1 else 1
    info: dict[str, Any] = {"key": key, "column": column, "units": _units(vds), "components": component_labels(vds.shape[1:]),
                            "rows": n, "t_first_s": None, "t_last_s": None}
    empty = Bins(np.empty(0), *(np.empty((0, width)) for _ in range(3)), np.empty((0, width), dtype=np.int64), 0, True, 0)
    if n == 0:
        info.update(t0_s=t0, t1_s=t1)
        return empty, info
    t_first, t_last = float(tds[0]), float(tds[n - 1])
    info.update(t_first_s=t_first, t_last_s=t_last)
    lo_t = t_first if t0 is None or not math.isfinite(t0) else t0
    hi_t = t_last if t1 is None or not math.isfinite(t1) else t1
    if hi_t < lo_t:
        lo_t, hi_t = hi_t, lo_t
    info.update(t0_s=lo_t, t1_s=hi_t)
    i0 = first_row_at_or_after(tds, lo_t, 0, n)
    i1 = first_row_at_or_after(tds, float(np.nextafter(hi_t, math.inf)), i0, n)
    m = i1 - i0
    if m <= 0:
        return empty, info
    if m <= RAW_FACTOR * px:
        t = np.asarray(tds[i0:i1], dtype=np.float64)
        v = np.asarray(vds[i0:i1], dtype=np.float64).reshape(m, width)
        cache.rows_read += m
        return Bins(*_raw_stats(t, v), m, True, m), info
    if m < BLOCKS_FROM_ROWS_PER_PX * px:
        t = np.asarray(tds[i0:i1], dtype=np.float64)
        v = np.asarray(vds[i0:i1], dtype=np.float64).reshape(m, width)
        cache.rows_read += m
        stats = _raw_stats(t, v)
        return Bins(*_reduce(_bin_of(t, lo_t, hi_t, px), *stats), m, False, m), info
    before = cache.rows_read
    blocks = cache.blocks((str(path), path.stat().st_ino, key, column), tds, vds, n)
    b0 = -(-i0 // BLOCK_ROWS)
    b1 = min(i1 // BLOCK_ROWS, len(blocks.t_first))
    head_end = min(b0 * BLOCK_ROWS, i1)
    pieces = []
    for a, b in ((i0, head_end), (max(b1 * BLOCK_ROWS, head_end), i1)):  # the partial blocks at both edges
        if b > a:
            t = np.asarray(tds[a:b], dtype=np.float64)
            v = np.asarray(vds[a:b], dtype=np.float64).reshape(b - a, width)
            cache.rows_read += b - a
            pieces.append((a, _raw_stats(t, v)))
    if b1 > b0:
        sl = slice(b0, b1)
        pieces.append((b0 * BLOCK_ROWS, (blocks.t_first[sl], blocks.vmin[sl], blocks.vmax[sl], blocks.vsum[sl], blocks.count[sl])))
    pieces.sort(key=lambda p: p[0])
    t, vmin, vmax, vsum, count = (np.concatenate([p[1][i] for p in pieces]) for i in range(5))
    return Bins(*_reduce(_bin_of(t, lo_t, hi_t, px), t, vmin, vmax, vsum, count), m, False, cache.rows_read - before), info


def _clean(a: np.ndarray) -> list:
    """Floats for JSON: NaN and inf as None."""
    return [None if not math.isfinite(x) else x for x in a.tolist()]


def decimate(path: Path, key: str, column: str, *, t0: float | None, t1: float | None, px: int,
             cache: StreamCache) -> dict[str, Any]:
    """The JSON of a plot of ``key``/``column`` over ``t0``..``t1`` (s) ``px`` pixels wide: ``t`` (s,
    first time in each pixel, or of each row when ``raw``), and per component ``min`` and ``max``
    (equal when ``raw``), with the stream's units, rows and span. :class:`InputError` for a bad request."""
    px = int(px)
    if not 1 <= px <= MAX_PX:
        raise InputError(f"px must be 1..{MAX_PX}, got {px}")
    with _open_run(path) as (f, _warnings):
        bins, info = column_bins(f, path, key, column, t0, t1, px, cache)
    with np.errstate(invalid="ignore"):
        vmin = np.where(bins.count > 0, bins.vmin, np.nan)
        vmax = np.where(bins.count > 0, bins.vmax, np.nan)
    return {**info, "raw": bins.raw, "points": int(len(bins.t)), "rows_in_range": bins.rows, "rows_read": bins.rows_read,
            "t": _clean(bins.t), "series": [{"label": c, "min": _clean(vmin[:, j]), "max": _clean(vmax[:, j])}
                                            for j, c in enumerate(info["components"])]}


def _means(f: h5py.File, path: Path, key: str, column: str, component: int, t0: float | None, t1: float | None,
           n: int, cache: StreamCache) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    bins, info = column_bins(f, path, key, column, t0, t1, n, cache)
    if not 0 <= component < len(info["components"]):
        raise InputError(f"column {column!r} of {key!r} has no component {component}")
    lo, hi = info["t0_s"], info["t1_s"]
    idx = _bin_of(bins.t, lo if lo is not None else 0.0, hi if hi is not None else 0.0, n)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(bins.count[:, component] > 0, bins.vsum[:, component] / np.maximum(bins.count[:, component], 1), np.nan)
    return idx, mean, info


def xy_pairs(path: Path, x: tuple[str, str, int], y: tuple[str, str, int], *, t0: float | None, t1: float | None,
             points: int, cache: StreamCache) -> dict[str, Any]:
    """Channel ``y`` against channel ``x`` (each ``(stream key, column, component index)``): the means of
    both over ``points`` common time bins of ``t0``..``t1`` (s; None: the span of ``x``), bins where both
    have a value. Returns ``x``, ``y`` lists with both channels' units."""
    points = int(points)
    if not 1 <= points <= MAX_PX:
        raise InputError(f"points must be 1..{MAX_PX}, got {points}")
    with _open_run(path) as (f, _warnings):
        ix, mx, infx = _means(f, path, *x, t0, t1, points, cache)
        iy, my, infy = _means(f, path, *y, infx["t0_s"], infx["t1_s"], points, cache)
    gx = np.full(points, np.nan)
    gy = np.full(points, np.nan)
    gx[ix] = mx
    gy[iy] = my
    ok = np.isfinite(gx) & np.isfinite(gy)
    return {"x": _clean(gx[ok]), "y": _clean(gy[ok]), "x_units": infx["units"], "y_units": infy["units"],
            "points": int(ok.sum()), "t0_s": infx["t0_s"], "t1_s": infx["t1_s"]}
