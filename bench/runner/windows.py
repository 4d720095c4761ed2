"""Named recording windows and the statistics checks compute over them.

While a window is open, every sample of every signal that arrives (board frames, polled
readings) is folded into running sums: count, sum, sum of squares, min, max and the sums a
least-squares slope needs. Memory is constant per window and signal, whatever the run length, so
a check at the end of an 8-hour ramp costs nothing. Only the signals the procedure's checks name
are folded (the procedure is data: its checks are known before it runs); of the others a window
keeps the names it saw, for the message of a check that finds no data.
"""

from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass, field
from typing import Any, Collection

import numpy as np


@dataclass
class RunningStats:
    """Running statistics of one signal (time t in s, value y)."""

    n: int = 0
    s: float = 0.0
    ss: float = 0.0
    lo: float = math.inf
    hi: float = -math.inf
    st: float = 0.0
    stt: float = 0.0
    sty: float = 0.0
    t0: float | None = None

    def add_one(self, t: float, y: float) -> None:
        """One sample (plain floats: polled readings arrive one at a time)."""
        if not math.isfinite(y):
            return
        if self.t0 is None:
            self.t0 = t
        tt = t - self.t0
        self.n += 1
        self.s += y
        self.ss += y * y
        self.lo = min(self.lo, y)
        self.hi = max(self.hi, y)
        self.st += tt
        self.stt += tt * tt
        self.sty += tt * y

    def add(self, t: np.ndarray, y: np.ndarray) -> None:
        ok = np.isfinite(y)
        if not np.any(ok):
            return
        t, y = t[ok], y[ok]
        if self.t0 is None:
            self.t0 = float(t[0])
        tt = t - self.t0  # centred for numerical stability over long windows
        self.n += int(y.size)
        self.s += float(y.sum())
        self.ss += float((y * y).sum())
        self.lo = min(self.lo, float(y.min()))
        self.hi = max(self.hi, float(y.max()))
        self.st += float(tt.sum())
        self.stt += float((tt * tt).sum())
        self.sty += float((tt * y).sum())

    def value(self, statistic: str) -> float:
        """``mean``, ``std`` (sample), ``rms``, ``min``, ``max``, ``count`` or ``slope`` (units/s)."""
        if statistic == "count":
            return float(self.n)
        if self.n == 0:
            raise ValueError("no samples in the window")
        mean = self.s / self.n
        if statistic == "mean":
            return mean
        if statistic == "rms":
            return math.sqrt(self.ss / self.n)
        if statistic == "min":
            return self.lo
        if statistic == "max":
            return self.hi
        if statistic == "std":
            if self.n < 2:
                raise ValueError("a standard deviation needs at least 2 samples")
            return math.sqrt(max(self.ss - self.n * mean * mean, 0.0) / (self.n - 1))
        if statistic == "slope":
            den = self.n * self.stt - self.st * self.st
            if self.n < 2 or den <= 0:
                raise ValueError("a slope needs samples at 2 or more times")
            return (self.n * self.sty - self.st * self.s) / den
        raise ValueError(f"unknown statistic {statistic!r}")


@dataclass
class Window:
    name: str
    t_start_s: float
    meta: dict[str, Any] = field(default_factory=dict)
    t_end_s: float | None = None
    stats: dict[str, RunningStats] = field(default_factory=dict)
    seen: dict[str, None] = field(default_factory=dict)
    """Every signal fed while open, in order (folded into ``stats`` or not)."""

    @property
    def open(self) -> bool:
        return self.t_end_s is None


class Windows:
    """All windows of a run: opened and closed by record steps, fed by the runner."""

    def __init__(self, watched: Collection[str] | None = None) -> None:
        """``watched``: the signals whose statistics are kept (a check names them); None: all."""
        self.all: dict[str, Window] = {}
        self._open: list[Window] = []
        self.watched = None if watched is None else frozenset(watched)

    def start(self, name: str, t_s: float, meta: dict[str, Any] | None = None) -> Window:
        """Open window ``name`` at run time ``t_s``; a name used again starts a fresh window."""
        w = Window(name, t_s, dict(meta or {}))
        self.all[name] = w
        self._open.append(w)
        return w

    def end(self, name: str, t_s: float) -> None:
        w = self.all.get(name)
        if w is not None and w.open:
            w.t_end_s = t_s
            self._open.remove(w)

    @property
    def any_open(self) -> bool:
        return bool(self._open)

    def feed(self, signal: str, t: np.ndarray, y: np.ndarray) -> None:
        """Samples of ``signal`` (run times ``t`` s) into every open window."""
        fold = self.watched is None or signal in self.watched
        for w in self._open:
            w.seen[signal] = None
            if fold:
                w.stats.setdefault(signal, RunningStats()).add(np.asarray(t, dtype=float), np.asarray(y, dtype=float))

    def feed_one(self, signal: str, t: float, y: float) -> None:
        """One sample of ``signal`` at run time ``t`` (s) into every open window."""
        fold = self.watched is None or signal in self.watched
        for w in self._open:
            w.seen[signal] = None
            if fold:
                st = w.stats.get(signal)
                if st is None:
                    st = w.stats[signal] = RunningStats()
                st.add_one(t, y)

    def matching(self, pattern: str) -> list[Window]:
        """Closed or open windows whose name matches ``pattern`` (``*`` wildcards), in start order."""
        return sorted((w for n, w in self.all.items() if fnmatch.fnmatchcase(n, pattern)), key=lambda w: w.t_start_s)

    def statistic(self, signal: str, statistic: str, pattern: str) -> tuple[float, str]:
        """The value of a check and a short description of what it was computed from.

        ``scale_factor_error`` and ``bias`` fit mean(signal) = (1 + e)·rate + bias over the windows
        matching ``pattern`` that know their commanded rate (rate schedules set it); others need
        exactly one window.
        """
        windows = self.matching(pattern)
        if not windows:
            raise ValueError(f"no recording window matches {pattern!r} (windows: {', '.join(self.all) or 'none'})")
        if statistic in ("scale_factor_error", "bias"):
            pts = [(w.meta["rate_dps"], w.stats[signal].value("mean")) for w in windows
                   if "rate_dps" in w.meta and signal in w.stats and w.stats[signal].n]
            rates = {r for r, _ in pts}
            if len(rates) < 2:
                raise ValueError(f"a {statistic} needs windows at 2 or more commanded rates matching {pattern!r} with {signal} data")
            r = np.array([p[0] for p in pts])
            m = np.array([p[1] for p in pts])
            slope, intercept = np.polyfit(r, m, 1)
            value = slope - 1.0 if statistic == "scale_factor_error" else intercept
            return float(value), f"fit over {len(pts)} windows at {len(rates)} rates"
        if len(windows) != 1:
            raise ValueError(f"{statistic} needs one window; {pattern!r} matches {len(windows)}")
        w = windows[0]
        st = w.stats.get(signal)
        if st is None:
            raise ValueError(f"window {w.name!r} has no {signal} data (signals: {', '.join(w.seen) or 'none'})")
        return st.value(statistic), f"{st.n} samples in window {w.name!r}"
