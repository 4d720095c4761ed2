"""``bench runs`` (query the catalogue of runs) and ``bench catalog rebuild`` (rebuild it from the files).

Light at import (argparse only): the catalogue, SQLAlchemy and rich are imported when a command runs.
See ``docs/catalog.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bench.cli_common import Parser, epilog
from bench.errors import EXIT_FAILED, EXIT_OK
from bench.terminal_text import printable

if TYPE_CHECKING:
    from rich.console import Console

UNIT_WIDTH = 10
"""Width of the unit column at most (cells); a longer serial continues on the next line."""
MIN_PROCEDURE_WIDTH = 12
"""The procedure column never gets narrower than this (characters)."""
PROGRESS_LINE_S = 5.0
"""Seconds of wall time between progress lines of a rebuild when stderr is not a terminal."""
CATALOG_HELP = "catalogue URL: postgresql://USER@HOST[:PORT]/DB, sqlite:///PATH or a file path"
"""Help of the --catalog options."""


def add_catalog_parsers(sub: Any) -> None:
    """Register ``runs`` and ``catalog`` on the ``bench`` subcommand parsers ``sub``."""
    catalog_help = CATALOG_HELP
    r = sub.add_parser(
        "runs", help="list the catalogued runs (unit, procedure, status, verdict, environment), filtered",
        description="One row per run file from the catalogue (default RUNS_DIR/catalog.sqlite). Text filters match "
                    "exactly; '*' matches any characters.",
        epilog=epilog("bench runs --unit 12 --vacuum-below 1e-4Torr", "bench runs --procedure 'thermal_*' --verdict failed --since 7d",
                      "bench runs --mode real --verdict passed      # acceptance evidence only: no dry-runs",
                      "bench runs --unit 12 --json", "bench runs --catalog postgresql://bench@labdb/bench --station tvac-1",
                      ok="the rows were listed (none may match)", failed="the catalogue could not be read (server unreachable, "
                      "locked beyond its timeout, a newer schema)", bad="a bad filter value (--since: ...), no catalogue"))
    add_run_filters(r)
    r.add_argument("--json", action="store_true", help="print a JSON list of rows (every column) instead of a table")

    c = sub.add_parser("catalog", help="the catalogue of runs: rebuild it from the run files",
                       description="The catalogue of runs (docs/catalog.md); 'bench runs' queries it.",
                       epilog=epilog("bench catalog rebuild runs", ok="see 'bench catalog rebuild --help'",
                                     failed="see 'bench catalog rebuild --help'"))
    csub = c.add_subparsers(dest="catalog_command", metavar="ACTION", parser_class=Parser, required=True)
    rb = csub.add_parser(
        "rebuild", help="catalogue every run file of a directory (idempotent upsert keyed by file path)",
        description="Read every *.h5 run file of DIR and upsert its row; unreadable files are reported and the rest catalogued.",
        epilog=epilog("bench catalog rebuild runs", "bench catalog rebuild /data/runs --catalog postgresql://bench@labdb/bench --recursive",
                      ok="every file catalogued", failed="some files were unreadable (listed on stderr), the others catalogued; "
                      "or the catalogue could not be written", bad="DIR is not a directory, a bad --catalog URL"))
    rb.add_argument("dir", type=Path, metavar="DIR", help="directory of run files")
    rb.add_argument("--catalog", metavar="URL", default=None, help=f"{catalog_help} (default: DIR/catalog.sqlite)")
    rb.add_argument("--recursive", action="store_true", help="also the run files in DIR's subdirectories")


def add_run_filters(r: Any) -> None:
    """The filters of ``bench runs`` and where its catalogue is, added to the parser (or argument
    group) ``r``; ``bench fleet --query`` takes the same (:func:`query_runs`)."""
    r.add_argument("--unit", metavar="SN", help="serial number of the unit under test")
    r.add_argument("--part", metavar="PN", help="part number of the unit under test")
    r.add_argument("--procedure", metavar="NAME", help="procedure name")
    r.add_argument("--status", metavar="S", help="running | completed | aborted | failed | crashed")
    r.add_argument("--verdict", metavar="V", help="passed | failed | no-verdict | incomplete")
    r.add_argument("--mode", metavar="M", help="real (hardware) | dry-run (sim) | replay | imported: a dry-run is never acceptance evidence")
    r.add_argument("--station", metavar="NAME", help="test station")
    r.add_argument("--since", metavar="DATE|DURATION", help="runs started at or after a UTC date/time (2026-11-23, 2026-11-23T08:00Z) or within a duration (7d, 12 h)")
    r.add_argument("--vacuum-below", metavar="PRESSURE", help="runs whose lowest monitored pressure was at or below this (1e-4 Torr; a bare number is Torr)")
    r.add_argument("--limit", type=int, metavar="N", default=None, help="only the latest N runs")
    r.add_argument("--runs-dir", type=Path, default=Path("runs"), metavar="DIR", help="directory of the runs and their catalog.sqlite (default: runs/)")
    r.add_argument("--catalog", metavar="URL", default=None, help=f"{CATALOG_HELP} (default: RUNS_DIR/catalog.sqlite)")


def cmd_catalog(args: argparse.Namespace, console: "Console") -> int:
    """``bench runs`` or ``bench catalog ACTION``."""
    if args.command == "runs":
        return cmd_runs(args, console)
    return cmd_rebuild(args, console)


# ---- bench runs ---------------------------------------------------------------------------------
def cmd_runs(args: argparse.Namespace, console: "Console") -> int:
    rows = query_runs(args)
    if args.json:
        print(json.dumps([{k: _json_value(v) for k, v in r.items()} for r in rows], indent=2))
        return EXIT_OK
    from bench.terminal_text import printable_data

    render_runs(printable_data(rows), console)  # texts of the run files are data: escapes shown, never acted on
    return EXIT_OK


def query_runs(args: argparse.Namespace) -> list[dict[str, Any]]:
    """The catalogue rows of the filters of :func:`add_run_filters` in ``args``, oldest start first."""
    from bench.catalog import query as q
    from bench.catalog.store import open_catalog, resolve_url

    f = q.RunFilter(  # every value is checked before the catalogue is opened
        unit=q.parse_text(args.unit, "--unit"), part=q.parse_text(args.part, "--part"),
        procedure=q.parse_text(args.procedure, "--procedure"), station=q.parse_text(args.station, "--station"),
        status=q.parse_status(args.status), verdict=q.parse_verdict(args.verdict), mode=q.parse_mode(getattr(args, "mode", None)),
        since=q.parse_since(args.since),
        vacuum_below_torr=q.parse_pressure(args.vacuum_below), limit=q.parse_limit(args.limit),
    )
    url = resolve_url(args.catalog, args.runs_dir)
    with open_catalog(url, create=False, field="--catalog" if args.catalog else "--runs-dir") as cat:
        return q.find_runs(cat, f)


def _json_value(v: Any) -> Any:
    return _utc(v) if isinstance(v, datetime) else v


def _utc(t: datetime | None, fmt: str = "%Y-%m-%dT%H:%M:%SZ") -> str:
    return t.strftime(fmt) if t is not None else ""


def render_runs(rows: list[dict[str, Any]], console: "Console") -> None:
    """The rows as a table as wide as the terminal allows (80 columns fit; units in the headers):
    every column at its content's width, the mode of each run (``real``, ``DRY-RUN``, ``REPLAY``:
    :mod:`bench.run_mode`) beside its verdict, numbers through :mod:`bench.quantity_format`
    (``760``, ``1.2e-05``, never ``7.6e+02``). The environment columns (lowest pressure, temperature
    range) are left out when no row has them, and move to the note lines when the procedure names
    would not fit beside them; a procedure name (or unit serial) longer than the room left continues
    on the next line, whole (never cut to "…", as ``bench/termtable.py``). Then one note line per
    failed check or reason, referring to the row by its number, and the count of runs per mode and
    verdict (a dry-run's pass is never counted with real ones)."""
    from rich.table import Table
    from rich.text import Text

    from bench.quantity_format import fmt_number, fmt_quantity, fmt_range
    from bench.run_mode import is_evidence, mode_word

    if not rows:
        console.print("no catalogued run matches")
        return
    colours = {"passed": "green", "failed": "red", "incomplete": "yellow", "crashed": "red", "aborted": "red"}
    base = ["#", "start UTC", "unit", "procedure", "mode", "status", "verdict"]
    env_heads = ["p min\nTorr", "T degC\nmin..max"]
    cells: list[list[str]] = []
    env: list[list[str]] = []
    notes: dict[int, list[str]] = {}
    for i, r in enumerate(rows, 1):
        p, lo, hi = r["min_pressure_torr"], r["temp_min_degc"], r["temp_max_degc"]
        cells.append([str(i), _utc(r["started_utc"], "%Y-%m-%d %H:%M"), r["unit_serial"] or "-", r["procedure_name"],
                      mode_word(r.get("mode")), r["status"], r["verdict"] or "-"])
        env.append([fmt_number(p, 2) if p is not None else "-",
                    f"{fmt_number(lo, 3)}..{fmt_number(hi, 3)}" if lo is not None and hi is not None else "-"])
        if r["first_failed_check"]:
            notes.setdefault(i, []).append(f"first failed: {r['first_failed_check']}")
        if r["reason"]:
            notes.setdefault(i, []).append(f"{r['status']}: {r['reason']}")
    has_env = any(e != ["-", "-"] for e in env)

    def widths_for(headers: list[str], table: list[list[str]]) -> list[int]:
        w = [max(max(len(h) for h in head.split("\n")), *(len(c[k]) for c in table)) for k, head in enumerate(headers)]
        w[2] = min(w[2], UNIT_WIDTH)
        return w

    headers = base + (env_heads if has_env else [])
    table = [c + e for c, e in zip(cells, env)] if has_env else cells
    widths = widths_for(headers, table)
    room = console.width - (sum(widths) - widths[3]) - (len(headers) - 1)  # one space between columns
    longest = max(len(c[3]) for c in cells)
    if has_env and room < longest:  # the names first: the environment goes to the notes
        for i, (e, r) in enumerate(zip(env, rows), 1):
            if e != ["-", "-"]:
                parts = []
                if r["min_pressure_torr"] is not None:
                    parts.append(f"p min {fmt_quantity(r['min_pressure_torr'], 'Torr', 2)}")
                if r["temp_min_degc"] is not None and r["temp_max_degc"] is not None:
                    parts.append(f"T {fmt_range(r['temp_min_degc'], r['temp_max_degc'], 'degC', 3)}")
                notes.setdefault(i, []).insert(0, ", ".join(parts))
        headers, table = base, cells
        widths = widths_for(headers, table)
        room = console.width - (sum(widths) - widths[3]) - (len(headers) - 1)
    widths[3] = max(min(widths[3], room), MIN_PROCEDURE_WIDTH)
    t = Table(box=None, padding=(0, 1, 0, 0), pad_edge=False, header_style="bold")
    for k, head in enumerate(headers):
        folds = k in (2, 3)  # unit, procedure
        t.add_column(head, justify="right" if k == 0 or k >= len(base) else "left", no_wrap=not folds, overflow="fold", width=widths[k])
    for c, r in zip(table, rows):
        evidence = is_evidence(r.get("mode"))
        mode = Text(c[4], style="bold green" if evidence else "bold black on yellow")
        verdict = Text(c[6], style=colours.get(c[6], "") if evidence else "")  # a dry-run's pass is not green
        t.add_row(*c[:4], mode, Text(c[5], style=colours.get(c[5], "")), verdict, *c[7:])
    console.print(t)
    for i, lines in notes.items():
        for n in lines:
            console.print(Text(f"{i:>3} {n}"), soft_wrap=False)
    for line in runs_summary(rows):
        console.print(line, markup=False, highlight=False)


def runs_summary(rows: list[dict[str, Any]]) -> list[str]:
    """The catalogue's verdict summary of ``rows``, counted per mode so a simulated pass never adds
    to the real ones: ``5 run(s)``, then one line per mode (``  real     2: 1 passed, 1 failed``,
    ``  DRY-RUN  3: 3 passed``), and a last line when some are not acceptance evidence."""
    from bench.catalog.row import VERDICTS
    from bench.run_mode import MODES, is_evidence, mode_word

    by_mode: dict[str, dict[str, int]] = {}
    for r in rows:
        counts = by_mode.setdefault(r.get("mode") or "", {})
        v = r["verdict"] or r["status"]
        counts[v] = counts.get(v, 0) + 1
    order = [m for m in MODES if m in by_mode] + sorted(m for m in by_mode if m not in MODES)
    rank = {v: k for k, v in enumerate(VERDICTS)}
    width = max(len(mode_word(m)) for m in order)
    lines = [f"{len(rows)} run(s):"]
    for m in order:
        counts = sorted(by_mode[m].items(), key=lambda x: (rank.get(x[0], 99), x[0]))
        lines.append(f"  {mode_word(m):<{width}} {sum(by_mode[m].values()):>3}: " + ", ".join(f"{n} {v}" for v, n in counts))
    not_evidence = [mode_word(m) for m in order if not is_evidence(m)]
    if not_evidence:
        lines.append(f"{', '.join(not_evidence)}: not acceptance evidence (--mode real lists real runs only)")
    return lines


# ---- bench catalog rebuild ----------------------------------------------------------------------
def cmd_rebuild(args: argparse.Namespace, console: "Console") -> int:
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from bench.catalog.rebuild import rebuild
    from bench.catalog.store import display_url, open_catalog, resolve_url
    from bench.errors import InputError

    if not args.dir.is_dir():
        raise InputError(f"{args.dir}: {'not a directory' if args.dir.exists() else 'no such directory'}", None, "DIR")
    url = resolve_url(args.catalog, args.dir)
    err = Console(stderr=True, highlight=False)
    last = [time.monotonic(), time.monotonic()]  # start, last progress line

    def line_progress(done: int, total: int, _path: Path) -> None:
        now = time.monotonic()
        if now - last[1] >= PROGRESS_LINE_S:
            last[1] = now
            print(f"{done}/{total} files, {done / max(now - last[0], 1e-9):.1f} files/s", file=sys.stderr, flush=True)

    with open_catalog(url) as cat:
        if err.is_terminal:
            with Progress(TextColumn("catalogue"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                          console=err, transient=True) as bar:
                task = bar.add_task("files", total=None)
                report = rebuild(cat, args.dir, recursive=args.recursive,
                                 on_file=lambda done, total, _p: bar.update(task, completed=done, total=total))
        else:
            report = rebuild(cat, args.dir, recursive=args.recursive, on_file=line_progress)
        total_rows = cat.count()
    for path, reason in report.unreadable:
        err.print(printable(reason), markup=False, soft_wrap=True)
    for path, reason in report.skipped:
        err.print(f"bench: warning: {reason}", markup=False, soft_wrap=True)
    console.print(
        f"catalogued {report.catalogued} of {report.files} run file(s) from {args.dir} in {report.wall_s:.2f} s "
        f"({report.files_per_s:.1f} files/s); {len(report.unreadable)} unreadable"
        f"{f', {len(report.skipped)} link(s) out of the directory skipped' if report.skipped else ''}; {display_url(url)} holds {total_rows} run(s)",
        markup=False, highlight=False, soft_wrap=True)
    return EXIT_FAILED if report.unreadable else EXIT_OK


# ---- bench run --------------------------------------------------------------------------------
def run_catalog(option: str | None, config: Any) -> str | None:
    """The catalogue ``bench run`` writes to: ``--catalog``, else the lab config's ``catalog:`` (a
    relative file path is relative to the config file), else None (``RUNS_DIR/catalog.sqlite``).
    A bad value is bad input (exit 2), located in the config when it comes from there."""
    from bench.catalog.store import resolve_url
    from bench.errors import InputError

    if option:
        resolve_url(option, field="--catalog")
        return option
    if not config.catalog:
        return None
    value = config.catalog
    if "://" not in value and not Path(value).expanduser().is_absolute():
        value = str(Path(config.path).parent / value)
    try:
        resolve_url(value, field="catalog")
    except InputError as exc:
        raise InputError(exc.message, config.catalog_location, "catalog") from None
    return value
