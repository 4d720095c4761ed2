"""Clocks: everything that waits asks the clock.

Run time is measured in seconds (s) since the clock was created. A :class:`WallClock` follows
``time.monotonic``; a :class:`VirtualClock` only moves when somebody waits on it, so a dry-run
advances as fast as the simulators can produce data ("an hour of procedure in seconds").
The protocol and the wall clock live in ``drivers.clock`` (drivers wait on them too).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

from drivers.clock import Clock, WallClock

__all__ = ["Clock", "WallClock", "VirtualClock"]


@dataclass
class _Lane:
    """One thread taking part in a lockstep phase: asleep until ``wake`` (run time, s), or busy
    (``wake`` None) since run time ``busy_t`` and wall time ``busy_wall`` (``time.monotonic``, s)."""

    busy_t: float
    busy_wall: float = field(default_factory=time.monotonic)
    wake: float | None = None


class VirtualClock:
    """Run time that advances only when waited on.

    Normally one runner owns it and each wait moves run time at once. Waits are atomic (a lock), so
    threads that wait outside a lockstep phase never move time backwards.

    **Lockstep phase** (the parallel safe state of an abort, ``bench/runner/safe_state.py``): the
    threads :meth:`enrol`-ed wait for one another as in a discrete-event simulation, so that no
    thread's long wait (a reconnection's 8-s backoff) jumps time under another thread's short
    ones (a rate table polling its deceleration every 50 ms). A thread enrolled that waits
    registers its wake time and blocks; the scheduler (the thread that enrolled them, see
    :meth:`advance_lockstep`) moves run time to the earliest wake, then :meth:`release` lets
    every thread whose time has come go on. A thread that is busy (talking to an instrument in
    wall time) holds run time back only as long as it is busy: run time may pass its busy start by
    the wall time it has been busy, as on hardware, where the others go on while one waits for an
    answer. A thread that leaves (done, or detached after missing its deadline) holds nothing back.
    """

    virtual = True

    def __init__(self, start_s: float = 0.0) -> None:
        self._t = float(start_s)
        self._released = self._t
        self._cond = threading.Condition()
        self._lanes: dict[threading.Thread, _Lane] = {}

    def now(self) -> float:
        return self._t

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            with self._cond:
                self._wait_until(self._t + float(seconds))

    def sleep_until(self, t_s: float) -> None:
        with self._cond:
            self._wait_until(float(t_s))

    def _wait_until(self, t_s: float) -> None:
        """Wait until run time ``t_s`` (s); the lock is held."""
        lane = self._lanes.get(threading.current_thread())
        if lane is None:
            if t_s > self._t:
                self._t = t_s
            return
        if t_s <= self._released:
            return
        lane.wake = t_s
        self._cond.notify_all()  # the scheduler may be waiting for every lane to be asleep
        while self._lanes.get(threading.current_thread()) is lane and self._released < t_s:
            self._cond.wait()
        # detached while waiting (past its deadline): the wait ends without moving run time under
        # the others; its later waits move it as outside a phase
        lane.wake, lane.busy_t, lane.busy_wall = None, self._t, time.monotonic()

    # ---- lockstep phase ---------------------------------------------------------------------
    def enrol(self, thread: threading.Thread) -> None:
        """Make ``thread`` (before it starts) wait in lockstep with the other enrolled threads."""
        with self._cond:
            self._released = self._t
            self._lanes[thread] = _Lane(self._t)

    def leave(self, thread: threading.Thread) -> None:
        """``thread`` no longer takes part (it is done, or detached after missing its deadline): a
        wait it is in ends at once, without moving run time; its later waits move run time as
        outside a phase."""
        with self._cond:
            if self._lanes.pop(thread, None) is not None:
                self._cond.notify_all()

    def advance_lockstep(self, wait_wall_s: float) -> float:
        """Scheduler: wait up to ``wait_wall_s`` (wall s) for every enrolled thread to be asleep,
        then move run time to the earliest wake, or, while some are busy, to no later than each busy
        thread's start plus the wall time it has been busy. Returns run time (s). The threads whose
        time has come go on at :meth:`release` (the scheduler first does what is due then, e.g.
        ends injected faults)."""
        with self._cond:
            if self._lanes and any(lane.wake is None for lane in self._lanes.values()):
                self._cond.wait(wait_wall_s)
            now_wall = time.monotonic()
            bounds = [lane.wake if lane.wake is not None else lane.busy_t + (now_wall - lane.busy_wall)
                      for lane in self._lanes.values()]
            if bounds and min(bounds) > self._t:
                self._t = min(bounds)
            return self._t

    def release(self) -> None:
        """Let the enrolled threads waiting for a run time up to now go on."""
        with self._cond:
            if self._t > self._released:
                self._released = self._t
                self._cond.notify_all()
