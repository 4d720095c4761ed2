"""The lab monitor: polled instruments, interlocks, the lab's own safety envelope, link recovery.

While a step waits, the runner asks the monitor to :meth:`~LabMonitor.poll` every instrument whose
poll interval has come (one row of ``/streams/NAME/monitor`` each), to evaluate the procedure's
interlocks on each reading and the always-on chamber envelope, and to check the streams for
stalls. A link fault on an idempotent read (a polled reading, a stream drain) is recovered by
reconnecting with backoff (:meth:`~LabMonitor.guarded`); the gap is recorded.
"""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING, Callable


from bench.errors import KNOWN_ERRORS, BenchError, DeviceFault, InstrumentError
from bench.procedure.signals import parse_signal
from bench.record import Column, layout
from bench.runner.instruments import Polled

if TYPE_CHECKING:  # pragma: no cover
    from bench.runner.engine import Runner

RECONNECT_BACKOFF_S = (0.5, 1.0, 2.0, 4.0, 8.0)
"""Waits between reconnection attempts after a link fault (s of run time); the last repeats."""

CHAMBER_SAFETY_MARGIN_C = 5.0
"""A chamber temperature reading more than this beyond the chamber's set-point limits (defaults, lab
config, procedure: the narrowest) aborts the run whatever the procedure's interlocks say: the
controller is not controlling (runaway heater or cooler, failed sensor). Our choice [U]: above the
overshoot of a controlled ramp, below damage."""

ENVELOPE_COLUMNS = ("air_temp", "mount_temp")
"""The chamber readings (degC) the lab's safety envelope watches."""


def outside_envelope(value_c: float, low_c: float | None, high_c: float | None) -> bool:
    """Whether a chamber temperature (degC) lies beyond the set-point limits ``low_c``..``high_c``
    by more than :data:`CHAMBER_SAFETY_MARGIN_C`: the chamber is not under control."""
    return (low_c is not None and value_c < low_c - CHAMBER_SAFETY_MARGIN_C) or (high_c is not None and value_c > high_c + CHAMBER_SAFETY_MARGIN_C)


DEFAULT_POLL_INTERVAL_S = 1.0
DEFAULT_RECONNECT_TIMEOUT_S = 30.0
"""Reconnection limit of an instrument the lab gives none for (s; the config's default)."""


class InterlockTrip(BenchError):
    """An interlock or the lab's safety envelope tripped: the run aborts to the safe state."""


def gap_message(name: str, t0: float, t1: float, attempts: int) -> str:
    """The ``gap`` event's message of a link restored after a fault at ``t0`` (run time, s)."""
    return f"link restored after {t1 - t0:.1f} s ({attempts} attempt(s)); no data from {name} in between"


def describe(exc: BaseException) -> str:
    """One line for an exception: our own errors as they are, others with their type."""
    text = str(exc) or type(exc).__name__
    return text if isinstance(exc, KNOWN_ERRORS) else f"{type(exc).__name__}: {text}"


