"""Step interpreter with safe state on abort.

Outcomes: every step ends ``passed`` (a check held), ``failed`` (a check did not hold; the run
goes on and ends with exit code 1), ``done`` (an action), or ``aborted``. An instrument fault, a
recorder failure or an abort request (SIGINT/SIGTERM) stops the run: every instrument is brought
to its safe state, the run file is closed with status ``aborted`` and the reason.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from bench.errors import BenchError, InstrumentError, RecorderError
from bench.lab import Lab
from bench.procedure import Procedure, Step
from bench.record import Column, RunRecorder

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

    @property
    def failed_steps(self) -> list[StepOutcome]:
        return [o for o in self.outcomes if o.outcome == "failed"]

    @property
    def ok(self) -> bool:
        return self.status == "completed" and not self.failed_steps


class Runner:
    """Runs one procedure on one lab into one recorder."""

    def __init__(self, procedure: Procedure, lab: Lab, recorder: RunRecorder, progress: Progress):
        self.procedure = procedure
        self.lab = lab
        self.clock = lab.clock
        self.rec = recorder
        self.progress = progress
        self.abort_reason = ""
        self.current_step = -1
        self.outcomes: list[StepOutcome] = []
        self.stream_keys: dict[str, str] = {}
        self.stream_stats: dict[str, dict[str, int]] = {}
        self._time_offset: dict[str, float | None] = {}
        self._last_gyro: dict[str, np.ndarray] = {}
        self._last_temp = float("nan")
        self.monitor_keys: dict[str, str] = {}
        self._monitor_due: dict[str, float] = {}
        self._last_monitor: dict[str, dict[str, float]] = {}
        self.handlers: dict[str, Callable[[Step], tuple[str, str]]] = {
            "comment": self._comment,
            "power": self._power,
            "configure": self._configure,
            "record": self._record,
            "wait": self._wait,
            "bit": self._bit,
        }

    # ---- abort ------------------------------------------------------------------------------
    def request_abort(self, reason: str) -> None:
        """Ask the run to stop at the next check point (safe to call from a signal handler)."""
        if not self.abort_reason:
            self.abort_reason = reason

    def _check_abort(self) -> None:
        if self.abort_reason:
            raise AbortRequested(self.abort_reason)

    # ---- run --------------------------------------------------------------------------------
    def prepare(self) -> None:
        """Identify every instrument, declare the streams, start the recorder (SWMR)."""
        for name, drv in self.lab.instruments.items():
            info = drv.identify()
            info.update(driver=drv.kind, port=self.lab.ports[name], mode=self.lab.mode, baudrate=str(getattr(getattr(drv, "port", None), "baudrate", "")))
            self.rec.add_instrument(name, {k: str(v) for k, v in info.items()})
            if not drv.streams:
                if hasattr(drv, "monitor_columns"):
                    interval = self.lab.poll_intervals.get(name, 1.0)
                    cols = [Column(c, u, "f8") for c, u in drv.monitor_columns()]
                    self.monitor_keys[name] = self.rec.add_stream(name, cols, "monitor", rate_hz=1.0 / interval)
                    self._monitor_due[name] = 0.0
                continue  # an instrument without a data stream: polled, its commands recorded
            self.stream_keys[name] = self.rec.add_stream(name, ACS_COLUMNS)
            self.stream_stats[name] = {"frames": 0, "crc_errors": 0, "dropped_frames": 0, "garbage_bytes": 0}
            self._time_offset[name] = None
        self.rec.start()
        self.rec.event("run_start", "runner", f"{self.procedure.name}: {len(self.procedure.steps)} steps, mode {self.lab.mode}", t_s=self.clock.now())

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
                outcome, message = self.handlers[step.type](step)
                t1 = self.clock.now()
                self.rec.event("step_end", step.type, outcome if not message else f"{outcome}: {message}", t_s=t1, step=step.index)
                self.outcomes.append(StepOutcome(step.index, step.name, step.type, outcome, message, t0, t1))
                self.rec.tick(t1)
        except (AbortRequested, InstrumentError, RecorderError, OSError, ValueError) as exc:
            status = "aborted"
            self.abort_reason = self.abort_reason or _describe(exc)
            self._abort_path()
        finally:
            self.progress.stop(self.clock.now())
        run_time = self.clock.now()
        self._close(status)
        rows = {name: self.rec.rows_written(key) for name, key in self.stream_keys.items()}
        return RunResult(status, self.abort_reason, self.outcomes, run_time, time.monotonic() - wall0, rows, self.stream_stats)

    def _abort_path(self) -> None:
        t = self.clock.now()
        if self.current_step >= 0 and (not self.outcomes or self.outcomes[-1].index != self.current_step):
            step = self.procedure.steps[self.current_step]
            self.outcomes.append(StepOutcome(step.index, step.name, step.type, "aborted", self.abort_reason, t, t))
            self._event("step_end", step.type, f"aborted: {self.abort_reason}", step=step.index)
        self._event("abort", "runner", self.abort_reason)
        self.progress.message(f"aborting: {self.abort_reason}; bringing instruments to their safe state")
        for name, drv in self.lab.instruments.items():
            try:
                drv.safe_state()
                if name in self.stream_keys:
                    self._drain(name)
                self._event("safe_state", name, "streaming stopped" if name in self.stream_keys else "stopped")
            except (BenchError, OSError, ValueError) as exc:
                self._event("error", name, f"safe state failed: {_describe(exc)}")
                self.progress.message(f"{name}: safe state failed: {_describe(exc)}")

    def _event(self, kind: str, source: str, message: str, step: int = -1) -> None:
        """Record an event on the abort path, where the recorder itself may be what failed."""
        try:
            self.rec.event(kind, source, message, t_s=self.clock.now(), step=step)
        except (RecorderError, OSError, ValueError):
            pass

    def _close(self, status: str) -> None:
        try:
            self.rec.event("run_end", "runner", status if not self.abort_reason else f"{status}: {self.abort_reason}", t_s=self.clock.now())
            self.rec.close(status, self.abort_reason)
        except (RecorderError, OSError, ValueError) as exc:
            self.abort_reason = self.abort_reason or f"recorder: {_describe(exc)}"
            try:
                self.rec.close("aborted", self.abort_reason)
            except (RecorderError, OSError, ValueError):
                pass
            raise RecorderError(f"the run file could not be finalised: {_describe(exc)}") from None

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
        self.rec.append(
            self.stream_keys[name], time_s,
            counter=batch.counter, board_time=batch.board_time_s, gyro=batch.gyro_dps, accel=batch.accel_g,
            mag=batch.mag_ut, temp=batch.temp_degc, status=batch.status,
        )
        stats["frames"] += n
        self._last_gyro[name] = batch.gyro_dps.mean(axis=0)
        self._last_temp = float(batch.temp_degc[-1, 0])
        return n

    # ---- step handlers: each returns (outcome, message) -------------------------------------
    def _comment(self, step: Step) -> tuple[str, str]:
        self.progress.message(step.params["text"])
        self.rec.event("note", "procedure", step.params["text"], t_s=self.clock.now(), step=step.index)
        return "done", ""

    def _power(self, step: Step) -> tuple[str, str]:
        name = step.params["instrument"]
        self.lab.instruments[name].sensor_power(step.params["on"])
        return "done", "sensors on" if step.params["on"] else "sensors off"

    def _configure(self, step: Step) -> tuple[str, str]:
        drv = self.lab.instruments[step.params["instrument"]]
        done = []
        if "odr" in step.params:
            hz = step.params["odr"]
            if abs(hz - round(hz)) > 1e-9:
                raise ValueError(f"step {step.index + 1}: output data rate must be a whole number of Hz, got {hz:g} Hz")
            drv.set_odr(int(round(hz)))
            done.append(f"odr {int(round(hz))} Hz")
        if "moving_average" in step.params:
            drv.set_moving_average(int(step.params["moving_average"]))
            done.append(f"moving average N={int(step.params['moving_average'])}")
        cfg = drv.get_config()
        if "odr" in step.params and cfg["odr_hz"] != int(round(step.params["odr"])) or (
            "moving_average" in step.params and cfg["moving_avg_n"] != int(step.params["moving_average"])
        ):
            return "failed", ", ".join(done) + f" requested, but the board reports odr {cfg['odr_hz']} Hz, N={cfg['moving_avg_n']}"
        return "done", ", ".join(done) + " (read back from the board)"

    def _wait(self, step: Step) -> tuple[str, str]:
        self._sleep_checked(self.clock.now() + step.params["duration"], [])
        return "done", ""

    def _record(self, step: Step) -> tuple[str, str]:
        name = step.params["instrument"]
        drv = self.lab.instruments[name]
        before = self.rec.rows_written(self.stream_keys[name])
        self._time_offset[name] = None
        drv.start_stream()
        t_end = self.clock.now() + step.params["duration"]
        self._sleep_checked(t_end, [name])
        drv.stop_stream()
        self._drain(name)
        rows = self.rec.rows_written(self.stream_keys[name]) - before
        window = step.params.get("window") or step.name
        return "done", f"{rows} rows in window {window!r}"

    def _sleep_checked(self, t_end: float, streams: list[str]) -> None:
        """Wait until run time ``t_end`` (s), draining ``streams``, reading the polled instruments
        when due, flushing, checking for aborts."""
        period = POLL_PERIOD_VIRTUAL_S if self.clock.virtual else POLL_PERIOD_WALL_S
        next_drain = min(self.clock.now() + period, t_end)
        while True:
            self._check_abort()
            now = self.clock.now()
            if now >= t_end:
                break
            wake = min([next_drain, *self._monitor_due.values()])
            self.clock.sleep_until(max(wake, now))
            t = self.clock.now()
            self._poll_monitors(t)
            if t + 1e-9 < next_drain:
                continue  # woken for a polled instrument only
            next_drain = min(t + period, t_end)
            for name in streams:
                self._drain(name)
            t = self.clock.now()
            self.rec.tick(t)
            self.progress.advance(t, self._readings(streams))

    def _poll_monitors(self, t: float) -> None:
        """Read every polled instrument whose interval has come and append one row for it."""
        for name, due in self._monitor_due.items():
            if t + 1e-9 < due:
                continue
            values = self.lab.instruments[name].monitor()
            self.rec.append(self.monitor_keys[name], np.array([t]), **{k: np.array([v], dtype=float) for k, v in values.items()})
            self._last_monitor[name] = values
            interval = self.lab.poll_intervals.get(name, 1.0)
            self._monitor_due[name] = due + interval if due + interval > t else t + interval

    def _readings(self, streams: list[str]) -> str:
        parts = [f"{name} " + ", ".join(f"{k} {v:.4g}" for k, v in vals.items()) for name, vals in self._last_monitor.items()]
        for name in streams:
            g = self._last_gyro.get(name)
            if g is not None:
                parts.append(f"gyro {g[0]:+.3f} {g[1]:+.3f} {g[2]:+.3f} deg/s, {self._last_temp:.1f} degC")
        return "; ".join(parts)

    def _bit(self, step: Step) -> tuple[str, str]:
        mask = self.lab.instruments[step.params["instrument"]].run_bit()
        expected = step.params["expect_mask"]
        if mask == expected:
            return "passed", f"failed-subsystem mask 0x{mask:04x}"
        return "failed", f"failed-subsystem mask 0x{mask:04x}, expected 0x{expected:04x}"


def _describe(exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    return text if isinstance(exc, (BenchError,)) else f"{type(exc).__name__}: {text}"
