"""What each action step does to the instruments: one handler per step type.

Handlers return ``(outcome, message)``: ``done`` (an action), ``passed`` / ``failed`` (a check
with limits), ``recorded`` (a check without limits: its value is stored, no verdict);
a condition that makes going on pointless or unsafe (a chamber that never reaches its set point,
an operator who says no) raises :class:`StepAbort`, which sends the run to the safe state.
Every wait goes through the runner's :meth:`~bench.runner.engine.Runner.wait_until`, so aborts,
pauses, polled readings, streams and interlocks keep working during it, and every wait has a
timeout.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from rich.markup import escape

from bench.errors import BenchError
from bench.procedure import Step
from bench.kinds import registry
from bench.procedure.schema import PROMPT_TIMEOUT_S, kind_step
from bench.procedure.signals import signal_units
from bench.record import layout
from bench.record.checks import has_limits
from bench.runner.operator import (
    CHOICES,
    MAX_INVALID_ANSWERS,
    NON_INTERACTIVE_SOURCES,
    NoAnswer,
    accepted_answers,
    answer_verdict,
    question,
)

if TYPE_CHECKING:  # pragma: no cover
    from bench.runner.engine import Runner

RATE_TOLERANCE_DPS = 0.002
"""A table rate counts as reached within 2 mdeg/s (two encoder counts per second at 0.001 deg)."""
ANGLE_TOLERANCE_DEG = 0.002
MOTION_TIMEOUT_S = 600.0
"""Longest a table or bench motion may take before the run aborts (s)."""


class StepAbort(BenchError):
    """A step cannot go on; the run aborts to the safe state with this reason."""


def comment(r: "Runner", step: Step) -> tuple[str, str]:
    r.progress.message(step.params["text"])
    r.rec.event("note", "procedure", step.params["text"], t_s=r.clock.now(), step=step.index)
    return "done", ""


def prompt(r: "Runner", step: Step) -> tuple[str, str]:
    """Ask the operator to act and confirm: the question shows the accepted answers, anything else
    is asked again (at most :data:`MAX_INVALID_ANSWERS` answers, within the step's ``timeout`` of wall
    time). Each question is an event ``prompt`` (the run reads ``waiting`` until it is answered),
    each answer an event ``operator``; the run keeps its heartbeat meanwhile (:meth:`Runner.keep_watch`)."""
    key = step.params.get("id") or step.name
    text = step.params["text"]
    timeout_s = float(step.params.get("timeout") or PROMPT_TIMEOUT_S)
    deadline = time.monotonic() + timeout_s
    answer = ""
    attempt = 0
    for attempt in range(1, MAX_INVALID_ANSWERS + 1):
        r.rec.event(layout.EVENT_PROMPT, "operator", question(text), t_s=r.clock.now(), step=step.index,
                    data=json.dumps({"id": key, "text": text, "choices": list(CHOICES), "attempt": attempt,
                                     "timeout_s": timeout_s}).encode())
        r.rec.flush()  # readers see the question (and the waiting run) at once
        try:
            answer, source = r.operator.ask(key, text, simulated=r.lab.mode == "sim", keepalive=r.keep_watch, deadline=deadline,
                                            show=lambda q: r.progress.message(escape(q)))
        except NoAnswer as exc:
            why = f"within {timeout_s:g} s" if exc.timed_out else f"({exc})"
            raise StepAbort(f"no answer at prompt {key!r} {why}: {text}") from None
        verdict = answer_verdict(answer)
        r.rec.event(layout.EVENT_OPERATOR, "prompt", json.dumps({"id": key, "text": text, "answer": answer, "source": source,
                                                                  "attempt": attempt, "valid": verdict is not None}),
                    t_s=r.clock.now(), step=step.index)
        if verdict == "yes":
            return "done", f"confirmed ({source})"
        if verdict == "no":
            raise StepAbort(f"operator answered {answer!r} at prompt {key!r}: {text}")
        if source in NON_INTERACTIVE_SOURCES:
            break  # the same answer would come again
        if attempt < MAX_INVALID_ANSWERS:
            r.progress.message(escape(f"{answer!r} is not an accepted answer; accepted: {accepted_answers()} "
                                      f"(asking again, {attempt + 1} of {MAX_INVALID_ANSWERS})"))
    raise StepAbort(f"no valid answer at prompt {key!r} after {attempt} attempt{'s' if attempt != 1 else ''} "
                    f"(last {answer!r}; accepted: {accepted_answers()}): {text}")


def wait(r: "Runner", step: Step) -> tuple[str, str]:
    r.wait_until(step.params["duration"])
    return "done", ""


def record(r: "Runner", step: Step) -> tuple[str, str]:
    name = step.params["instrument"]
    window = step.params.get("window") or step.name
    rows = r.recording(name, window, step.meta, lambda: r.wait_until(step.params["duration"]))
    return "done", f"{rows} rows in window {window!r}"


def wait_until_stable(r: "Runner", step: Step) -> tuple[str, str]:
    p = step.params
    history: list[tuple[float, float]] = []

    def stable() -> bool:
        t, v = r.clock.now(), r.read_signal(p["signal"])
        if not math.isfinite(v):
            history.clear()
            return False
        history.append((t, v))
        while history and t - history[0][0] > p["hold"]:
            history.pop(0)
        values = [x for _, x in history]
        held = len(history) > 1 and t - history[0][0] >= p["hold"] - 1e-9 - r.poll_interval(p["signal"])
        return held and max(values) - min(values) <= p["band"]

    def run() -> bool:
        return r.wait_until(p["timeout"], stable)

    if p.get("record"):
        ok = [False]
        window = p.get("window") or step.name

        def body() -> None:
            ok[0] = run()

        r.recording(p["record"], window, step.meta, body)
        ok = ok[0]
    else:
        ok = run()
    if not ok:
        raise StepAbort(f"{p['signal']} not stable within {p['band']:g} over {p['hold']:g} s after {p['timeout']:g} s")
    return "done", f"{p['signal']} stable at {r.read_signal(p['signal']):.4g}"


def mount(r: "Runner", step: Step) -> tuple[str, str]:
    """Remount the unit with axis ``up`` on the table axis: the operator confirms; a dry-run also
    turns the simulated unit on its platter."""
    up = step.params["up"]
    key = step.params.get("id") or f"mount_{up.replace('-', 'minus_')}"
    text = f"Mount the unit with its {up} axis along the table's rotation axis (platter normal), then confirm."
    outcome, msg = prompt(r, Step(step.index, "prompt", step.name, {"text": text, "id": key}, step.location, step.path))
    if r.lab.mode == "sim" and r.lab.world is not None:
        r.lab.world.set_mount(up)
        msg += f"; simulated unit mounted {up} up"
    return outcome, msg


# ---- vibration ------------------------------------------------------------------------------------
def vibrate(r: "Runner", step: Step) -> tuple[str, str]:
    """Run a shaker profile along an axis. On hardware the shaker has its own controller: the
    operator runs it and confirms. In a dry-run the simulated world shakes the unit."""
    from bench.model.vibration import load_vibration

    p = step.params
    spec = load_vibration(Path(p["profile"]))
    duration = spec.duration_s
    if r.lab.mode == "sim" and r.lab.world is not None:
        r.lab.world.vibration.add(spec.event(p["axis"], r.clock.now(), seed=len(r.outcomes)))
        body = (lambda: r.wait_until(duration))
        if p.get("record"):
            r.recording(p["record"], p.get("window") or step.name, {"vibration": spec.name, "axis": p["axis"]}, body)
        else:
            body()
        return "done", f"{spec.name} along {p['axis']} for {duration:g} s (simulated shaker)"
    text = f"Run '{spec.name}' on the shaker along {p['axis']} ({duration:g} s), then confirm."
    outcome, msg = prompt(r, Step(step.index, "prompt", step.name, {"text": text, "id": step.name}, step.location, step.path))
    return outcome, msg


# ---- checks ---------------------------------------------------------------------------------------
def check(r: "Runner", step: Step) -> tuple[str, str]:
    p = step.params
    value, basis = r.windows.statistic(p["signal"], p["statistic"], p["window"])
    lo, hi = p.get("min"), p.get("max")
    problems = []
    if lo is not None and value < lo:
        problems.append(f"below {lo:g}")
    if hi is not None and value > hi:
        problems.append(f"above {hi:g}")
    ref_text = ""
    if p.get("reference"):
        ref = r.results.get(p["reference"])
        if ref is None:
            raise StepAbort(f"check {step.name!r} refers to {p['reference']!r}, which has no result yet")
        diff = value - ref["value"]
        ref_text = f", {diff:+.6g} from {p['reference']} ({ref['value']:.6g})"
        if p.get("max_difference") is not None and abs(diff) > p["max_difference"]:
            problems.append(f"differs from {p['reference']} by more than {p['max_difference']:g}")
    limited = has_limits(lo, hi, p.get("max_difference"), p.get("reference"))
    outcome = layout.OUTCOME_FAILED if problems else (layout.OUTCOME_PASSED if limited else layout.OUTCOME_RECORDED)
    result = {"name": step.name, "signal": p["signal"], "statistic": p["statistic"], "window": p["window"], "value": value,
              "min": lo, "max": hi, "reference": p.get("reference") or None, "outcome": outcome, "basis": basis,
              "max_difference": p.get("max_difference"), "units": _signal_units(r, p["signal"]), "step": step.index}
    r.results[step.name] = result
    r.rec.event(layout.EVENT_CHECK, step.name, f"{outcome}: {p['statistic']} of {p['signal']} = {value:.6g}", t_s=r.clock.now(),
                step=step.index, data=json.dumps(result).encode())
    if not limited:
        return outcome, f"{p['statistic']} {p['signal']} = {value:.6g}{ref_text}, no limits: no verdict ({basis})"
    limits = f"[{'-inf' if lo is None else f'{lo:g}'}, {'inf' if hi is None else f'{hi:g}'}]"
    return outcome, f"{p['statistic']} {p['signal']} = {value:.6g} {limits}{ref_text} ({basis})" + (f": {'; '.join(problems)}" if problems else "")


def _signal_units(r: "Runner", signal: str) -> str:
    """Units of ``signal`` on this lab (``""`` if its instrument or column is unknown)."""
    try:
        inst = signal.split(".", 1)[0]
        return signal_units(signal, r.lab.kinds.get(inst), r.lab.signals.get(inst))
    except KeyError:
        return ""


CORE_HANDLERS = {
    "comment": comment, "prompt": prompt, "wait": wait, "record": record, "wait_until_stable": wait_until_stable,
    "mount": mount, "vibrate": vibrate, "check": check,
}
"""Core step type -> handler (:data:`bench.procedure.schema.CORE_STEP_TYPES`)."""


def handler(stype: str) -> Callable[["Runner", Step], tuple[str, str]]:
    """The handler of step type ``stype``: the core's, or the one its kind names (``StepDef.handler``,
    imported on first use). ``KeyError`` for a type nobody handles."""
    fn = CORE_HANDLERS.get(stype)
    if fn is not None:
        return fn
    found = kind_step(stype)
    if found is None:
        raise KeyError(f"no handler for step type {stype!r}")
    return registry.load(found[1].handler)
