"""The safe state of an abort: every instrument told at once, each within its own deadline.

On an abort (:meth:`bench.runner.engine.Runner._abort_path`) one thread per instrument calls its
driver's ``safe_state()``; the moving axes (rate table, stepper bench) are started first, then the
rest. A link fault is retried through a reconnection (:meth:`LabMonitor.restore_link`) bounded by
the instrument's ``reconnect_timeout`` *and* what is left of its own deadline (config
``safe_state_timeout``, default its kind's ``safe_state_timeout_s``), so one
unreachable instrument never delays another. The main thread watches the deadlines; an instrument
still not confirmed when its deadline passes is reported as such (its thread is told to stop trying
and left behind as a daemon: a driver call cannot be interrupted, and every driver wait is bounded).

Threads and the run file: only the main thread records and shows. Worker threads leave what they
did (told, confirmed at, error; a reconnection's ``fault`` and ``gap``) in their job and a queue;
the main thread records the events (``safe_state`` when confirmed, ``error`` when failed or past its
deadline; timing in the message and the JSON data) and prints the progress messages as they come.
The instruments' traffic events, which the drivers emit from the worker threads, go through a lock
(:class:`SerialEvents`) while the phase lasts.

Virtual time (dry-runs): the threads wait on the lab's :class:`~bench.clock.VirtualClock` in
lockstep (discrete-event: run time moves to the earliest wake of the threads, as the main thread
schedules it, and the injected faults due then are applied before the threads go on), so a
reconnection's 8-s backoff never jumps run time under the table's 50-ms deceleration polls and
every deadline holds in run time exactly as on hardware. A thread busy talking to an instrument in
wall time lets run time pass only by the wall time it has been busy. Each deadline is also bounded
in wall time (the same number of seconds), so a stuck simulator or driver cannot hold the abort.
"""

from __future__ import annotations

import json
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable

from bench.clock import VirtualClock
from bench.config import DEFAULT_SAFE_STATE_TIMEOUT_S
from bench.errors import DeviceFault, InstrumentError
from bench.kinds import registry
from bench.runner.monitor import describe, gap_message

if TYPE_CHECKING:  # pragma: no cover
    from bench.record import RunRecorder
    from bench.runner.engine import Runner

Record = Callable[..., None]
"""``record(kind, source, message, *, t_s=None, data=b"")``: one event into the run file."""

WATCH_PERIOD_WALL_S = 0.02
"""How often the main thread looks at the deadlines on the wall clock (s)."""
LOCKSTEP_WAIT_WALL_S = 0.002
"""In virtual time, how long the scheduler waits for a busy thread before letting run time pass by
the wall time it has been busy (s)."""


def deadline_of(run: "Runner", name: str) -> float:
    """Deadline of instrument ``name``'s safe state (s): its config's, else its driver's default."""
    lab = run.lab
    if name in lab.safe_state_timeouts:
        return lab.safe_state_timeouts[name]
    kind = registry.get(lab.kinds.get(name, getattr(lab.instruments[name], "kind", "")))
    return kind.safe_state_timeout_s if kind is not None else DEFAULT_SAFE_STATE_TIMEOUT_S


def _moves(kind: str) -> bool:
    k = registry.get(kind)
    return k is not None and k.moves


def safe_state_order(names: list[str], kinds: dict[str, str]) -> list[str]:
    """``names`` with what moves first (``Kind.moves``: it can harm the unit soonest), each group in its own order."""
    return sorted(names, key=lambda n: not _moves(kinds.get(n, "")))


def safe_state_waves(names: list[str], powered_by: dict[str, tuple[str, str]]) -> list[list[str]]:
    """``names`` (in order) in waves told one after the other: a supply after everything it powers
    has ended its own safe state (the unit is told while it still has power; then its power goes off);
    everything else in the first wave."""
    left = list(names)
    waves: list[list[str]] = []
    while left:
        wave = [n for n in left if not any(c in left for c, (supplier, _) in powered_by.items() if supplier == n and c != n)]
        if not wave:  # a loop of supplies: tell the rest at once
            wave = list(left)
        waves.append(wave)
        left = [n for n in left if n not in wave]
    return waves


