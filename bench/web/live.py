"""Runs started from the web station: each runs in-process on its own worker thread.

The runner thread is the only one that writes the run file (h5py): the page's controls reach it as
flags (:meth:`Runner.request_abort`, :meth:`Runner.toggle_pause`) and as queued operator events
(:meth:`Runner.operator_event`), recorded by the runner at its next check point. Prompts are asked
through a :class:`WebAsker`: the question waits on the page, the answer comes back through a queue
read in ticks (the runner's keepalive runs between ticks, so the run keeps its heartbeat and its
lab under watch), and is recorded with the source ``web <client address>``.
"""

from __future__ import annotations

import queue
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from bench.procedure import Procedure, Step
from bench.runner.operator import Operator

MAX_MESSAGES = 50
"""Progress messages kept per run for the page."""


@dataclass
class Question:
    """A prompt waiting on the page: ``text`` as shown (with its accepted answers), asked at ``asked_unix`` (s)."""

    text: str
    asked_unix: float


class WebAsker:
    """An :class:`~bench.runner.operator.Asker` whose person is at a browser: :meth:`show` puts the
    question on the page, :meth:`read_line` waits (at most ``timeout_s``) for :meth:`answer`."""

    def __init__(self) -> None:
        self._answers: queue.Queue[tuple[str, str, str]] = queue.Queue()
        self._lock = threading.Lock()
        self.question: Question | None = None
        self.last_origin = ""
        """Origin (``web <address>``) of the last answer read."""
        self.last_person = ""
        """Name the browser gave with the last answer read (its operator field)."""

    def show(self, text: str) -> None:
        with self._lock:
            self.question = Question(text, time.time())

    def read_line(self, timeout_s: float) -> str | None:
        try:
            line, origin, person = self._answers.get(timeout=max(0.0, timeout_s))
        except queue.Empty:
            return None
        with self._lock:
            self.question = None
            self.last_origin, self.last_person = origin, person
        return line

    def answer(self, line: str, origin: str, person: str = "") -> bool:
        """Hand the page's answer to the waiting prompt; False when no question waits."""
        with self._lock:
            if self.question is None:
                return False
        self._answers.put((line, origin, person))
        return True

    def close(self) -> None:
        """The run is over: no question waits any more."""
        with self._lock:
            self.question = None


class WebOperator(Operator):
    """An :class:`Operator` asking through a :class:`WebAsker`; an answer from the page is recorded
    with the source ``web <client address>`` instead of ``operator``, and with the name the page
    gave (:attr:`last_person`). A "no" reaches it only once the page has confirmed that it stops the
    run (:func:`check_answer`), so :meth:`confirm_abort` asks nothing more."""

    def __init__(self, asker: WebAsker):
        super().__init__(None, asker)
        self.asker = asker

    @property
    def last_person(self) -> str | None:  # type: ignore[override]
        return self.asker.last_person or None

    def confirm_abort(self, key: str, **_kw: Any) -> tuple[bool, str]:
        return True, ""

    def ask(self, key: str, text: str, simulated: bool, **kw: Any) -> tuple[str, str]:
        shown = kw.pop("show", None)

        def show(q: str) -> None:  # on the page, and wherever the runner shows it (its progress messages)
            self.asker.show(q)
            if shown is not None:
                shown(q)

        try:
            answer, source = super().ask(key, text, simulated, show=show, **kw)
        finally:
            self.asker.close()  # answered, timed out or aborted: nothing waits on the page any more
        return answer, (self.asker.last_origin or "web") if source == "operator" else source


def check_answer(text: Any, confirm_abort: Any) -> str:
    """An answer from the page, checked before it reaches the run: one of the accepted answers
    (a typo is refused at once, the prompt keeps waiting), and a "no" only with ``confirm_abort``
    true (it stops the run). :class:`InputError` naming ``answer`` otherwise; returns the answer."""
    from bench.errors import InputError
    from bench.runner.operator import accepted_answers, answer_verdict

    if not isinstance(text, str) or not text.strip() or len(text) > 200:
        raise InputError("expected an answer such as yes or no", None, "answer")
    verdict = answer_verdict(text)
    if verdict is None:
        raise InputError(f"{text.strip()[:40]!r} is not an accepted answer; accepted: {accepted_answers()} (no stops the run)",
                         None, "answer")
    if verdict == "no" and confirm_abort is not True:
        raise InputError("answering no stops the run (instruments to their safe state): confirm it (confirm_abort: true)",
                         None, "answer")
    return text.strip()


