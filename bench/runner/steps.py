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
from typing import TYPE_CHECKING

from rich.markup import escape

from bench.errors import BenchError
from bench.procedure import Step
from bench.procedure.schema import PROMPT_TIMEOUT_S
from bench.procedure.signals import signal_units
from bench.record import layout
from bench.quantity_format import fmt_quantity, fmt_range
from bench.record.checks import display_value, has_limits
from bench.runner.operator import (
    CHOICES,
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
    """Ask the operator to act and confirm: the question shows the accepted answers and that "no"
    aborts the run; anything else is asked again until the step's ``timeout`` of wall time (a typo
    never ends a run). A "no" typed by a person is confirmed first (:meth:`Operator.confirm_abort`);
    from an answers file it aborts at once. Each question is an event ``prompt`` (the run reads
    ``waiting`` until it is answered), each answer an event ``operator`` (with who answered and from
    where); the run keeps its heartbeat meanwhile (:meth:`Runner.keep_watch`)."""
    key = step.params.get("id") or step.name
    text = step.params["text"]
    timeout_s = float(step.params.get("timeout") or PROMPT_TIMEOUT_S)
    deadline = time.monotonic() + timeout_s
    show = lambda q: r.progress.message(escape(q))  # noqa: E731
    attempt = 0
    while True:
        attempt += 1
        r.rec.event(layout.EVENT_PROMPT, "operator", question(text, no_aborts=True), t_s=r.clock.now(), step=step.index,
                    data=json.dumps({"id": key, "text": text, "choices": list(CHOICES), "attempt": attempt,
                                     "timeout_s": timeout_s}).encode())
        r.rec.flush()  # readers see the question (and the waiting run) at once
        try:
            answer, source = r.operator.ask(key, text, simulated=r.lab.mode == "sim", keepalive=r.keep_watch, deadline=deadline,
                                            show=show, no_aborts=True)
        except NoAnswer as exc:
            why = f"within {timeout_s:g} s" if exc.timed_out else f"({exc})"
            raise StepAbort(f"no answer at prompt {key!r} {why}: {text}") from None
        verdict = answer_verdict(answer)
        person = r.operator.last_person or r.operator_name
        _record_answer(r, step, {"id": key, "text": text, "answer": answer, "source": source, "operator": person,
                                 "attempt": attempt, "valid": verdict is not None})
        if verdict == "yes":
            return "done", f"confirmed ({source})"  # who: the operator event (the wording replays of older runs compare)
        interactive = source not in NON_INTERACTIVE_SOURCES
        if verdict == "no":
            if interactive:
                try:
                    confirmed, line = r.operator.confirm_abort(key, keepalive=r.keep_watch, deadline=deadline, show=show)
                except NoAnswer as exc:
                    why = f"within {timeout_s:g} s" if exc.timed_out else f"({exc})"
                    raise StepAbort(f"no answer at prompt {key!r} {why}: {text}") from None
                if line:
                    _record_answer(r, step, {"id": key, "confirm_abort": line, "confirmed": confirmed, "source": source,
                                             "operator": r.operator.last_person or person, "attempt": attempt})
                if not confirmed:
                    r.progress.message(escape(f"not stopped; asking {key!r} again"))
                    continue
            raise StepAbort(f"operator {person} answered {answer!r} at prompt {key!r}: {text}")
        if not interactive:  # the same answer would come again
            raise StepAbort(f"no valid answer at prompt {key!r} ({answer!r} from {source}; accepted: {accepted_answers()}): {text}")
        r.progress.message(escape(f"{answer!r} is not an accepted answer; accepted: {accepted_answers()} (no aborts the run); "
                                  "asking again"))


def _record_answer(r: "Runner", step: Step, info: dict) -> None:
    """An ``operator`` event (source ``prompt``) with an answer to the prompt of ``step``."""
    r.rec.event(layout.EVENT_OPERATOR, "prompt", json.dumps(info), t_s=r.clock.now(), step=step.index)


def power(r: "Runner", step: Step) -> tuple[str, str]:
    r.lab.instruments[step.params["instrument"]].sensor_power(step.params["on"])
    return "done", "sensors on" if step.params["on"] else "sensors off"


def configure(r: "Runner", step: Step) -> tuple[str, str]:
    drv = r.lab.instruments[step.params["instrument"]]
    done = []
    if "odr" in step.params:
        hz = step.params["odr"]
        if abs(hz - round(hz)) > 1e-9:
            raise ValueError(f"step {step.path}: output data rate must be a whole number of Hz, got {hz:g} Hz")
        drv.set_odr(int(round(hz)))
        done.append(f"odr {int(round(hz))} Hz")
    if "moving_average" in step.params:
        drv.set_moving_average(int(step.params["moving_average"]))
        done.append(f"moving average N={int(step.params['moving_average'])}")
    cfg = drv.get_config()
    if not cfg.get("read_back", True):
        return "done", ", ".join(done) + " (acknowledged; not read back: the board has no GET_CONFIG)"
    if "odr" in step.params and cfg["odr_hz"] != int(round(step.params["odr"])) or (
        "moving_average" in step.params and cfg["moving_avg_n"] != int(step.params["moving_average"])
    ):
        return "failed", ", ".join(done) + f" requested, but the board reports odr {cfg['odr_hz']} Hz, N={cfg['moving_avg_n']}"
    return "done", ", ".join(done) + " (read back from the board)"


def wait(r: "Runner", step: Step) -> tuple[str, str]:
    r.wait_until(step.params["duration"])
    return "done", ""


def record(r: "Runner", step: Step) -> tuple[str, str]:
    name = step.params["instrument"]
    window = step.params.get("window") or step.name
    rows = r.recording(name, window, step.meta, lambda: r.wait_until(step.params["duration"]))
    return "done", f"{rows} rows in window {window!r}"


def bit(r: "Runner", step: Step) -> tuple[str, str]:
    mask = r.lab.instruments[step.params["instrument"]].run_bit()
    expected = step.params["expect_mask"]
    if mask == expected:
        return "passed", f"failed-subsystem mask 0x{mask:04x}"
    return "failed", f"failed-subsystem mask 0x{mask:04x}, expected 0x{expected:04x}"


# ---- chamber ------------------------------------------------------------------------------------
def set_temperature(r: "Runner", step: Step) -> tuple[str, str]:
    p = step.params
    drv = r.lab.instruments[p["instrument"]]
    drv.set_point(p["set_point"], p.get("ramp", 0.0))
    what = f"set point {p['set_point']:g} degC" + (f" at {p['ramp']:g} degC/min" if p.get("ramp") else "")
    if not p.get("wait"):
        return "done", what
    sig = f"{p['instrument']}.air_temp"
    ok = r.wait_until(p["timeout"], lambda: abs(r.read_signal(sig) - p["set_point"]) <= p["band"])
    if not ok:
        raise StepAbort(f"{p['instrument']}: chamber air did not reach {p['set_point']:g} degC ± {p['band']:g} within {p['timeout']:g} s (now {r.read_signal(sig):.1f} degC)")
    return "done", f"{what}; reached ({r.read_signal(sig):.1f} degC)"


def pump_down(r: "Runner", step: Step) -> tuple[str, str]:
    p = step.params
    r.lab.instruments[p["instrument"]].pump_down()
    sig = f"{p['instrument']}.pressure"
    if not r.wait_until(p["timeout"], lambda: r.read_signal(sig) <= p["pressure"]):
        raise StepAbort(f"{p['instrument']}: pressure did not fall to {p['pressure']:g} Torr within {p['timeout']:g} s (now {r.read_signal(sig):.3g} Torr)")
    r.in_vacuum = True
    return "done", f"{r.read_signal(sig):.3g} Torr"


def vent(r: "Runner", step: Step) -> tuple[str, str]:
    p = step.params
    r.in_vacuum = False
    r.lab.instruments[p["instrument"]].vent()
    sig = f"{p['instrument']}.pressure"
    if not r.wait_until(p["timeout"], lambda: r.read_signal(sig) >= p["pressure"]):
        raise StepAbort(f"{p['instrument']}: pressure did not rise to {p['pressure']:g} Torr within {p['timeout']:g} s")
    return "done", f"{r.read_signal(sig):.3g} Torr"


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
    units = _signal_units(r, p["signal"])
    if not ok:
        raise StepAbort(f"{p['signal']} not stable within {fmt_quantity(p['band'], units)} over {fmt_quantity(p['hold'], 's')} "
                        f"after {fmt_quantity(p['timeout'], 's')}")
    return "done", f"{p['signal']} stable at {fmt_quantity(r.read_signal(p['signal']), units)}"


# ---- rate table and stepper bench -----------------------------------------------------------------
def table_rate(r: "Runner", step: Step) -> tuple[str, str]:
    p = step.params
    drv = r.lab.instruments[p["instrument"]]
    actual = drv.set_rate(p["rate"], p.get("accel"))
    sig = f"{p['instrument']}.rate"
    if not r.wait_until(MOTION_TIMEOUT_S, lambda: abs(r.read_signal(sig, fresh=True) - actual) <= RATE_TOLERANCE_DPS):
        raise StepAbort(f"{p['instrument']}: table did not reach {actual:g} deg/s within {MOTION_TIMEOUT_S:g} s")
    if p.get("settle"):
        r.wait_until(p["settle"])
    return "done", f"{actual:+g} deg/s"


def _wait_target(r: "Runner", inst: str, what: str) -> None:
    def reached() -> bool:
        s = r.lab.instruments[inst].read()  # looked up each time: a link fault may reopen the driver
        if s["any_fault"]:
            raise StepAbort(f"{inst}: drive fault during {what}")
        return bool(s["target_reached"] and s["tilt_target_reached"])

    if not r.wait_until(MOTION_TIMEOUT_S, reached):
        raise StepAbort(f"{inst}: {what} not finished within {MOTION_TIMEOUT_S:g} s")


def table_move(r: "Runner", step: Step) -> tuple[str, str]:
    p = step.params
    r.lab.instruments[p["instrument"]].move_to(p["angle"], p.get("rate"))
    _wait_target(r, p["instrument"], f"move to {p['angle']:g} deg")
    return "done", f"at {r.read_signal(p['instrument'] + '.angle', fresh=True):.3f} deg"


def table_tilt(r: "Runner", step: Step) -> tuple[str, str]:
    p = step.params
    r.lab.instruments[p["instrument"]].tilt(p["angle"])
    _wait_target(r, p["instrument"], f"tilt to {p['angle']:g} deg")
    return "done", f"tilted {r.read_signal(p['instrument'] + '.tilt', fresh=True):.3f} deg"


def table_stop(r: "Runner", step: Step) -> tuple[str, str]:
    inst = step.params["instrument"]
    r.lab.instruments[inst].stop()
    if not r.wait_until(MOTION_TIMEOUT_S, lambda: abs(r.read_signal(f"{inst}.rate", fresh=True)) <= RATE_TOLERANCE_DPS):
        raise StepAbort(f"{inst}: table did not stop within {MOTION_TIMEOUT_S:g} s")
    return "done", "stopped"


def bench_rate(r: "Runner", step: Step) -> tuple[str, str]:
    p = step.params
    drv = r.lab.instruments[p["instrument"]]
    if p["rate"] == 0:
        drv.stop()
        msg = "stopped"
    else:
        actual = drv.set_rate(p["rate"])
        drv.run()
        msg = f"{actual:+.4f} deg/s"
    if p.get("settle"):
        r.wait_until(p["settle"])
    return "done", msg


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
    units = _signal_units(r, p["signal"])

    def shown(v: float | None) -> str:  # a value in the check's display units (scale-factor errors in %)
        x, u = display_value(p["statistic"], v, units)
        return fmt_quantity(x, u)

    problems = []
    if lo is not None and value < lo:
        problems.append(f"below {shown(lo)}")
    if hi is not None and value > hi:
        problems.append(f"above {shown(hi)}")
    ref_text = ""
    if p.get("reference"):
        ref = r.results.get(p["reference"])
        if ref is None:
            raise StepAbort(f"check {step.name!r} refers to {p['reference']!r}, which has no result yet")
        diff = value - ref["value"]
        ref_text = f", {display_signed(p['statistic'], diff, units)} from {p['reference']} ({shown(ref['value'])})"
        if p.get("max_difference") is not None and abs(diff) > p["max_difference"]:
            problems.append(f"differs from {p['reference']} by more than {shown(p['max_difference'])}")
    limited = has_limits(lo, hi, p.get("max_difference"), p.get("reference"))
    outcome = layout.OUTCOME_FAILED if problems else (layout.OUTCOME_PASSED if limited else layout.OUTCOME_RECORDED)
    result = {"name": step.name, "signal": p["signal"], "statistic": p["statistic"], "window": p["window"], "value": value,
              "min": lo, "max": hi, "reference": p.get("reference") or None, "outcome": outcome, "basis": basis,
              "max_difference": p.get("max_difference"), "units": units, "step": step.index}
    r.results[step.name] = result
    r.rec.event(layout.EVENT_CHECK, step.name, f"{outcome}: {p['statistic']} of {p['signal']} = {shown(value)}", t_s=r.clock.now(),
                step=step.index, data=json.dumps(result).encode())
    if not limited:
        return outcome, f"{p['statistic']} {p['signal']} = {shown(value)}{ref_text}, no limits: no verdict ({basis})"
    x_lo, u = display_value(p["statistic"], lo, units)
    x_hi, _ = display_value(p["statistic"], hi, units)
    limits = f"limits {fmt_range(x_lo, x_hi, u)}" if lo is not None or hi is not None else "no limits"
    return outcome, (f"{p['statistic']} {p['signal']} = {shown(value)} ({limits}{ref_text}; {basis})"
                     + (f": {'; '.join(problems)}" if problems else ""))


def display_signed(statistic: str, value: float, units: str) -> str:
    """A difference in the check's display units with its sign: ``+0.012 %``."""
    x, u = display_value(statistic, value, units)
    return fmt_quantity(x, u, signed=True)


def _signal_units(r: "Runner", signal: str) -> str:
    """Units of ``signal`` on this lab (``""`` if its instrument or column is unknown)."""
    try:
        inst = signal.split(".", 1)[0]
        return signal_units(signal, r.lab.kinds.get(inst), r.lab.signals.get(inst))
    except KeyError:
        return ""


HANDLERS = {
    "comment": comment, "prompt": prompt, "power": power, "configure": configure, "wait": wait, "record": record, "bit": bit,
    "set_temperature": set_temperature, "pump_down": pump_down, "vent": vent, "wait_until_stable": wait_until_stable,
    "table_rate": table_rate, "table_move": table_move, "table_tilt": table_tilt, "table_stop": table_stop,
    "bench_rate": bench_rate, "mount": mount, "vibrate": vibrate, "check": check,
}
"""Step type -> handler. Every action type of the schema has one (tests check it)."""
