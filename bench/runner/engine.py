"""Step interpreter with safe state on abort.

Outcomes: every step ends ``passed`` (a check held), ``failed`` (a check did not hold; the run
goes on and ends with exit code 1), ``done`` (an action), or ``aborted``. An instrument fault, a
recorder failure, an interlock trip, a step that cannot go on or an abort request (SIGINT/SIGTERM)
stops the run: every instrument is brought to its safe state, the run file is closed with status
``aborted`` and the reason.

While any step waits, the runner keeps the lab under watch (:meth:`Runner.wait_until`): polled
instruments are read at their poll interval and logged, streams are drained, interlocks are
evaluated, the run file is flushed, pause and abort requests are honoured.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from bench.errors import KNOWN_ERRORS, BenchError, DeviceFault, InstrumentError, RecorderError
from bench.lab import Lab
from bench.procedure import Procedure, Step
from bench.procedure.signals import parse_signal
from bench.record import Column, RunRecorder
from bench.runner import steps as step_handlers
from bench.runner.operator import Operator
from bench.runner.steps import StepAbort
from bench.runner.windows import Windows

ACS_COLUMNS = [
    Column("counter", "1", "u2"),
    Column("board_time", "s", "f8"),
    Column("gyro", "deg/s", "f8", (3,)),
    Column("accel", "g", "f8", (3,)),
    Column("mag", "uT", "f8", (3,)),
    Column("temp", "degC", "f8", (3,)),
    Column("status", "1", "u2"),
]
"""Stream layout of a sensor board: temp = (gyro die, accel die, board)."""

COMPENSATED_COLUMN = Column("gyro_comp", "deg/s", "f8", (3,))
"""Added when the board has a calibration: the gyro rates compensated with NPSAT1 Eq. 2."""

RECONNECT_BACKOFF_S = (0.5, 1.0, 2.0, 4.0, 8.0)
"""Waits between reconnection attempts after a link fault (s of run time); the last repeats."""

CHAMBER_SAFETY_MARGIN_C = 5.0
"""A chamber temperature reading more than this beyond the chamber's set-point limits (defaults, lab
config, procedure: the narrowest) aborts the run whatever the procedure's interlocks say: the
controller is not controlling (runaway heater or cooler, failed sensor). Our choice [U]: above the
overshoot of a controlled ramp, below damage."""

POLL_PERIOD_VIRTUAL_S = 5.0  # run time between stream polls in a dry-run (s): 500 frames per batch at 100 Hz
POLL_PERIOD_WALL_S = 0.1  # on the wall clock: keeps abort latency and progress updates short


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
        return self.status == "completed" and not self.failed_steps


class InterlockTrip(BenchError):
    """An interlock's signal left its limits."""