class PageProgress:
    """The runner's :class:`~bench.runner.engine.Progress` kept for the page: current step, run
    time, estimated total, readings and the last messages (read by the server's threads)."""

    def __init__(self) -> None:
        self.total_s = 0.0
        self.step_n = 0
        self.steps = 0
        self.step_name = ""
        self.step_type = ""
        self.run_time_s = 0.0
        self.readings = ""
        self.messages: list[str] = []
        self.stopped = False

    def start(self, procedure: Procedure, total_s: float) -> None:
        self.total_s, self.steps = float(total_s), len(procedure.steps)

    def step(self, n: int, total: int, step: Step) -> None:
        self.step_n, self.steps, self.step_name, self.step_type = n, total, step.name, step.type

    def advance(self, run_time_s: float, readings: str = "") -> None:
        self.run_time_s = float(run_time_s)
        if readings:
            self.readings = readings

    def message(self, text: str) -> None:
        self.messages = (self.messages + [text])[-MAX_MESSAGES:]

    def stop(self, run_time_s: float) -> None:
        self.run_time_s, self.stopped = float(run_time_s), True


@dataclass
class LiveRun:
    """One run started from the page. ``session`` is the :class:`~bench.runner.session.RunSession`."""

    run_id: str
    path: Path
    session: Any
    asker: WebAsker
    progress: PageProgress
    instruments: tuple[str, ...]
    sim: bool
    thread: threading.Thread | None = None
    result: Any = None
    error: str = ""
    done: threading.Event = field(default_factory=threading.Event)

    @property
    def runner(self) -> Any:
        return self.session.runner

    def state(self) -> dict[str, Any]:
        """What the live page shows beyond the run file: control state, prompt, progress, interlocks."""
        r, p, q = self.runner, self.progress, self.asker.question
        return {
            "in_process": True, "running": not self.done.is_set(), "paused": bool(r.paused), "aborting": bool(r.abort_reason),
            "abort_reason": r.abort_reason, "prompt": None if q is None or self.done.is_set() else {"text": q.text, "asked_unix": q.asked_unix},
            "progress": {"step": p.step_n, "steps": p.steps, "step_name": p.step_name, "step_type": p.step_type,
                         "run_time_s": p.run_time_s, "estimated_total_s": p.total_s, "readings": p.readings},
            "messages": p.messages[-10:], "interlocks": interlock_states(r), "limits": limit_states(r), "error": self.error,
        }


def interlock_states(runner: Any) -> list[dict[str, Any]]:
    """The procedure's interlocks with their latest value and state: ``ok``, ``beyond`` (the reading is
    outside its limits), ``inactive`` (a vacuum interlock outside vacuum), ``no reading``, ``stall``
    (watched by frame gaps). Read from another thread: values only, never an instrument."""
    from bench.procedure.signals import signal_units
    from bench.quantity_format import fmt_quantity, fmt_range

    out = []
    for lock in runner.procedure.interlocks:
        try:
            units = signal_units(lock.signal, runner.lab.kinds.get(lock.signal.split(".", 1)[0]))
        except (KeyError, AttributeError):
            units = ""
        item: dict[str, Any] = {"name": lock.name, "signal": lock.signal, "min": lock.minimum, "max": lock.maximum,
                                "active": lock.active, "value": None, "units": units, "value_text": "",
                                "limits_text": fmt_range(lock.minimum, lock.maximum, units)}
        if lock.stall_s is not None:
            item.update(state="stall watch", max_gap_s=lock.stall_s,
                        limits_text=f"no gap in the frames longer than {fmt_quantity(lock.stall_s, 's')}")
        elif lock.active == "vacuum" and not runner.in_vacuum:
            item["state"] = "inactive"
        else:
            inst, _, col = lock.signal.partition(".")
            v = runner.monitor.last.get(inst, {}).get(col.split(".")[0])
            if v is None or v != v:
                item["state"] = "no reading"
            else:
                item["value"] = float(v)
                item["value_text"] = fmt_quantity(float(v), units)
                item["state"] = "beyond" if lock.beyond(float(v)) else "ok"
        out.append(item)
    return out