@dataclass
class SafeStateOutcome:
    """What one instrument was told on an abort and when it confirmed.

    ``outcome``: ``confirmed`` (``told`` is the driver's account), ``failed`` (``error``) or
    ``missed`` (its deadline passed first). Times: ``t_told_s`` and ``t_end_s`` run time (s),
    ``wall_s`` wall time from the telling to the end (s)."""

    name: str
    deadline_s: float
    t_told_s: float
    outcome: str = "missed"
    told: str = ""
    error: str = ""
    t_end_s: float = 0.0
    wall_s: float = 0.0
    t_abort_s: float | None = None
    """Run time of the abort when the instrument was told later (a supply, after what it powers)."""

    @property
    def after_s(self) -> float:
        """Run time from the telling to the end (s)."""
        return self.t_end_s - self.t_told_s

    @property
    def late(self) -> bool:
        """Ended after its deadline (in run time or wall time)."""
        return max(self.after_s, self.wall_s) > self.deadline_s

    def message(self) -> str:
        """The event's message: what was told, or why not, with the timing."""
        within = f"deadline {self.deadline_s:g} s"
        after = "the abort" if self.t_abort_s is None else \
            f"it was told, {self.t_told_s - self.t_abort_s:.2f} s after the abort once what it powers had ended"
        if self.outcome == "confirmed":
            when = f"confirmed {self.after_s:.2f} s after {after}" + (f", beyond its {within}" if self.late else f" ({within})")
            return f"{self.told or 'safe state reached'}; {when}"
        if self.outcome == "failed":
            return f"safe state failed {self.after_s:.2f} s after {after} ({within}): {self.error}"
        return f"safe state not confirmed within its {within} (told {self.t_told_s:.2f} s; still trying when given up)"

    def data(self) -> bytes:
        """The event's JSON data: outcome, told, error, deadline_s, t_told_s, t_end_s, wall_s."""
        return json.dumps({"outcome": self.outcome, "told": self.told, "error": self.error, "deadline_s": self.deadline_s,
                           "t_told_s": self.t_told_s, "t_end_s": self.t_end_s, "wall_s": round(self.wall_s, 6),
                           "late": self.late}).encode()


def _on_terminal(show: Callable[..., None], *args: Any) -> None:
    """Show something; a terminal gone (SIGHUP: the ssh session dropped) must not stop the safe state."""
    try:
        show(*args)
    except OSError:
        pass


class DeadlinePassed(InstrumentError):
    """Raised in a worker thread told to stop trying (its deadline passed)."""


@dataclass
class _Job:
    name: str
    deadline_s: float
    t_told_s: float
    cancel: threading.Event = field(default_factory=threading.Event)
    result: SafeStateOutcome | None = None
    """Set once by the worker when it ends (the main thread reads it only after ``done``)."""
    done: threading.Event = field(default_factory=threading.Event)
    thread: threading.Thread | None = None

    def check_cancelled(self) -> None:
        if self.cancel.is_set():
            raise DeadlinePassed(f"{self.name}: safe-state deadline of {self.deadline_s:g} s passed; reconnection stopped")


@dataclass
class _Note:
    """Something a worker did for the run file and the terminal (recorded by the main thread)."""

    kind: str
    source: str
    message: str
    shown: str
    t_s: float
    data: bytes = b""


