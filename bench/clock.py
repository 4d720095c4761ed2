"""Clocks: everything that waits asks the clock.

Run time is measured in seconds (s) since the clock was created. A :class:`WallClock` follows
``time.monotonic``; a :class:`VirtualClock` only moves when somebody waits on it, so a dry-run
advances as fast as the simulators can produce data ("an hour of procedure in seconds").
The protocol and the wall clock live in ``drivers.clock`` (drivers wait on them too).
"""

from __future__ import annotations

from drivers.clock import Clock, WallClock

__all__ = ["Clock", "WallClock", "VirtualClock"]


class VirtualClock:
    """Run time that advances only when waited on. Not thread-safe: one runner owns it."""

    virtual = True

    def __init__(self, start_s: float = 0.0) -> None:
        self._t = float(start_s)

    def now(self) -> float:
        return self._t

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            self._t += float(seconds)

    def sleep_until(self, t_s: float) -> None:
        if t_s > self._t:
            self._t = float(t_s)
