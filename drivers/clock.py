"""The clock drivers wait on: the :class:`Clock` protocol and the :class:`WallClock`.

Drivers know nothing of ``bench``; ``bench.clock`` re-exports both and adds the ``VirtualClock``.
Everything that waits asks the clock.

Run time is measured in seconds (s) since the clock was created. A :class:`WallClock` follows
``time.monotonic``; a :class:`VirtualClock` only moves when somebody waits on it, so a dry-run
advances as fast as the simulators can produce data ("an hour of procedure in seconds").
"""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    """What the runner, drivers' transports and simulators need from a clock."""

    virtual: bool

    def now(self) -> float:
        """Run time in s."""

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` s of this clock's time (virtual clocks advance instantly)."""

    def sleep_until(self, t_s: float) -> None:
        """Wait until run time ``t_s`` s (no-op if already past)."""


class WallClock:
    """Run time from ``time.monotonic``; ``sleep`` really sleeps."""

    virtual = False

    def __init__(self) -> None:
        self._t0 = time.monotonic()

    def now(self) -> float:
        return time.monotonic() - self._t0

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)

    def sleep_until(self, t_s: float) -> None:
        self.sleep(t_s - self.now())
