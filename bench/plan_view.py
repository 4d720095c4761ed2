"""``bench plan``'s view of a procedure: its expanded steps with their parameters in units, the
estimated duration of each and the procedure time it starts at, and the total.

Shared by ``bench plan`` and the web station's plan (which renders it into text in its own process,
instead of a ``bench plan`` process per request). Widths in terminal cells, times in s.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from bench.validate import lab_model

if TYPE_CHECKING:
    from rich.console import Console

    from bench.procedure.estimate import Estimate, StepEstimate


def fmt_duration(seconds: float) -> str:
    seconds = max(0.0, seconds)
    h, rem = divmod(int(round(seconds)), 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}"


def fmt_estimate(e: "StepEstimate") -> str:
    """A step's estimated duration, ``h:mm:ss``, ``≥ h:mm:ss`` for a lower bound, ``""`` for none."""
    if not e.duration_s and not e.lower_bound:
        return ""
    return ("≥ " if e.lower_bound else "") + fmt_duration(e.duration_s)


def plan_total(est: "Estimate") -> str:
    """The last line of ``bench plan``: the total, marked as a lower bound where a wait has no model."""
    prompts = f"; {est.prompts} operator prompt{'s' if est.prompts != 1 else ''} not counted" if est.prompts else ""
    if est.lower_bound:
        unmodelled = sum(s.lower_bound for s in est.steps)
        return (f"estimated procedure time ≥ {fmt_duration(est.total_s)} (a lower bound: {unmodelled} wait"
                f"{'s' if unmodelled != 1 else ''} marked ≥ have no model and count what they take at least{prompts})")
    return f"estimated procedure time {fmt_duration(est.total_s)} (chamber and table waits from the lab model{prompts})"


def describe_parts(step) -> list[str]:
    """The step's fields, each as ``name value unit`` (durations in s, temperatures in degC, rates in
    deg/s, angles in deg, pressures in Torr, data rates in Hz)."""
    units = {"duration": "s", "settle": "s", "hold": "s", "timeout": "s", "set_point": "degC", "ramp": "degC/min",
             "band": "", "rate": "deg/s", "accel": "deg/s^2", "angle": "deg", "pressure": "Torr", "odr": "Hz"}
    if step.type == "set_temperature":
        units["band"] = "degC"
    parts = []
    for k, v in step.params.items():
        if k in ("instrument", "name") or v in ("", None) or (k == "timeout" and step.type not in ("set_temperature", "pump_down", "vent", "wait_until_stable")):
            continue
        if k == "timeout" and step.type == "set_temperature" and not step.params.get("wait"):
            continue
        if isinstance(v, float):
            parts.append(f"{k} {v:g}{(' ' + units[k]) if units.get(k) else ''}")
        else:
            parts.append(f"{k} {v}")
    return parts


def describe_params(step) -> str:
    """The step's fields in their units, compactly (:func:`describe_parts` joined)."""
    return ", ".join(describe_parts(step))


PLAN_HEADERS = ["#", "path", "step: instrument, parameters", "est. (h:mm:ss)", "at (h:mm:ss)"]
"""Columns of ``bench plan``: step number, path in the YAML, what the step does, its estimated
duration and the procedure time at which it starts."""


def render_plan(procedure: Any, config: Any, console: "Console") -> None:
    """Print the plan of ``procedure`` (checked against ``config``, or None) on ``console``: tables
    as wide as the console, then the total."""
    from bench.termtable import fit_tables, longest_word, pack, table_overhead

    est = procedure.estimate(lab_model(config))
    starts, t = est.starts_s(), est.total_s
    fixed = [len(str(len(procedure.steps))), max((len(s.path) for s in procedure.steps), default=4),
             max(longest_word(PLAN_HEADERS[3]), len(fmt_duration(t)) + 2 * est.lower_bound), max(longest_word(PLAN_HEADERS[4]), len(fmt_duration(t)))]
    room = console.width - table_overhead(len(PLAN_HEADERS)) - sum(fixed)  # what the step column has at most
    rows = []
    for s, at, e in zip(procedure.steps, starts, est.steps):
        instrument = s.params.get("instrument", "")
        parts = ([f"instrument {instrument}"] if instrument else []) + describe_parts(s) + ([f"[{s.context}]"] if s.context else [])
        head = f"{s.type}" + (f" ({s.name})" if s.name != s.type else "")
        rows.append([str(s.index + 1), s.path, head + ("\n" + pack(parts, room) if parts else ""), fmt_estimate(e),
                     fmt_duration(at)])
    for table in fit_tables(PLAN_HEADERS, rows, console.width, title=f"{procedure.title}: {len(procedure.steps)} steps", prose=[2]):
        console.print(table)
    console.print(plan_total(est))


def plan_text(procedure: Any, config: Any, width: int) -> str:
    """:func:`render_plan` as plain text ``width`` cells wide (no colours), as ``bench plan`` prints
    it on a terminal that wide."""
    import io

    from rich.console import Console

    buf = io.StringIO()
    render_plan(procedure, config, Console(file=buf, width=width, color_system=None, highlight=False, force_terminal=False,
                                           no_color=True))
    return buf.getvalue()
