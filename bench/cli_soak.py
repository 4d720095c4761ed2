"""``bench soak``: command-line front of :mod:`bench.soak`."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from typing import TYPE_CHECKING

from bench.cli_common import quantity
from bench.errors import EXIT_FAILED, EXIT_OK, InputError

if TYPE_CHECKING:
    from rich.console import Console


def soak_duration_h(args: argparse.Namespace) -> float:
    """The soak's run time in hours from ``--duration`` (a quantity; a bare number is hours) or
    ``--hours`` (hours; a quantity is converted): :class:`InputError` naming the option if it is
    not a positive duration."""
    option, value = ("--duration", args.duration) if args.duration is not None else ("--hours", args.hours)
    hours = quantity(value, "h", option)
    if hours <= 0:
        raise InputError(f"expected a positive duration such as 2h or 90min, got {value!r}", None, option)
    return hours


def faults_per_hour(value: str) -> float:
    """``--faults-per-hour``: mean faults per hour of run time (a bare number, or a rate such as
    ``0.1/min``); :class:`InputError` if it is not a rate >= 0."""
    rate = quantity(value, "1/h", "--faults-per-hour")
    if rate < 0:
        raise InputError(f"expected a rate >= 0 such as 3 or 0.1/min, got {value!r}", None, "--faults-per-hour")
    return rate


def cmd_soak(args: argparse.Namespace, console: Console) -> int:
    """Soak the simulated lab; exit 0 when nothing crashed, no file is unreadable, no row was lost
    and every abort is explained, else 1."""
    from bench.config import load_config
    from bench.faults import parse_fault_spec
    from bench.soak import soak

    hours, rate = soak_duration_h(args), faults_per_hour(args.faults_per_hour)
    config = load_config(args.config)
    if config.mode != "sim" and not all(i.sim is not None for i in config.instruments.values()):
        raise InputError("bench soak needs a simulated lab (every instrument with a 'sim' section)", None, "--config")
    root = Path(args.config).resolve().parent.parent
    procedures = args.procedures or sorted((root / "procedures").glob("*.yaml"))
    answers = args.answers or (root / "procedures" / "answers" / "ci.yaml")
    if not Path(answers).exists():
        raise InputError("answers file not found (give --answers FILE)", None, "--answers")
    classes = parse_fault_spec(f"classes={args.classes}").classes if args.classes else None

    def on_run(entry: dict) -> None:
        if not args.json:
            faults = ", ".join(f"{f['class']}@{f['t_s']:.0f}s" for f in entry["faults"]) or "no faults"
            extra = f": {entry['abort_reason']}" if entry.get("status") != "completed" else ""
            console.print(f"{entry['procedure']:36s} {entry.get('status', '?'):9s} {entry.get('run_time_s', 0) / 3600:6.2f} h  "
                          f"[{faults}]{extra}", markup=False, soft_wrap=True)

    report = soak(Path(args.config), hours, rate, args.seed, args.runs_dir,
                  procedures=[Path(p) for p in procedures], answers=Path(answers), classes=classes, on_run=on_run)
    if args.json:
        print(json.dumps(report.to_json(), indent=2))
    else:
        console.print(report.markdown_table(), markup=False)
        console.print(f"runs {report.runs}, run time {report.run_time_s / 3600:.2f} h in {report.wall_time_s:.0f} s wall; "
                      f"aborts {report.aborts} ({report.aborts_explained} explained); crashes {report.crashes}; "
                      f"unreadable files {report.unreadable_files}; data lost {report.data_lost_rows} rows", markup=False)
        for p in report.problems:
            console.print(f"problem: {p}", markup=False, soft_wrap=True)
    ok = not report.crashes and not report.unreadable_files and not report.data_lost_rows and report.aborts == report.aborts_explained
    return EXIT_OK if ok else EXIT_FAILED