class Runner:
    """Runs one procedure on one lab into one recorder."""

    def __init__(self, procedure: Procedure, lab: Lab, recorder: RunRecorder, progress: Progress, operator: Operator | None = None):
        self.procedure = procedure
        self.lab = lab
        self.clock = lab.clock
        self.rec = recorder
        self.progress = progress
        self.operator = operator or Operator()
        self.abort_reason = ""
        self.current_step = -1
        self.outcomes: list[StepOutcome] = []
        self.stream_keys: dict[str, str] = {}
        self.stream_stats: dict[str, dict[str, int]] = {}
        self._time_offset: dict[str, float | None] = {}
        self._last_gyro: dict[str, np.ndarray] = {}
        self._last_stream: dict[str, dict[str, np.ndarray]] = {}
        self._last_frame_t: dict[str, float] = {}
        self.monitor_keys: dict[str, str] = {}
        self._monitor_due: dict[str, float] = {}
        self._last_monitor: dict[str, dict[str, float]] = {}
        self.streaming: set[str] = set()
        self.windows = Windows()
        self.results: dict[str, dict] = {}
        self.in_vacuum = False
        self.paused = False
        self.notices: list[str] = []
        """Messages from signal handlers, printed by the main loop (a handler must not render: it
        may interrupt the terminal library in the middle of its own work)."""
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

    def _check_abort(self) -> None:
        self.flush_notices()
        if self.abort_reason:
            raise AbortRequested(self.abort_reason)

    def flush_notices(self) -> None:
        """Print the messages signal handlers left (main thread only)."""
        while self.notices:
            self.progress.message(self.notices.pop(0))

    # ---- run --------------------------------------------------------------------------------
    def prepare(self) -> None:
        """Identify every instrument, declare the streams, start the recorder (SWMR)."""
        for name, drv in self.lab.instruments.items():
            info = drv.identify()
            info.update(driver=drv.kind, port=self.lab.ports[name], mode=self.lab.mode, baudrate=str(getattr(getattr(drv, "port", None), "baudrate", "")))
            comp = getattr(drv, "compensation", None)
            if comp is not None:
                info["compensation"] = comp.describe()
            self.rec.add_instrument(name, {k: str(v) for k, v in info.items()})
            if not drv.streams:
                if hasattr(drv, "monitor_columns"):
                    interval = self.lab.poll_intervals.get(name, 1.0)
                    cols = [Column(c, u, "f8") for c, u in drv.monitor_columns()]
                    self.monitor_keys[name] = self.rec.add_stream(name, cols, "monitor", rate_hz=1.0 / interval)
                    self._monitor_due[name] = 0.0
                continue  # an instrument without a data stream: polled, its commands recorded
            self.stream_keys[name] = self.rec.add_stream(name, ACS_COLUMNS + ([COMPENSATED_COLUMN] if comp is not None else []))
            self.stream_stats[name] = {"frames": 0, "crc_errors": 0, "dropped_frames": 0, "garbage_bytes": 0}
            self._time_offset[name] = None
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
        self._poll_monitors(self.clock.now())

    def run(self) -> RunResult:
        """Execute every step; never raises for instrument or recorder faults (they abort the run)."""
        wall0 = time.monotonic()
        status = "completed"
        total = len(self.procedure.steps)
        self.progress.start(self.procedure, self.procedure.estimated_duration_s())
        try:
            self.prepare()
            for step in self.procedure.steps:
                self._check_abort()
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
            self.abort_reason = self.abort_reason or _describe(exc)
            self._abort_path()
        finally:
            self.flush_notices()
            self.progress.stop(self.clock.now())
        run_time = self.clock.now()
        status = self._close(status)
        rows = {name: self.rec.rows_written(key) for name, key in {**self.stream_keys, **self.monitor_keys}.items()}
        return RunResult(status, self.abort_reason, self.outcomes, run_time, time.monotonic() - wall0, rows, self.stream_stats,
                         list(self.results.values()))

    def _abort_path(self) -> None:
        t = self.clock.now()
        if self.current_step >= 0 and (not self.outcomes or self.outcomes[-1].index != self.current_step):
            step = self.procedure.steps[self.current_step]
            self.outcomes.append(StepOutcome(step.index, step.name, step.type, "aborted", self.abort_reason, t, t))
            self._event("step_end", step.type, f"aborted: {self.abort_reason}", step=step.index)
        self._event("abort", "runner", self.abort_reason)
        self.progress.message(f"aborting: {self.abort_reason}; bringing instruments to their safe state")
        self.progress.advance(t, "aborting")
        for name in list(self.lab.instruments):
            self.flush_notices()
            try:
                self._safe_state(name)
            except Exception as exc:  # noqa: BLE001 - the abort path must reach every instrument and the file
                self._event("error", name, f"safe state failed: {_describe(exc)}")
                self.progress.message(f"{name}: safe state failed: {_describe(exc)}")
                continue
            self._event("safe_state", name, "streaming stopped" if name in self.stream_keys else "safe state reached")
            if name in self.stream_keys:
                try:
                    self._drain(name)  # salvage the last frames; the instrument is already safe
                except Exception as exc:  # noqa: BLE001
                    self._event("error", name, f"last frames not read: {_describe(exc)}")

    def _safe_state(self, name: str) -> None:
        """Bring ``name`` to its safe state; a link fault is retried through a reconnection (within
        the instrument's ``reconnect_timeout``), as the safe state matters most when links fail."""
        try:
            self.lab.instruments[name].safe_state()
        except DeviceFault:
            raise
        except (InstrumentError, OSError) as exc:
            self._reconnect(name, exc, aborting=True)
            self.lab.instruments[name].safe_state()
        self.streaming.clear()

    def _event(self, kind: str, source: str, message: str, step: int = -1) -> None:
        """Record an event on the abort path, where the recorder itself may be what failed."""
        try:
            self.rec.event(kind, source, message, t_s=self.clock.now(), step=step)
        except (RecorderError, OSError, ValueError):
            pass

    def _close(self, status: str) -> str:
        """Finalise the run file; returns the status it was closed with."""
        try:
            self.rec.event("run_end", "runner", status if not self.abort_reason else f"{status}: {self.abort_reason}", t_s=self.clock.now())
            self.rec.close(status, self.abort_reason)
        except (RecorderError, OSError, ValueError) as exc:
            self.abort_reason = self.abort_reason or f"recorder: {_describe(exc)}"
            try:
                self.rec.close("aborted", self.abort_reason)
            except (RecorderError, OSError, ValueError):
                pass
            if self.rec.closed:
                return "aborted"  # finalised as aborted with the recorder's reason (e.g. disk nearly full)
            raise RecorderError(f"the run file could not be finalised: {_describe(exc)}") from None
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
            self._check_abort()
            now = self.clock.now()
            if self.paused:
                self._hold_while_paused(period)
                t_end += self.clock.now() - now
                next_drain = self.clock.now()
                continue
            if now >= t_end:
                return condition is None
            wake = min([next_drain, t_end, *self._monitor_due.values()])
            self.clock.sleep_until(max(wake, now))
            t = self.clock.now()
            self._poll_monitors(t)
            if t + 1e-9 >= next_drain:
                next_drain = min(t + period, t_end)
                for name in list(self.streaming):
                    self._guarded(name, lambda n=name: self._drain(n))
                self._check_stalls(self.clock.now())
                self.rec.tick(self.clock.now())
                self.progress.advance(self.clock.now(), self._readings())
            if condition is not None and condition():
                return True

    def _hold_while_paused(self, period: float) -> None:
        self.progress.message("paused: timed steps are on hold, instruments stay under watch (pause again to resume)")
        self._event("pause", "operator", "paused")
        while self.paused:
            self._check_abort()
            now = self.clock.now()
            self.clock.sleep_until(min([now + period, *self._monitor_due.values()]) if self._monitor_due else now + period)
            self._poll_monitors(self.clock.now())
            for name in list(self.streaming):
                self._drain(name)
            self.rec.tick(self.clock.now())
            if not self.clock.virtual:
                time.sleep(0)  # let a signal handler run
        self._event("resume", "operator", "resumed")
        self.progress.message("resumed")

    def recording(self, name: str, window: str, meta: dict, body: Callable[[], object]) -> int:
        """Stream instrument ``name`` into window ``window`` while ``body()`` runs; returns rows."""
        drv = self.lab.instruments[name]
        before = self.rec.rows_written(self.stream_keys[name])
        self._time_offset[name] = None
        self.windows.start(window, self.clock.now(), meta)
        drv.start_stream()
        self.streaming.add(name)
        self._last_frame_t[name] = self.clock.now()
        try:
            body()
        finally:
            self.streaming.discard(name)
        self.lab.instruments[name].stop_stream()  # the driver may have been reopened after a link fault
        self._drain(name)
        self.windows.end(window, self.clock.now())
        return self.rec.rows_written(self.stream_keys[name]) - before

    # ---- signals ----------------------------------------------------------------------------
    def poll_interval(self, signal: str) -> float:
        return self.lab.poll_intervals.get(signal.split(".", 1)[0], 1.0)

    def read_signal(self, signal: str, fresh: bool = False) -> float:
        """Latest value of ``INSTRUMENT.COLUMN[.AXIS]``: a polled reading (``fresh``: read now) or
        the newest frame of a stream. NaN when nothing has been read yet."""
        inst, column, axis = parse_signal(signal)
        if inst in self.monitor_keys:
            if fresh:
                self._poll_one(inst, self.clock.now())
            return float(self._last_monitor.get(inst, {}).get(column, float("nan")))
        last = self._last_stream.get(inst, {}).get(column)
        if last is None:
            return float("nan")
        return float(last[axis if axis is not None else 0])

    def _poll_monitors(self, t: float) -> None:
        """Read every polled instrument whose interval has come, log a row, evaluate interlocks."""
        for name, due in list(self._monitor_due.items()):
            if t + 1e-9 < due:
                continue
            self._guarded(name, lambda n=name: self._poll_one(n, self.clock.now()))
            interval = self.lab.poll_intervals.get(name, 1.0)
            self._monitor_due[name] = due + interval if due + interval > t else t + interval

    def _poll_one(self, name: str, t: float) -> None:
        values = self.lab.instruments[name].monitor()
        self.rec.append(self.monitor_keys[name], np.array([t]), **{k: np.array([v], dtype=float) for k, v in values.items()})
        self._last_monitor[name] = values
        if self.windows.any_open:
            for col, v in values.items():
                self.windows.feed_one(f"{name}.{col}", t, float(v))
        self._check_interlocks(name)
        self._check_lab_safety(name, values)

    # ---- link faults ------------------------------------------------------------------------
    def _guarded(self, name: str, read: Callable[[], object]) -> None:
        """Run an idempotent read (a polled reading, a stream drain); a link fault (timeout, lost
        port, garbled answer) is recovered by reconnecting with backoff, the gap recorded. A
        fault the instrument reports itself (DeviceFault) is not a link fault: it aborts."""
        try:
            read()
        except DeviceFault:
            raise
        except (InstrumentError, OSError) as exc:
            self._reconnect(name, exc)
            read()

    def _reconnect(self, name: str, exc: BaseException, aborting: bool = False) -> None:
        t0 = self.clock.now()
        limit = self.lab.reconnect_timeouts.get(name, 30.0)
        self.rec.event("fault", name, f"link fault: {_describe(exc)}; reconnecting (up to {limit:g} s)", t_s=t0, step=self.current_step)
        self.progress.message(f"{name}: link fault ({_describe(exc)}); reconnecting")
        attempt, last = 0, exc
        while True:
            if not aborting:
                self._check_abort()
            wait = RECONNECT_BACKOFF_S[min(attempt, len(RECONNECT_BACKOFF_S) - 1)]
            if self.clock.now() - t0 + wait > limit:
                raise InstrumentError(f"{name}: link lost ({_describe(last)}); not restored within {limit:g} s")
            self.clock.sleep(wait)
            self.progress.advance(self.clock.now(), f"{name}: reconnecting (attempt {attempt + 1})")
            attempt += 1
            try:
                drv = self.lab.reopen(name)
                drv.identify()
                if name in self.monitor_keys:
                    drv.monitor_columns()  # a fresh driver sets its instrument up again (thermocouple scan list)
                if not aborting and name in self.streaming and not drv.get_config()["streaming"]:
                    drv.start_stream()
                break
            except DeviceFault:
                raise
            except (InstrumentError, OSError) as again:
                last = again
        t1 = self.clock.now()
        for w in self.windows.all.values():
            if w.open:
                w.meta.setdefault("gaps_s", []).append([t0, t1])
        self.rec.event("gap", name, f"link restored after {t1 - t0:.1f} s ({attempt} attempt(s)); no data from {name} in between",
                       t_s=t1, step=self.current_step, data=json.dumps({"t_start_s": t0, "t_end_s": t1, "attempts": attempt}).encode())
        self.progress.message(f"{name}: link restored after {t1 - t0:.1f} s")

    def _check_interlocks(self, inst: str) -> None:
        for lock in self.procedure.interlocks:
            if lock.stall_s is not None or not lock.signal.startswith(inst + "."):
                continue
            if lock.active == "vacuum" and not self.in_vacuum:
                continue
            v = self.read_signal(lock.signal)
            if math.isnan(v):
                if inst in self._last_monitor and lock.signal.split(".")[1] in self._last_monitor[inst]:
                    self._trip(f"interlock {lock.name!r}: {lock.signal} has no valid reading (open sensor?)", lock)
                continue
            if (lock.minimum is not None and v < lock.minimum) or (lock.maximum is not None and v > lock.maximum):
                lim = f"min {lock.minimum:g}" if lock.minimum is not None and v < lock.minimum else f"max {lock.maximum:g}"
                self._trip(f"interlock {lock.name!r}: {lock.signal} = {v:.4g} beyond {lim}", lock)

    def _check_lab_safety(self, inst: str, values: dict[str, float]) -> None:
        """Always-on limits of the lab, independent of the procedure's interlocks: the chamber's
        air and mount temperatures stay within its set-point limits ± CHAMBER_SAFETY_MARGIN_C."""
        if self.lab.kinds.get(inst) != "tvac":
            return
        from bench.procedure.limits import effective_limits

        lo, hi, src = effective_limits("tvac", self.lab.config_limits.get(inst, {}), self.procedure.limits.get(inst, {}))["set_point"]
        for col in ("air_temp", "mount_temp"):
            v = values.get(col)
            if v is None or math.isnan(v):
                continue
            if (lo is not None and v < lo - CHAMBER_SAFETY_MARGIN_C) or (hi is not None and v > hi + CHAMBER_SAFETY_MARGIN_C):
                reason = (f"lab safety: {inst}.{col} = {v:.1f} degC beyond the chamber limits "
                          f"{lo:g}..{hi:g} degC ({src}) by more than {CHAMBER_SAFETY_MARGIN_C:g} degC: the chamber is not under control")
                self.request_abort(reason)
                raise InterlockTrip(reason)

    def _check_stalls(self, t: float) -> None:
        for lock in self.procedure.interlocks:
            if lock.stall_s is None or lock.signal not in self.streaming:
                continue
            gap = t - self._last_frame_t.get(lock.signal, t)
            if gap > lock.stall_s:
                self._trip(f"interlock {lock.name!r}: no frames from {lock.signal} for {gap:.1f} s (limit {lock.stall_s:g} s)", lock)

    def _trip(self, reason: str, lock) -> None:
        self.request_abort(reason)
        raise InterlockTrip(reason)

    # ---- streams ----------------------------------------------------------------------------
    def _drain(self, name: str) -> int:
        """Poll instrument ``name`` and append its decoded frames to the run file; returns rows."""
        drv = self.lab.instruments[name]
        batch = drv.poll()
        stats = self.stream_stats[name]
        if batch.crc_errors or batch.dropped_frames or batch.garbage_bytes:
            self.rec.event(
                "stream", name,
                f"link errors: {batch.crc_errors} CRC errors, {batch.dropped_frames} dropped frames, {batch.garbage_bytes} garbage bytes",
                t_s=self.clock.now(), step=self.current_step,
            )
        stats["crc_errors"] += batch.crc_errors
        stats["dropped_frames"] += batch.dropped_frames
        stats["garbage_bytes"] += batch.garbage_bytes
        n = batch.counter.shape[0]
        if n == 0:
            return 0
        if self._time_offset[name] is None:
            # Map board time to run time: the newest frame of the first batch arrived just now.
            self._time_offset[name] = self.clock.now() - float(batch.board_time_s[-1])
        time_s = batch.board_time_s + self._time_offset[name]
        extra = {"gyro_comp": drv.compensated_gyro(batch)} if getattr(drv, "compensation", None) is not None else {}
        self.rec.append(
            self.stream_keys[name], time_s,
            counter=batch.counter, board_time=batch.board_time_s, gyro=batch.gyro_dps, accel=batch.accel_g,
            mag=batch.mag_ut, temp=batch.temp_degc, status=batch.status, **extra,
        )
        stats["frames"] += n
        self._last_frame_t[name] = float(time_s[-1])
        columns = {"gyro": batch.gyro_dps, "accel": batch.accel_g, "mag": batch.mag_ut, "temp": batch.temp_degc}
        self._last_stream[name] = {c: v[-1] for c, v in columns.items()}
        self._last_gyro[name] = batch.gyro_dps.mean(axis=0)
        if self.windows.any_open:
            for c, v in columns.items():
                for k, axis in enumerate("xyz"):
                    self.windows.feed(f"{name}.{c}.{axis}", time_s, v[:, k])
                if c == "temp":
                    self.windows.feed(f"{name}.temp", time_s, v[:, 0])
        return n

    def _readings(self) -> str:
        parts = []
        for name in self.streaming:
            g = self._last_gyro.get(name)
            if g is not None:
                t = self._last_stream.get(name, {}).get("temp")
                parts.append(f"gyro {g[0]:+.3f} {g[1]:+.3f} {g[2]:+.3f} deg/s" + (f", {t[0]:.1f} degC" if t is not None else ""))
        for name, vals in self._last_monitor.items():
            parts.append(f"{name} " + " ".join(f"{k} {v:.4g}" for k, v in list(vals.items())[:3]))
        return "; ".join(parts)


def _describe(exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    return text if isinstance(exc, KNOWN_ERRORS) else f"{type(exc).__name__}: {text}"
