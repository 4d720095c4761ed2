"""``bench unit SERIAL``: a unit's history on one screen (:mod:`bench.unit_history`), and its
acceptance data package as one self-contained HTML file (``--html -o FILE``;
:mod:`bench.report.unit_package`). See ``docs/units-under-test.md``.

Light at import (argparse only): the catalogue, h5py and rich are imported when the command runs.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bench.cli_common import add_force, epilog
from bench.errors import EXIT_OK, InputError

if TYPE_CHECKING:  # pragma: no cover
    from rich.console import Console

SPARK = "▁▂▃▄▅▆▇█"


def add_unit_parser(sub: Any) -> None:
    """Register ``unit`` on the ``bench`` subcommand parsers ``sub``."""
    u = sub.add_parser(
        "unit", help="a unit's history: every run, its key figures across runs and against the other units of its part number",
        description="Every catalogued run of one unit (procedure, date, station, mode, verdict, first failed check), and its "
                    "key figures (bias, scale-factor error, noise per sensor axis, from the checks its runs recorded) across "
                    "runs and against the other units of the same part number: is this unit an outlier of its lot? Dry-runs "
                    "are listed and marked, never counted as evidence. --html writes the acceptance data package.",
        epilog=epilog("bench unit SN12", "bench unit SN12 --runs-dir /data/runs --json",
                      "bench unit SN12 --html -o SN12_acceptance.html",
                      ok="the history was printed (or the package written)", failed="the catalogue could not be read",
                      bad="no run of that unit, no catalogue, a bad option, or the output exists (without --force)"))
    u.add_argument("serial", metavar="SERIAL", help="serial number of the unit (as bench run --unit recorded it)")
    u.add_argument("--part", metavar="PN", default=None,
                   help="part number whose units form the lot (default: the one the unit's runs recorded)")
    u.add_argument("--runs-dir", type=Path, default=Path("runs"), metavar="DIR", help="directory of the runs and their catalog.sqlite (default: runs/)")
    u.add_argument("--catalog", metavar="URL", default=None, help="catalogue URL or file (default: RUNS_DIR/catalog.sqlite)")
    u.add_argument("--json", action="store_true", help="print the history as one JSON object (fields: docs/units-under-test.md)")
    u.add_argument("--html", action="store_true", help="write the acceptance data package (one self-contained HTML file) to -o")
    u.add_argument("-o", "--output", type=Path, default=None, help="with --html: the file to write (default: SERIAL_history.html)")
    add_force(u)


def cmd_unit(args: argparse.Namespace, console: "Console") -> int:
    from bench.cli_common import check_output
    from bench.unit_history import history_json, unit_history

    if args.output is not None and not args.html:
        raise InputError("-o is the file of --html; add --html", None, "-o")
    out = None
    if args.html:
        out = args.output or Path(f"{args.serial}_history.html")
        check_output(out, "-o", force=args.force)
    h = unit_history(args.serial, runs_dir=args.runs_dir, catalog=args.catalog, part=args.part,
                     field="--catalog" if args.catalog else "--runs-dir")
    if args.json:
        print(json.dumps(history_json(h), indent=2))
        return EXIT_OK
    if out is not None:
        from bench.outputs import output_file
        from bench.report.unit_package import build_package

        with output_file(out, "-o", force=args.force) as tmp:
            tmp.write_text(build_package(h), encoding="utf-8")
        console.print(f"wrote {out}: {len(h.runs)} run(s) of {h.serial}, {len(h.figures)} key figure(s)", markup=False, highlight=False)
        return EXIT_OK
    from bench.terminal_text import printable_data

    render_history(printable_data(h), console)  # texts of the catalogue and run files are data: escapes shown, never acted on
    return EXIT_OK


def sparkline(values: list[float]) -> str:
    """One character per value, scaled between their extremes."""
    finite = [v for v in values if v == v]
    if not finite:
        return ""
    lo, hi = min(finite), max(finite)
    top = len(SPARK) - 1
    return "".join(SPARK[top // 2 + 1 if hi == lo else round((v - lo) / (hi - lo) * top)] for v in values)


def render_history(h: Any, console: "Console") -> None:
    """The history at the console's width (80 columns fit): who and what, the runs, the figures."""
    from rich.text import Text

    from bench.quantity_format import fmt_quantity, fmt_range
    from bench.run_mode import is_evidence, mode_word, verdict_text
    from bench.termtable import fit_tables

    head = Text(f"Unit {h.serial}", style="bold")
    head.append(f", part {h.part or '-'}")
    head.append(f"; its lot: {len(h.lot_units)} other unit(s) of {h.part}" if h.part else "")
    console.print(head)
    if h.dry_runs:
        console.print(Text(f" {h.dry_runs} of {len(h.runs)} run(s) are DRY-RUNs or replays: listed, never acceptance evidence ",
                           style="bold black on yellow"))
    colours = {"passed": "green", "failed": "red", "incomplete": "yellow"}
    rows = []
    for i, r in enumerate(h.runs, 1):
        evidence = is_evidence(r.mode)
        verdict = Text(verdict_text(r.verdict, r.mode) if r.verdict else r.status,
                       style=colours.get(r.verdict or "", "") if evidence else "")
        if r.first_failed_check:
            verdict.append(f"\nfirst failed: {r.first_failed_check}", style="red")
        what = Text(r.procedure)
        what.append(f"\n{r.station or '-'}", style="dim")
        rows.append([str(i), r.started_utc.strftime("%Y-%m-%d %H:%M") if r.started_utc else "-", what,
                     Text(mode_word(r.mode), style="" if evidence else "bold black on yellow"), verdict])
    for t in fit_tables(["#", "start UTC", "procedure, station", "mode", "verdict"], rows, console.width,
                        title=f"Runs of {h.serial}", prose=(2, 4)):
        console.print(t)
    if not h.figures:
        console.print("no key figures: none of its runs recorded a check of bias, scale-factor error or noise on a sensor axis",
                      markup=False, highlight=False)
    else:
        rows = []
        for f in h.figures:
            values = [p.value for p in f.points]
            name = Text(f.name)
            name.append(f"\n{sparkline(values)} " + "".join("●" if p.evidence else "○" for p in f.points), style="cyan")
            latest = fmt_quantity(f.latest.value, f.units) + ("\n(dry-run)" if not f.latest.evidence else "") if f.latest else "-"
            spread = f"\nrange {fmt_range(min(values), max(values), f.units)}" if len(values) > 1 and min(values) != max(values) else ""
            lot = (fmt_quantity(f.lot_median, f.units) if f.lot_median is not None else "-") + f"\n{len(f.lot)} unit(s)"
            z = "" if f.z is None else (f" (z {f.z:+.1f})" if f.z == f.z and abs(f.z) != float("inf") else " (z inf)")
            rows.append([name, Text(latest + spread), lot, Text(f.verdict + z, style="bold red" if f.outlier else "")])
        for t in fit_tables(["figure (● real run, ○ dry-run)", "latest", "lot median", "against its lot"], rows, console.width,
                            title=f"Key figures of {h.serial}", prose=(0, 1, 3)):
            console.print(t)
    for note in h.notes:
        console.print(f"note: {note}", markup=False, highlight=False, style="yellow")
