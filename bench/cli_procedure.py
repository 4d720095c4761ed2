"""``bench validate`` and ``bench plan``, and the procedure loading ``bench run`` shares with them.

A procedure is validated against a lab config when one is given (instrument names, drivers,
limits of this lab), else against the standard instrument names of ``configs/sim.yaml``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from rich.console import Console
from rich.table import Table

from bench.errors import EXIT_OK, InputError
from bench.validate import load_checked


def parse_params(items: list[str] | None) -> dict[str, str]:
    """``-p NAME=VALUE`` options -> {NAME: VALUE}; a malformed one is an input error."""
    out: dict[str, str] = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise InputError(f"expected NAME=VALUE such as cold=-20degC, got {item!r}", None, "-p")
        out[name.strip()] = value.strip()
    return out


def fmt_duration(seconds: float) -> str:
    seconds = max(0.0, seconds)
    h, rem = divmod(int(round(seconds)), 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}"


def cmd_validate(args: argparse.Namespace, console: Console) -> int:
    procedure, config = load_checked(args.procedure, args.config, parse_params(args.param))
    against = f"config {args.config}" if config is not None else "the standard instrument names (no --config)"
    print(f"{procedure.path}: valid ({len(procedure.steps)} steps after expansion, about "
          f"{fmt_duration(procedure.estimated_duration_s())} of procedure time; checked against {against})")
    return EXIT_OK


def describe_params(step) -> str:
    """The step's fields in their units, compactly."""
    units = {"duration": "s", "settle": "s", "hold": "s", "timeout": "s", "set_point": "degC", "ramp": "degC/min",
             "band": "", "rate": "deg/s", "accel": "deg/s^2", "angle": "deg", "pressure": "Torr", "odr": "Hz"}
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
    return ", ".join(parts)


def cmd_plan(args: argparse.Namespace, console: Console) -> int:
    procedure, _ = load_checked(args.procedure, args.config, parse_params(args.param))
    table = Table(title=f"{procedure.title}: {len(procedure.steps)} steps")
    for col in ("#", "path", "step", "instrument", "what", "est.", "at"):
        table.add_column(col, overflow="fold")
    t = 0.0
    for s in procedure.steps:
        d = s.estimated_duration_s()
        table.add_row(str(s.index + 1), s.path, f"{s.type}" + (f" ({s.name})" if s.name != s.type else ""),
                      str(s.params.get("instrument", "")), describe_params(s) + (f" [{s.context}]" if s.context else ""),
                      fmt_duration(d) if d else "", fmt_duration(t))
        t += d
    console.print(table)
    waits = sum(1 for s in procedure.steps if s.type in ("wait_until_stable", "pump_down", "vent") or (s.type == "set_temperature" and s.params.get("wait")))
    console.print(f"estimated procedure time {fmt_duration(t)}" + (f" (+ {waits} conditional waits, counted at their minimum)" if waits else ""))
    return EXIT_OK
