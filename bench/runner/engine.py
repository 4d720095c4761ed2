"""Step interpreter with safe state on abort.

Outcomes: every step ends ``passed`` (a check held), ``failed`` (a check did not hold; the run
goes on and ends with exit code 1), ``recorded`` (a check without limits: value stored, no
verdict), ``done`` (an action), or ``aborted``. An instrument fault, a
recorder failure, an interlock trip, a step that cannot go on or an abort request (SIGINT/SIGTERM)
stops the run: every instrument is brought to its safe state, the run file is closed with status
``aborted`` and the reason.

While any step waits, the runner keeps the lab under watch (:meth:`Runner.wait_until`): polled
instruments are read at their poll interval and logged, streams are drained, interlocks are
evaluated, the run file is flushed, pause and abort requests are honoured.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from typing import Callable, Protocol

from bench.errors import BenchError, InstrumentError, RecorderError
from bench.lab import Lab
from bench.procedure import Procedure, Step
from bench.record import RunRecorder, layout
from bench.record.checks import check_counts, check_from_result, check_json, checks_verdict
from bench.record.summary_json import json_ready
from bench.runner import steps as step_handlers
from bench.runner.ingest import StreamIngest
from bench.runner.instruments import Polled, Streaming, link_baudrate
from bench.runner.monitor import InterlockTrip, LabMonitor, describe
from bench.runner.operator import Operator
from bench.runner.safe_state import SafeStatePhase
from bench.runner.steps import StepAbort
from bench.runner.windows import Windows

POLL_PERIOD_VIRTUAL_S = 5.0  # run time between stream polls in a dry-run (s): 500 frames per batch at 100 Hz
POLL_PERIOD_WALL_S = 0.1  # on the wall clock: keeps abort latency and progress updates short
PAUSED_TICK_WALL_S = 0.1  # a paused dry-run in virtual time looks at its flags this often (s of wall time)


class AbortRequested(BenchError):
    """Raised inside the runner when an abort was requested (signal, operator)."""


class Progress(Protocol):
    def start(self, procedure: Procedure, total_s: float) -> None: ...

    def step(self, n: int, total: int, step: Step) -> None: ...

    def advance(self, run_time_s: float, readings: str = "") -> None: ...

    def message(self, text: str) -> None: ...

    def stop(self, run_time_s: float) -> None: ...


@dataclass
class StepOutcome:
    index: int
    name: str
    type: str
    outcome: str
    message: str
    t_start_s: float
    t_end_s: float


@dataclass
class RunResult:
    status: str  # completed | aborted
    abort_reason: str
    outcomes: list[StepOutcome]
    run_time_s: float
    wall_time_s: float
    rows: dict[str, int] = field(default_factory=dict)
    stream_stats: dict[str, dict[str, int]] = field(default_factory=dict)
    checks: list[dict] = field(default_factory=list)

    @property
    def failed_steps(self) -> list[StepOutcome]:
        return [o for o in self.outcomes if o.outcome == "failed"]

    @property
    def ok(self) -> bool:
        """Completed with no failed step (checks without limits, ``recorded``, do not fail a run)."""
        return self.status == "completed" and not self.failed_steps

    @property
    def check_counts(self) -> dict[str, int]:
        """Checks and built-in tests by outcome: ``passed``, ``failed``, ``recorded`` (no limits, no
        verdict); the same steps the report and the catalogue judge the run by."""
        return check_counts(o.outcome for o in self.outcomes if o.type in ("check", "bit"))

    @property
    def verdict(self) -> str:
        """What the checks say, e.g. ``all 3 checks passed`` or ``3 checks recorded without limits; no verdict``."""
        return checks_verdict(self.check_counts)

    def as_json(self) -> dict:
        """The result as a JSON-ready mapping (``bench run --json``; fields in ``docs/run-file.md``):
        run and wall times in s, steps with 1-based ``step``, checks as ``bench inspect --json`` gives
        them, rows and link statistics per stream."""
        return json_ready({
            "status": self.status, "abort_reason": self.abort_reason, "ok": self.ok,
            "run_time_s": self.run_time_s, "wall_time_s": self.wall_time_s,
            "steps": [{"step": o.index + 1, "name": o.name, "type": o.type, "outcome": o.outcome, "detail": o.message,
                       "t_start_s": o.t_start_s, "t_end_s": o.t_end_s} for o in self.outcomes],
            "checks": [check_json(check_from_result(c, int(c.get("step", -1)), str(c["outcome"]))) for c in self.checks],
            "checks_summary": {**self.check_counts, "verdict": self.verdict},
            "streams": {name: {"rows": rows, **self.stream_stats.get(name, {})} for name, rows in self.rows.items()},
        })


class Runner:
    """Runs one procedure on one lab into one recorder."""

    def __init__(self, procedure: Procedure, lab: Lab, recorder: RunRecorder, progress: Progress, operator: Operator | None = None,
                 declared: dict[str, dict[str, str]] | None = None):
        self.procedure = procedure
        self.declared = declared or {}
        """Instrument name -> the identity its lab config declares, recorded next to what it reports."""
        self.lab = lab
        self.clock = lab.clock
        self.rec = recorder
        self.progress = progress
        self.operator = operator or Operator()
        self.abort_reason = ""
        self.current_step = -1
        self.outcomes: list[StepOutcome] = []
        self.windows = Windows({s.params.get("signal") for s in procedure.steps if s.type == "check"} - {None})
        """Recording windows; statistics kept for the signals the procedure's checks name."""
        self.ingest = StreamIngest(recorder, self.clock, self.windows, lambda: self.current_step)
        """The streaming instruments (sensor boards): frames into the run file and the windows."""
        self.monitor = LabMonitor(self)
        """The polled instruments, interlocks, the lab's safety envelope, link recovery."""
        self.results: dict[str, dict] = {}
        self.in_vacuum = False
        self.paused = False
        self.operator_name = "operator"
        """The run's operator (who answers at the terminal): set by ``start_run`` to the recorded name."""
        self.notices: list[str] = []
        """Messages from signal handlers, printed by the main loop (a handler must not render: it
        may interrupt the terminal library in the middle of its own work)."""
        self.operator_events: list[tuple[str, str, str, str]] = []
        """Operator actions taken elsewhere (:meth:`operator_event`), recorded by the runner's thread."""
        self.handlers: dict[str, Callable[["Runner", Step], tuple[str, str]]] = dict(step_handlers.HANDLERS)

    # ---- abort and pause ----------------------------------------------------------------------
    def request_abort(self, reason: str) -> None:
        """Ask the run to stop at the next check point (safe to call from a signal handler)."""
        if not self.abort_reason:
            self.abort_reason = reason

    def toggle_pause(self) -> None:
        """Pause or resume (safe to call from a signal handler). While paused, timed steps stop
        counting; polled instruments, streams and interlocks stay under watch."""
        self.paused = not self.paused

    def operator_event(self, action: str, origin: str, message: str = "", operator: str = "") -> None:
        """Record an operator action taken from another thread (the web station: ``action`` ``pause``,
        ``resume``, ``stop``; ``origin`` e.g. ``web 127.0.0.1``; ``operator`` the acting person's name)
        as an event ``control`` (source the origin, message JSON ``action``, ``origin``, ``operator``,
        ``message``). Only queued here: the runner's own thread writes it at its next check point, as
        h5py writes must stay on that thread."""
        self.operator_events.append((action, origin, message, operator))

    def check_abort(self) -> None:
        """Raise :class:`AbortRequested` if an abort was asked for (prints pending notices first)."""
        self.flush_notices()
        if self.abort_reason:
            raise AbortRequested(self.abort_reason)

    def flush_notices(self) -> None:
        """Print the messages signal handlers left (main thread only)."""
        while self.notices:
            self.progress.message(self.notices.pop(0))
        while self.operator_events:
            action, origin, message, operator = self.operator_events.pop(0)
            info = {"action": action, "origin": origin, **({"operator": operator} if operator else {}), "message": message}
            self._event(layout.EVENT_CONTROL, origin, json.dumps(info), step=self.current_step)

    # ---- run --------------------------------------------------------------------------------
    def prepare(self) -> None:
        """Identify every instrument, declare the streams, start the recorder (SWMR)."""
        for name, drv in self.lab.instruments.items():
            info = drv.identify()
            info.update(driver=drv.kind, port=self.lab.ports[name], mode=self.lab.mode, baudrate=link_baudrate(drv))
            info.update(self.declared.get(name, {}))
            if drv.streams and isinstance(drv, Streaming):
                if drv.compensation is not None:
                    info["compensation"] = drv.compensation.describe()
                self.rec.add_instrument(name, {k: str(v) for k, v in info.items()})
                self.ingest.declare(name, drv)
                continue
            self.rec.add_instrument(name, {k: str(v) for k, v in info.items()})
            if isinstance(drv, Polled):
                self.monitor.declare(name, drv)
            # else: an instrument without readings; its commands are recorded
        for lock in self.procedure.interlocks:
            inst = lock.signal.split(".", 1)[0]
            if inst not in self.lab.instruments:
                raise StepAbort(f"interlock {lock.name!r} watches {inst!r}, which is not open in this run")
        self.rec.start()
        self.rec.event("run_start", "runner", f"{self.procedure.name}: {len(self.procedure.steps)} steps, mode {self.lab.mode}", t_s=self.clock.now())
        # what a replay needs to re-execute the same procedure: parameter values in force and the
        # text of every called sub-procedure (the main text is in /texts)
        self.rec.event("procedure", "runner", self.procedure.name, t_s=self.clock.now(), data=json.dumps({
            "path": str(self.procedure.path), "parameters": self.procedure.parameters, "sources": self.procedure.sources,
            "steps": len(self.procedure.steps), "clock": "virtual" if self.clock.virtual else "wall"}, default=str).encode())
        self.monitor.poll(self.clock.now())

    def run(self) -> RunResult:
        """Execute every step; never raises for instrument or recorder faults (they abort the run)."""
        wall0 = time.monotonic()
        status = "completed"
        total = len(self.procedure.steps)
        self.progress.start(self.procedure, self.procedure.estimated_duration_s())
        try:
            self.prepare()
            for step in self.procedure.steps:
                self.check_abort()
                self.current_step = step.index
                self.progress.step(step.index + 1, total, step)
                t0 = self.clock.now()
                self.rec.event("step_start", step.type, step.name, t_s=t0, step=step.index)
                outcome, message = self.handlers[step.type](self, step)
                t1 = self.clock.now()
                self.rec.event("step_end", step.type, outcome if not message else f"{outcome}: {message}", t_s=t1, step=step.index)
                self.outcomes.append(StepOutcome(step.index, step.name, step.type, outcome, message, t0, t1))
                if outcome == "failed":
                    self.progress.message(f"step {step.index + 1} {step.name}: FAILED {message}")
                self.rec.tick(t1)
        except (AbortRequested, InstrumentError, RecorderError, StepAbort, InterlockTrip, OSError, ValueError) as exc:
            status = "aborted"
            self.abort_reason = self.abort_reason or describe(exc)
            self._abort_path()
        finally:
            self.flush_notices()
            self.progress.stop(self.clock.now())
        run_time = self.clock.now()
        status = self._close(status)
        rows = {name: self.rec.rows_written(key) for name, key in {**self.ingest.keys, **self.monitor.keys}.items()}
        return RunResult(status, self.abort_reason, self.outcomes, run_time, time.monotonic() - wall0, rows, self.ingest.stats,
                         list(self.results.values()))

    def _abort_path(self) -> None:
        t = self.clock.now()
        if self.current_step >= 0 and (not self.outcomes or self.outcomes[-1].index != self.current_step):
            step = self.procedure.steps[self.current_step]
            self.outcomes.append(StepOutcome(step.index, step.name, step.type, "aborted", self.abort_reason, t, t))
            self._event("step_end", step.type, f"aborted: {self.abort_reason}", step=step.index)
        self._event("abort", "runner", self.abort_reason)
        self._bring_to_safe_state(t)

    def _bring_to_safe_state(self, t: float) -> None:
        """Tell every instrument to go to its safe state at once, the moving axes first, each
        within its own deadline (:mod:`bench.runner.safe_state`); then read the last frames of the
        streaming instruments that confirmed (salvage; a failure there is reported, the safe state
        stands). Run time ``t`` (s) of the abort."""
        phase = SafeStatePhase(self, list(self.lab.instruments), self._event)
        self.progress.message(f"aborting: {self.abort_reason}; {phase.announcement()}")
        self.progress.advance(t, "aborting")
        outcomes = phase.run_all()
        self.ingest.streaming.clear()
        for o in outcomes:
            if o.outcome == "confirmed" and o.name in self.ingest.keys:
                try:
                    self._drain(o.name)
                except Exception as exc:  # noqa: BLE001 - the abort path must reach the file
                    self._event("error", o.name, f"last frames not read: {describe(exc)}")

    def _event(self, kind: str, source: str, message: str, step: int = -1, *, t_s: float | None = None, data: bytes = b"") -> None:
        """Record an event on the abort path, where the recorder itself may be what failed (at run
        time ``t_s``, s; default now)."""
        try:
            self.rec.event(kind, source, message, t_s=self.clock.now() if t_s is None else t_s, step=step, data=data)
        except (RecorderError, OSError, ValueError):
            pass

    def _close(self, status: str) -> str:
        """Finalise the run file; returns the status it was closed with."""
        try:
            self.rec.event("run_end", "runner", status if not self.abort_reason else f"{status}: {self.abort_reason}", t_s=self.clock.now())
            self.rec.close(status, self.abort_reason)
        except (RecorderError, OSError, ValueError) as exc:
            self.abort_reason = self.abort_reason or f"recorder: {describe(exc)}"
            try:
                self.rec.close("aborted", self.abort_reason)
            except (RecorderError, OSError, ValueError):
                pass
            if self.rec.closed:
                return "aborted"  # finalised as aborted with the recorder's reason (e.g. disk nearly full)
            raise RecorderError(f"the run file could not be finalised: {describe(exc)}") from None
        return status

    # ---- waiting ----------------------------------------------------------------------------
    def wait_until(self, timeout_s: float, condition: Callable[[], bool] | None = None) -> bool:
        """Wait up to ``timeout_s`` of run time (paused time not counted) for ``condition``;
        without one, wait the whole time. Returns whether the condition held (True when there is
        none). The lab stays under watch meanwhile; an abort request or interlock trip raises."""
        period = POLL_PERIOD_VIRTUAL_S if self.clock.virtual else POLL_PERIOD_WALL_S
        t_end = self.clock.now() + timeout_s
        next_drain = min(self.clock.now() + period, t_end)
        if condition is not None and condition():
            return True
        while True:
            self.check_abort()
            now = self.clock.now()
            if self.paused:
                self._hold_while_paused(period)
                t_end += self.clock.now() - now
                next_drain = self.clock.now()
                continue
            if now >= t_end:
                return condition is None
            wake = min([next_drain, t_end, *self.monitor.due.values()])
            self.clock.sleep_until(max(wake, now))
            t = self.clock.now()
            self.monitor.poll(t)
            if t + 1e-9 >= next_drain:
                next_drain = min(t + period, t_end)
                self._service_streams()
            if condition is not None and condition():
                return True

    def _service_streams(self) -> None:
        """Drain the streaming instruments, check them for stalls, flush the run file when due
        (heartbeat) and show progress."""
        for name in list(self.ingest.streaming):
            self.monitor.guarded(name, lambda n=name: self._drain(n))
        self.monitor.check_stalls(self.clock.now())
        self.rec.tick(self.clock.now())
        self.progress.advance(self.clock.now(), self._readings())

    def keep_watch(self) -> None:
        """Called while the operator is asked (every :data:`~bench.runner.operator.ANSWER_TICK_S` of
        wall time, on this thread): honour abort requests and keep the run file's heartbeat. On the
        wall clock the lab goes on meanwhile, so it stays under watch as in :meth:`wait_until`
        (polled readings, interlocks, streams); on a virtual clock run time stands still while a
        person answers."""
        self.check_abort()
        if self.clock.virtual:
            self.rec.tick(self.clock.now())
            return
        self.monitor.poll(self.clock.now())
        self._service_streams()

    def _hold_while_paused(self, period: float) -> None:
        self.progress.message("paused: timed steps are on hold, instruments stay under watch (pause again to resume)")
        self._event("pause", "operator", "paused")
        while self.paused:
            self.check_abort()
            if self.clock.virtual:
                # virtual time stands still while paused (as while a person answers): nobody is
                # watching hours of simulated physics go by; the file keeps its heartbeat
                self.flush_notices()
                self.rec.tick(self.clock.now())
                time.sleep(PAUSED_TICK_WALL_S)
                continue
            now = self.clock.now()
            self.clock.sleep_until(min([now + period, *self.monitor.due.values()]))
            self.monitor.poll(self.clock.now())
            for name in list(self.ingest.streaming):
                self._drain(name)
            self.rec.tick(self.clock.now())
            time.sleep(0)  # let a signal handler run
        self._event("resume", "operator", "resumed")
        self.progress.message("resumed")

    def recording(self, name: str, window: str, meta: dict, body: Callable[[], object]) -> int:
        """Stream instrument ``name`` into window ``window`` while ``body()`` runs; returns rows."""
        drv = self.lab.instruments[name]
        before = self.rec.rows_written(self.ingest.keys[name])
        self.windows.start(window, self.clock.now(), meta)
        drv.start_stream()
        self.ingest.begin(name)
        try:
            body()
        finally:
            self.ingest.end(name)
        self.lab.instruments[name].stop_stream()  # the driver may have been reopened after a link fault
        self._drain(name)
        self.windows.end(window, self.clock.now())
        return self.rec.rows_written(self.ingest.keys[name]) - before

    # ---- signals ----------------------------------------------------------------------------
    def poll_interval(self, signal: str) -> float:
        """Poll interval of the instrument of ``signal`` (s)."""
        return self.monitor.interval(signal.split(".", 1)[0])

    def read_signal(self, signal: str, fresh: bool = False) -> float:
        """Latest value of ``INSTRUMENT.COLUMN[.AXIS]`` (see :meth:`LabMonitor.read_signal`)."""
        return self.monitor.read_signal(signal, fresh)

    def _drain(self, name: str) -> int:
        """Poll streaming instrument ``name`` into the run file; returns rows."""
        return self.ingest.drain(name, self.lab.instruments[name])

    def _readings(self) -> str:
        return "; ".join(self.ingest.readings() + self.monitor.readings())