class SerialEvents:
    """Puts the recorder's ``event`` behind a lock while worker threads may call it (the drivers'
    traffic hooks record every frame); after :meth:`close`, events from threads other than the
    owner's (a driver still busy past its deadline) are dropped and counted, never written while
    the main thread finalises the file."""

    def __init__(self, rec: "RunRecorder"):
        self.rec = rec
        self.lock = threading.Lock()
        self.plain: Callable[..., Any] = rec.event
        self.owner = threading.current_thread()
        self.open = True
        self.dropped = 0
        rec.event = self  # type: ignore[method-assign]  # an instance attribute shadows the method

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        with self.lock:
            if not self.open and threading.current_thread() is not self.owner:
                self.dropped += 1
                return None
            return self.plain(*args, **kwargs)

    def close(self, stragglers: bool) -> None:
        """End of the phase: the method is restored, unless threads are still busy (``stragglers``)."""
        with self.lock:
            self.open = False
            if not stragglers and self.rec.__dict__.get("event") is self:
                del self.rec.event


class SafeStatePhase:
    """Brings every instrument of ``run`` to its safe state at once; see the module docstring."""

    def __init__(self, run: "Runner", names: list[str], record: Record):
        self.run = run
        self.record = record
        """Records one event; never raises (the recorder may be what failed)."""
        self.names = safe_state_order(names, run.lab.kinds)
        self.deadlines = {n: deadline_of(run, n) for n in self.names}
        self.notes: queue.SimpleQueue[_Note] = queue.SimpleQueue()
        self.wake = threading.Event()
        self.lockstep = isinstance(run.clock, VirtualClock)
        self.t_abort: float | None = None
        """The abort's run time while a later wave is told (a supply after what it powers), else None."""

    def announcement(self) -> str:
        """One line: who is told, in which order, with which deadlines."""
        return "telling every instrument to go to its safe state at once (deadlines: " + \
            ", ".join(f"{n} {d:g} s" for n, d in self.deadlines.items()) + ")"

    def run_all(self) -> list[SafeStateOutcome]:
        """Tell every instrument, wait for each until it confirms, fails or its deadline passes;
        record and show each outcome as it comes. Returns the outcomes in the order told. A supply is
        told after what it powers (:func:`safe_state_waves`)."""
        out: list[SafeStateOutcome] = []
        t_abort = self.run.clock.now()
        for wave in safe_state_waves(self.names, getattr(self.run.lab, "powered_by", {})):
            out += self._run_wave(wave, t_abort)
        return out

    def _run_wave(self, names: list[str], t_abort: float) -> list[SafeStateOutcome]:
        run, clock = self.run, self.run.clock
        t0, wall0 = clock.now(), time.monotonic()
        self.t_abort = t_abort if t0 > t_abort else None
        jobs = [_Job(n, self.deadlines[n], t0) for n in names]
        outcomes: dict[str, SafeStateOutcome] = {}
        events = SerialEvents(run.rec)
        try:
            for job in jobs:
                job.thread = threading.Thread(target=self._work, args=(job, wall0), name=f"safe state {job.name}", daemon=True)
                if self.lockstep:
                    clock.enrol(job.thread)
            for job in jobs:
                job.thread.start()
            pending = list(jobs)
            while pending:
                self._record_notes()
                _on_terminal(run.flush_notices)
                for job in list(pending):
                    outcome = self._settled(job, t0, wall0)
                    if outcome is not None:
                        pending.remove(job)
                        outcomes[job.name] = outcome
                        self._record(outcome)
                if pending:
                    self._tick(pending)
        finally:
            for job in jobs:
                job.cancel.set()
                if self.lockstep and job.thread is not None:
                    clock.leave(job.thread)
            self._record_notes()
            events.close(stragglers=any(j.thread is not None and j.thread.is_alive() for j in jobs))
            if events.dropped:
                self.record("note", "runner", f"{events.dropped} traffic event(s) of instruments past their deadline not recorded")
        return [outcomes[j.name] for j in jobs if j.name in outcomes]

    def _settled(self, job: _Job, t0: float, wall0: float) -> SafeStateOutcome | None:
        """The job's outcome if it ended or its deadline passed (then it is told to stop), else None."""
        clock = self.run.clock
        if job.done.is_set() and job.result is not None:
            return job.result
        wall = time.monotonic() - wall0
        if wall <= job.deadline_s and clock.now() - t0 <= job.deadline_s:
            return None
        job.cancel.set()
        if self.lockstep and job.thread is not None:
            clock.leave(job.thread)  # its waits no longer hold run time back
        return SafeStateOutcome(job.name, job.deadline_s, t0, "missed", t_end_s=clock.now(), wall_s=wall, t_abort_s=self.t_abort)

    def _tick(self, pending: list[_Job]) -> None:
        """Let time pass until something may have changed: in virtual time, schedule the threads'
        waits (and apply the faults due, through the progress sink); on the wall clock, wait."""
        run, clock = self.run, self.run.clock
        waiting = "safe state: waiting for " + ", ".join(j.name for j in pending)
        if self.lockstep:
            t = clock.advance_lockstep(LOCKSTEP_WAIT_WALL_S)
            _on_terminal(run.progress.advance, t, waiting)
            clock.release()
        else:
            self.wake.wait(WATCH_PERIOD_WALL_S)
            self.wake.clear()
            _on_terminal(run.progress.advance, clock.now(), waiting)

    def _work(self, job: _Job, wall0: float) -> None:
        """Worker thread: tell instrument ``job.name`` to go safe; retry a link fault through a
        reconnection within its reconnect timeout and what is left of its deadline."""
        run, clock, name = self.run, self.run.clock, job.name
        try:
            try:
                told = run.lab.instruments[name].safe_state()
            except DeviceFault:
                raise
            except (InstrumentError, OSError) as exc:
                told = self._reconnect_and_retry(job, exc)
            result = SafeStateOutcome(name, job.deadline_s, job.t_told_s, "confirmed", told=str(told or ""), t_abort_s=self.t_abort)
        except Exception as exc:  # noqa: BLE001 - every outcome is reported, none may kill the phase
            result = SafeStateOutcome(name, job.deadline_s, job.t_told_s, "failed", error=describe(exc), t_abort_s=self.t_abort)
        finally:
            if self.lockstep:
                clock.leave(threading.current_thread())
        result.t_end_s, result.wall_s = clock.now(), time.monotonic() - wall0
        job.result = result
        job.done.set()
        self.wake.set()

    def _reconnect_and_retry(self, job: _Job, exc: BaseException) -> Any:
        run, clock, name = self.run, self.run.clock, job.name
        t_fault = clock.now()
        left = job.deadline_s - (t_fault - job.t_told_s)
        limit = min(run.monitor.reconnect_limit(name), left)
        why = " (its safe-state deadline)" if limit == left else ""
        self.notes.put(_Note("fault", name, f"link fault during the safe state: {describe(exc)}; reconnecting (up to {limit:.4g} s)",
                             f"{name}: link fault ({describe(exc)}); reconnecting for its safe state", t_fault))
        self.wake.set()
        attempts = run.monitor.restore_link(name, exc, limit, before_wait=job.check_cancelled, after_wait=lambda _n: None,
                                            restart_stream=False, why=why)
        t1 = clock.now()
        self.notes.put(_Note("gap", name, gap_message(name, t_fault, t1, attempts), f"{name}: link restored after {t1 - t_fault:.1f} s", t1,
                             json.dumps({"t_start_s": t_fault, "t_end_s": t1, "attempts": attempts}).encode()))
        self.wake.set()
        job.check_cancelled()
        return run.lab.instruments[name].safe_state()

    def _record_notes(self) -> None:
        while True:
            try:
                note = self.notes.get_nowait()
            except queue.Empty:
                return
            self.record(note.kind, note.source, note.message, t_s=note.t_s, data=note.data)
            _on_terminal(self.run.progress.message, note.shown)

    def _record(self, o: SafeStateOutcome) -> None:
        """One outcome into the run file (``safe_state`` or ``error``) and onto the terminal."""
        kind = "safe_state" if o.outcome == "confirmed" else "error"
        self.record(kind, o.name, o.message(), t_s=o.t_end_s, data=o.data())
        _on_terminal(self.run.progress.message, f"{o.name}: {o.message()}")