def limit_states(runner: Any) -> list[dict[str, Any]]:
    """The hardware limits in force for this run (defaults, the lab config's and the procedure's
    ``limits:``, the narrowest winning; bench/procedure/limits.py), each with its state: the chamber's
    set-point limits are also watched on every reading as the lab's safety envelope (air and mount
    within them ± the envelope margin: ``ok`` or ``beyond``, with the reading); the other limits bound
    what the steps command and were checked on every step before the run started (``checked``).
    Read from another thread: values only, never an instrument."""
    from bench.procedure.limits import LIMIT_UNITS, effective_limits
    from bench.quantity_format import fmt_quantity, fmt_range
    from bench.runner.monitor import CHAMBER_SAFETY_MARGIN_C, ENVELOPE_COLUMNS, outside_envelope

    out = []
    for inst, kind in runner.lab.kinds.items():
        limits = effective_limits(kind, runner.lab.config_limits.get(inst, {}), runner.procedure.limits.get(inst, {}))
        for quantity, (lo, hi, source) in limits.items():
            units = LIMIT_UNITS.get(kind, {}).get(quantity, "").replace("delta_", "")
            item: dict[str, Any] = {"instrument": inst, "quantity": quantity, "min": lo, "max": hi, "source": source,
                                    "units": units, "value": None, "state": "checked", "limits_text": fmt_range(lo, hi, units),
                                    "value_text": ""}
            if kind == "tvac" and quantity == "set_point":
                item["watch"] = f"air and mount temperature within ± {CHAMBER_SAFETY_MARGIN_C:g} degC"
                values = [v for v in (runner.monitor.last.get(inst, {}).get(c) for c in ENVELOPE_COLUMNS) if v is not None and v == v]
                if not values:
                    item["state"] = "no reading"
                else:
                    worst = max(values, key=lambda v: max((lo - v) if lo is not None else 0.0, (v - hi) if hi is not None else 0.0))
                    item["value"] = float(worst)
                    item["value_text"] = fmt_quantity(float(worst), "degC")
                    item["state"] = "beyond" if outside_envelope(worst, lo, hi) else "ok"
            out.append(item)
    return out


class LiveRuns:
    """The runs started from this server, by run id (thread-safe)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._runs: dict[str, LiveRun] = {}

    def get(self, run_id: str) -> LiveRun | None:
        with self._lock:
            return self._runs.get(run_id)

    def busy_instruments(self) -> set[str]:
        """Instruments of the real lab held by runs still going (a dry-run holds none: its simulators are its own)."""
        with self._lock:
            return {i for r in self._runs.values() if not r.done.is_set() and not r.sim for i in r.instruments}

    def active(self) -> list[LiveRun]:
        with self._lock:
            return [r for r in self._runs.values() if not r.done.is_set()]

    def launch(self, live: LiveRun, on_end: Callable[[LiveRun], None] | None = None) -> None:
        """Run ``live`` on its own thread: ``runner.run()``, then ``lab.close()`` and the catalogue's
        ``run_ended()`` whatever happens."""
        def work() -> None:
            s = live.session
            try:
                live.result = s.runner.run()
            except Exception as exc:  # noqa: BLE001 - the server stays up; the page shows why
                live.error = f"{type(exc).__name__}: {exc}"
            finally:
                try:
                    s.lab.close()
                finally:
                    live.asker.close()
                    if s.catalog is not None:
                        s.catalog.run_ended()
                    live.done.set()
                    if on_end is not None:
                        on_end(live)

        with self._lock:
            self._runs[live.run_id] = live
        live.thread = threading.Thread(target=work, name=f"run {live.run_id}", daemon=True)
        live.thread.start()

    def stop_all(self, reason: str, timeout_s: float = 60.0) -> None:
        """Abort every run still going (the server is stopping) and wait up to ``timeout_s`` (s) for
        their safe states and files to close."""
        runs = self.active()
        for r in runs:
            r.runner.operator_event("stop", "server", reason)
            r.runner.request_abort(reason)
        deadline = time.monotonic() + timeout_s
        for r in runs:
            r.done.wait(max(0.0, deadline - time.monotonic()))