class LabMonitor:
    """Watches the polled instruments of one run (``run`` is the :class:`~bench.runner.engine.Runner`)."""

    def __init__(self, run: "Runner"):
        self.run = run
        self.keys: dict[str, str] = {}
        """Instrument -> run-file key of its monitor stream."""
        self.due: dict[str, float] = {}
        """Instrument -> run time of its next reading (s)."""
        self.last: dict[str, dict[str, float]] = {}
        self.envelopes: dict[str, tuple] = {}
        self.signals: dict[str, dict[str, str]] = {}
        """Instrument -> column -> its signal name (``INSTRUMENT.COLUMN``), made once."""
        self.units: dict[str, dict[str, str]] = {}
        """Instrument -> column -> its units (as its monitor stream declares them)."""
        """Chamber -> its set-point limits (low, high degC, source), read at its first reading."""

    def declare(self, name: str, drv: Polled) -> None:
        """Declare ``/streams/NAME/monitor`` with the driver's columns; first reading due at 0 s."""
        interval = self.interval(name)
        cols = [Column(c, u, "f8") for c, u in drv.monitor_columns()]
        self.units[name] = {c.name: c.units for c in cols}
        self.keys[name] = self.run.rec.add_stream(name, cols, layout.MONITOR_STREAM, rate_hz=1.0 / interval)
        self.due[name] = 0.0

    def interval(self, name: str) -> float:
        """Poll interval of instrument ``name`` (s)."""
        return self.run.lab.poll_intervals.get(name, DEFAULT_POLL_INTERVAL_S)

    # ---- readings ---------------------------------------------------------------------------
    def poll(self, t: float) -> None:
        """Read every polled instrument whose interval has come, log a row, evaluate interlocks."""
        for name, due in list(self.due.items()):
            if t + 1e-9 < due:
                continue
            self.guarded(name, lambda n=name: self.poll_one(n, self.run.clock.now()))
            interval = self.interval(name)
            self.due[name] = due + interval if due + interval > t else t + interval

    def poll_one(self, name: str, t: float) -> None:
        """Read instrument ``name`` now (run time ``t``, s)."""
        run = self.run
        values = run.lab.instruments[name].monitor()
        run.rec.append_row(self.keys[name], t, values)
        self.last[name] = values
        if run.windows.any_open:
            signals = self.signals.get(name)
            if signals is None:
                signals = self.signals[name] = {}
            for col, v in values.items():
                sig = signals.get(col)
                if sig is None:
                    sig = signals[col] = f"{name}.{col}"
                run.windows.feed_one(sig, t, float(v))
        self.check_interlocks(name)
        self.check_lab_safety(name, values)

    def read_signal(self, signal: str, fresh: bool = False) -> float:
        """Latest value of ``INSTRUMENT.COLUMN[.AXIS]``: a polled reading (``fresh``: read now) or
        the newest frame of a stream. NaN when nothing has been read yet."""
        inst, column, axis = parse_signal(signal)
        if inst in self.keys:
            if fresh:
                self.poll_one(inst, self.run.clock.now())
            return float(self.last.get(inst, {}).get(column, float("nan")))
        return self.run.ingest.latest(inst, column, axis)

    def readings(self) -> list[str]:
        """One progress fragment per polled instrument (its first three columns, each with its
        units: ``rate_table angle 41.86 deg, rate 5 deg/s, tilt -36.4 deg``)."""
        from bench.quantity_format import fmt_reading

        return [f"{name} " + ", ".join(f"{k} {fmt_reading(v, self.units.get(name, {}).get(k, ''), k)}" for k, v in list(vals.items())[:3])
                for name, vals in self.last.items()]

    # ---- link faults ------------------------------------------------------------------------
    def guarded(self, name: str, read: Callable[[], object]) -> None:
        """Run an idempotent read (a polled reading, a stream drain); a link fault (timeout, lost
        port, garbled answer) is recovered by reconnecting with backoff, the gap recorded. A
        fault the instrument reports itself (DeviceFault) is not a link fault: it aborts."""
        try:
            read()
        except DeviceFault:
            raise
        except (InstrumentError, OSError) as exc:
            self.reconnect(name, exc)
            read()

    def reconnect(self, name: str, exc: BaseException) -> None:
        """Reopen instrument ``name`` with backoff until it identifies again, within its
        ``reconnect_timeout`` (s); restart its stream if a recording window is open. An abort
        request stops the attempts. The fault and the gap are recorded and shown."""
        run = self.run
        clock = run.clock
        t0 = clock.now()
        limit = self.reconnect_limit(name)
        run.rec.event("fault", name, f"link fault: {describe(exc)}; reconnecting (up to {limit:g} s)", t_s=t0, step=run.current_step)
        run.progress.message(f"{name}: link fault ({describe(exc)}); reconnecting")
        attempts = self.restore_link(name, exc, limit, before_wait=run.check_abort, restart_stream=True,
                                     after_wait=lambda n: run.progress.advance(clock.now(), f"{name}: reconnecting (attempt {n})"))
        t1 = clock.now()
        for w in run.windows.all.values():
            if w.open:
                w.meta.setdefault("gaps_s", []).append([t0, t1])
        run.rec.event("gap", name, gap_message(name, t0, t1, attempts), t_s=t1, step=run.current_step,
                      data=json.dumps({"t_start_s": t0, "t_end_s": t1, "attempts": attempts}).encode())
        run.progress.message(f"{name}: link restored after {t1 - t0:.1f} s")

    def reconnect_limit(self, name: str) -> float:
        """How long a link fault of ``name`` is retried (s): its config's ``reconnect_timeout``."""
        return self.run.lab.reconnect_timeouts.get(name, DEFAULT_RECONNECT_TIMEOUT_S)

    def restore_link(self, name: str, exc: BaseException, limit_s: float, *, before_wait: Callable[[], None],
                     after_wait: Callable[[int], None], restart_stream: bool, why: str = "") -> int:
        """Reopen instrument ``name`` (``Lab.reopen``) with backoff (:data:`RECONNECT_BACKOFF_S`, run
        time) until it identifies again; returns the attempts made. Records and shows nothing, so any
        thread may call it (the safe state of an abort runs one per instrument). ``before_wait()`` may
        raise to stop (an abort request, a missed deadline); ``after_wait(attempt)`` is called after
        each wait; ``restart_stream``: restart the stream of a board whose recording window is open.
        Raises :class:`InstrumentError` ("not restored within ``limit_s`` s" + ``why``) when the next
        wait would end beyond ``limit_s`` (s of run time) after the first; a :class:`DeviceFault` as is."""
        run = self.run
        clock = run.clock
        t0 = clock.now()
        attempt, last = 0, exc
        while True:
            before_wait()
            wait = RECONNECT_BACKOFF_S[min(attempt, len(RECONNECT_BACKOFF_S) - 1)]
            if clock.now() - t0 + wait > limit_s:
                raise InstrumentError(f"{name}: link lost ({describe(last)}); not restored within {limit_s:.4g} s{why}")
            clock.sleep(wait)
            attempt += 1
            after_wait(attempt)
            try:
                drv = run.lab.reopen(name)
                drv.identify()
                if name in self.keys:
                    drv.monitor_columns()  # a fresh driver sets its instrument up again (thermocouple scan list)
                if restart_stream and name in run.ingest.streaming and not drv.get_config()["streaming"]:
                    drv.start_stream()
                return attempt
            except DeviceFault:
                raise
            except (InstrumentError, OSError) as again:
                last = again

    # ---- interlocks and the lab's envelope ----------------------------------------------------
    def check_interlocks(self, inst: str) -> None:
        """Trip on any interlock of the procedure on instrument ``inst`` whose reading is out of
        bounds (or has no valid reading: an open sensor)."""
        for lock in self.run.procedure.interlocks:
            if lock.stall_s is not None or not lock.signal.startswith(inst + "."):
                continue
            if lock.active == "vacuum" and not self.run.in_vacuum:
                continue
            v = self.read_signal(lock.signal)
            if math.isnan(v):
                if inst in self.last and lock.signal.split(".")[1] in self.last[inst]:
                    self.trip(f"interlock {lock.name!r}: {lock.signal} has no valid reading (open sensor?)")
                continue
            if lock.beyond(v):
                lim = f"min {lock.minimum:g}" if lock.minimum is not None and v < lock.minimum else f"max {lock.maximum:g}"
                self.trip(f"interlock {lock.name!r}: {lock.signal} = {v:.4g} beyond {lim}")

    def check_lab_safety(self, inst: str, values: dict[str, float]) -> None:
        """Always-on limits of the lab, independent of the procedure's interlocks: the chamber's
        air and mount temperatures stay within its set-point limits ± CHAMBER_SAFETY_MARGIN_C."""
        run = self.run
        if run.lab.kinds.get(inst) != "tvac":
            return
        limits = self.envelopes.get(inst)
        if limits is None:
            from bench.procedure.limits import effective_limits

            limits = self.envelopes[inst] = effective_limits("tvac", run.lab.config_limits.get(inst, {}),
                                                             run.procedure.limits.get(inst, {}))["set_point"]
        lo, hi, src = limits
        for col in ENVELOPE_COLUMNS:
            v = values.get(col)
            if v is None or math.isnan(v):
                continue
            if outside_envelope(v, lo, hi):
                self.trip(f"lab safety: {inst}.{col} = {v:.1f} degC beyond the chamber limits "
                          f"{lo:g}..{hi:g} degC ({src}) by more than {CHAMBER_SAFETY_MARGIN_C:g} degC: the chamber is not under control")

    def check_stalls(self, t: float) -> None:
        """Trip a stall interlock whose stream sent no frame for longer than its limit (s)."""
        ingest = self.run.ingest
        for lock in self.run.procedure.interlocks:
            if lock.stall_s is None or lock.signal not in ingest.streaming:
                continue
            gap = t - ingest.last_frame_t.get(lock.signal, t)
            if gap > lock.stall_s:
                self.trip(f"interlock {lock.name!r}: no frames from {lock.signal} for {gap:.1f} s (limit {lock.stall_s:g} s)")

    def trip(self, reason: str) -> None:
        self.run.request_abort(reason)
        raise InterlockTrip(reason)
