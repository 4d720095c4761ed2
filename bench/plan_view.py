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
    """A duration (s) as ``h:mm:ss`` (:func:`bench.quantity_format.fmt_hms`; never negative)."""
    from bench.quantity_format import fmt_hms

    return fmt_hms(max(0.0, seconds))


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


DURATION_FIELDS = ("duration", "settle", "hold", "timeout", "dwell")
"""Step fields that are durations, shown in s (the estimate columns give h:mm:ss)."""


def field_units(step_type: str, field: str) -> str:
    """Units of a numeric step field as shown, from the step's declaration (its kind's, for a kind's
    step: ``set_point`` degC, ``ramp`` degC/min, ``accel`` deg/s², a supply's ``voltage`` V);
    ``""`` where it declares none (a band or a check limit takes its signal's units)."""
    from bench.procedure.schema import step_types
    from bench.quantity_format import unit_text

    spec = step_types().get(step_type)
    f = spec.fields.get(field) if spec else None
    return unit_text(f.units if f else "")


def _shows_timeout(step) -> bool:
    """A step's ``timeout`` is shown where the step waits for the lab (:data:`bench.kinds.WAIT_TIMEOUT`)
    and, for a step that may not wait (``wait: no``), only when it does."""
    from bench.kinds import WAIT_TIMEOUT
    from bench.procedure.schema import step_types

    spec = step_types().get(step.type)
    return bool(spec) and spec.fields.get("timeout") is WAIT_TIMEOUT and ("wait" not in spec.fields or bool(step.params.get("wait")))


def describe_parts(step, kinds: dict[str, str] | None = None) -> list[str]:
    """The step's fields, each as ``name value unit`` (:mod:`bench.quantity_format`): durations in
    s, temperatures in degC, rates in deg/s, angles in deg, pressures in Torr, data rates in
    Hz; a band in its signal's units; a check's limits in the check's display units (a
    scale-factor error limit of 0.05 reads ``-5 .. 5 %``). ``kinds``: instrument -> driver (for
    the units of signals; default the standard instrument names)."""
    from bench.procedure.signals import default_kinds, parse_signal, signal_units
    from bench.quantity_format import fmt_quantity, fmt_range
    from bench.record.checks import display_value

    def units_of(signal: str) -> str:
        try:
            return signal_units(signal, (kinds or default_kinds()).get(parse_signal(signal)[0]))
        except KeyError:
            return ""

    p = step.params
    signal_u = units_of(str(p["signal"])) if p.get("signal") else ""
    parts = []
    if step.type == "check":
        stat = str(p.get("statistic", ""))
        shown = lambda v: display_value(stat, v, signal_u)  # noqa: E731
        for k in ("signal", "statistic", "window"):
            if p.get(k):
                parts.append(f"{k} {p[k]}")
        if p.get("min") is not None or p.get("max") is not None:
            lo, u = shown(p.get("min"))
            parts.append(f"limits {fmt_range(lo, shown(p.get('max'))[0], u)}")
        if p.get("reference"):
            parts.append(f"reference {p['reference']}")
        if p.get("max_difference") is not None:
            d, u = shown(p["max_difference"])
            parts.append(f"max difference {fmt_quantity(d, u)}")
        return parts
    for k, v in p.items():
        if k in ("instrument", "name") or v in ("", None) or (k == "timeout" and not _shows_timeout(step)):
            continue
        if isinstance(v, bool):
            parts.append(f"{k} {'yes' if v else 'no'}")
        elif isinstance(v, (int, float)) and k in DURATION_FIELDS:
            parts.append(f"{k} {fmt_quantity(v, 's', 6)}")
        elif isinstance(v, (int, float)) and k == "band":
            parts.append(f"{k} {fmt_quantity(v, field_units(step.type, k) or signal_u)}")
        elif isinstance(v, float) or (isinstance(v, int) and field_units(step.type, k)):
            parts.append(f"{k} {fmt_quantity(v, field_units(step.type, k))}")
        else:
            parts.append(f"{k} {v}")
    return parts


PLAN_HEADERS = ["#", "path", "step: instrument, parameters", "est. (h:mm:ss)", "at (h:mm:ss)"]
"""Columns of ``bench plan``: step number, path in the YAML, what the step does, its estimated
duration and the procedure time at which it starts."""


def render_plan(procedure: Any, config: Any, console: "Console") -> None:
    """Print the plan of ``procedure`` (checked against ``config``, or None) on ``console``: tables
    as wide as the console, then the total."""
    from bench.termtable import fit_tables, longest_word, pack, table_overhead

    est = procedure.estimate(lab_model(config))
    starts, t = est.starts_s(), est.total_s
    fixed = [len(str(len(procedure.steps))), max([len(PLAN_HEADERS[1])] + [len(s.path) for s in procedure.steps]),
             max(longest_word(PLAN_HEADERS[3]), len(fmt_duration(t)) + 2 * est.lower_bound), max(longest_word(PLAN_HEADERS[4]), len(fmt_duration(t)))]
    room = console.width - table_overhead(len(PLAN_HEADERS)) - sum(fixed)  # what the step column has at most
    rows = []
    for s, at, e in zip(procedure.steps, starts, est.steps):
        instrument = s.params.get("instrument", "")
        parts = ([f"instrument {instrument}"] if instrument else []) + describe_parts(s, config.kinds() if config else None) + (
            [f"[{s.context}]"] if s.context else [])
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
