"""``bench validate`` and ``bench plan``, and the procedure loading ``bench run`` shares with them.

A procedure is validated against a lab config when one is given (instrument names, drivers,
limits of this lab), else against the standard instrument names of ``configs/sim.yaml``.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from bench.errors import EXIT_OK, InputError
from bench.plan_view import fmt_duration, render_plan
from bench.validate import lab_model, load_checked

if TYPE_CHECKING:
    from rich.console import Console


def parse_params(items: list[str] | None) -> dict[str, str]:
    """``-p NAME=VALUE`` options -> {NAME: VALUE}; a malformed one is an input error."""
    out: dict[str, str] = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep or not name.strip():
            raise InputError(f"expected NAME=VALUE such as cold=-20degC, got {item!r}", None, "-p")
        out[name.strip()] = value.strip()
    return out


def cmd_validate(args: argparse.Namespace, console: Console) -> int:
    procedure, config = load_checked(args.procedure, args.config, parse_params(args.param))
    against = f"config {args.config}" if config is not None else "the standard instrument names (no --config)"
    est = procedure.estimate(lab_model(config))
    print(f"{procedure.path}: valid ({len(procedure.steps)} steps after expansion, "
          f"{'at least' if est.lower_bound else 'about'} {fmt_duration(est.total_s)} of procedure time; checked against {against})")
    return EXIT_OK


def cmd_plan(args: argparse.Namespace, console: Console) -> int:
    procedure, config = load_checked(args.procedure, args.config, parse_params(args.param))
    render_plan(procedure, config, console)
    return EXIT_OK
