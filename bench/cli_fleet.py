"""``bench fleet replay|calibrate METHOD|diagnose|report (DIR | --query FILTERS)``: one command over
many run files on dask.distributed workers (docs/fleet.md).

Thin: the files, the workers and the per-file work are ``bench/fleet``; this module parses the
options, shows progress on stderr, and prints the summary table (or ``--json``). Light at import
(argparse only): dask, rich and the analyses are imported when the command runs.
Exit codes: 0 every file done (every replay matched), 1 a file failed or diverged (the others are
finished), 2 bad input (no such directory, no file matched, a bad option or scheduler address).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bench.cli_common import add_force, epilog, quantity
from bench.errors import EXIT_FAILED, EXIT_OK, InputError

if TYPE_CHECKING:
    from rich.console import Console

    from bench.fleet.fanout import FleetRun
    from bench.fleet.tasks import FileResult

PROGRESS_LINE_S = 5.0
"""Seconds of wall time between progress lines when stderr is not a terminal."""
DEFAULT_OUT = Path("runs") / "fleet"
"""Where a fleet's outputs go unless --out says otherwise."""
_FILTERS = ("unit", "part", "procedure", "status", "verdict", "mode", "station", "since", "vacuum_below", "limit")
"""The ``bench runs`` filters (argparse destinations) that only mean something with --query."""

_WHAT = {
    "replay": ("replay every run file against its recorded answers and compare (as 'bench replay')",
               "the replay's own run file, in OUT/<subdirectory of the file>/", "every replay matched",
               "a replay diverged, or a file could not be replayed (listed; the others were replayed)"),
    "calibrate": ("calibrate from every run file with one method (as 'bench calibrate METHOD FILE --json')",
                  "OUT/<subdirectory>/<file stem>.<METHOD>.json: what 'bench calibrate METHOD FILE --json' prints",
                  "every file calibrated", "a file could not be calibrated (listed; the others were)"),
    "diagnose": ("diagnose every run file (as 'bench diagnose FILE --json')",
                 "OUT/<subdirectory>/<file stem>.diagnose.json: what 'bench diagnose FILE --json' prints",
                 "every file diagnosed (whatever each diagnosis found)", "a file could not be diagnosed (listed; the others were)"),
    "report": ("write the HTML report of every run file (as 'bench report FILE -o ...')",
               "OUT/<subdirectory>/<file stem>.html", "every report written", "a report could not be written (listed; the others were)"),
}


def add_fleet_parser(sub: Any) -> None:
    """Register ``bench fleet`` and its four actions on the ``bench`` subcommand parsers ``sub``."""
    from bench.analysis.per_file import METHODS
    from bench.cli_analysis import _add_map_option
    from bench.cli_common import Parser

    f = sub.add_parser(
        "fleet", help="replay, calibrate, diagnose or report many run files on dask.distributed workers (docs/fleet.md)",
        description="One command over the run files of a directory (and below) or of a catalogue query, fanned out over "
                    "dask.distributed worker processes: an embedded local cluster, or an existing one with --scheduler. "
                    "Each file gets what the serial command gives it (docs/fleet.md).",
        epilog=epilog("bench fleet replay tests/sessions", "bench fleet diagnose runs --workers 4 --json",
                      "bench fleet report --query --unit SN12 --since 30d --out reports/",
                      ok="see 'bench fleet ACTION --help'", failed="see 'bench fleet ACTION --help'"))
    fsub = f.add_subparsers(dest="fleet_command", metavar="ACTION", parser_class=Parser, required=True)
    for command, (help_text, output, ok, failed) in _WHAT.items():
        p = fsub.add_parser(
            command, help=help_text,
            description=f"{help_text[0].upper()}{help_text[1:]}, over the *.h5 files of DIR and its subdirectories "
                        f"(files under --out skipped) or of the catalogue rows a query selects, on dask.distributed worker "
                        f"processes. Output per file: {output}. Progress on stderr; a table (or --json) at the end.",
            epilog=epilog(*_examples(command), ok=ok, failed=failed,
                          bad="bad input: no such DIR, no run file or catalogue row matched, a bad option or scheduler "
                              "address, a scheduler that does not answer, outputs that exist (without --force); nothing run"))
        if command == "calibrate":
            p.add_argument("method", choices=list(METHODS), help="calibration method: " + ", ".join(METHODS))
        p.add_argument("dir", type=Path, nargs="?", metavar="DIR", help="directory of run files (searched recursively); or --query")
        q = p.add_argument_group("catalogue query (with --query; the filters of 'bench runs', docs/catalog.md)")
        q.add_argument("--query", action="store_true", help="the run files of the catalogue rows the filters select, instead of DIR")
        from bench.cli_catalog import add_run_filters

        add_run_filters(q)
        if command in ("calibrate", "diagnose"):
            _add_map_option(p)
        if command == "calibrate":
            p.add_argument("--sensor", choices=["accel", "gyro"], default=None, help="gauss-newton: which sensor (default accel)")
            p.add_argument("--degree", type=int, default=None, help="thermal: polynomial degree (default 3, NPSAT1 Table 4)")
        if command == "diagnose":
            p.add_argument("--model", type=Path, default=None,
                           help="sensor model YAML whose known terms join the baseline (default: the baseline alone)")
        p.add_argument("--out", type=Path, default=DEFAULT_OUT, metavar="OUT",
                       help=f"output directory, made if needed; every output inside it, named after its run file (default: {DEFAULT_OUT}/)")
        add_force(p)
        w = p.add_argument_group("workers")
        w.add_argument("--workers", type=int, default=None, metavar="N",
                       help="worker processes of the embedded cluster (one thread each; default: the number of cores)")
        w.add_argument("--scheduler", metavar="tcp://HOST:PORT", default=None,
                       help="use the existing dask.distributed cluster of this scheduler (its workers must reach the files "
                            "and OUT at the same paths; default: an embedded cluster on 127.0.0.1)")
        w.add_argument("--dashboard", action="store_true", help="embedded cluster: serve dask's dashboard on 127.0.0.1 (a free port, printed)")
        w.add_argument("--timeout", default="60 s", metavar="DURATION",
                       help="longest wait for the embedded cluster to start or the scheduler to answer, a duration (default '60 s')")
        w.add_argument("--file-timeout", default="1 h", metavar="DURATION",
                       help="longest wait for the next file to finish, a duration; the files left are then cancelled (default '1 h')")
        p.add_argument("--json", action="store_true",
                       help="print one JSON object (per file: verdict, exit code, time, output, error, the serial command's "
                            "JSON) instead of the table; progress stays on stderr")


def _examples(command: str) -> list[str]:
    return {
        "replay": ["bench fleet replay tests/sessions", "bench fleet replay runs --workers 8 --out /tmp/replays",
                   "bench fleet replay --query --procedure 'thermal_*' --since 7d --scheduler tcp://10.0.0.5:8786"],
        "calibrate": ["bench fleet calibrate noise runs --out calibrations/", "bench fleet calibrate thermal --query --unit SN12 --json"],
        "diagnose": ["bench fleet diagnose runs --workers 2", "bench fleet diagnose --query --verdict failed --json"],
        "report": ["bench fleet report runs --out reports/", "bench fleet report --query --unit SN12 --out reports/ --force"],
    }[command]


def cmd_fleet(args: argparse.Namespace, console: "Console") -> int:
    """Run the fleet; the exit code of the whole (0 all done, 1 some failed)."""
    from rich.console import Console

    from bench.fleet import cluster, files
    from bench.fleet.fanout import run_fleet

    command = args.fleet_command
    timeout_s = _positive_duration(args.timeout, "--timeout")
    file_timeout_s = _positive_duration(args.file_timeout, "--file-timeout")
    refs = _select_files(args, files)
    cluster.check_options(args.scheduler, args.workers, timeout_s)
    job = _job(args, command)
    _check_out(args, refs, job, files)
    err = Console(stderr=True, highlight=False)
    with cluster.connect(args.scheduler, workers=args.workers, timeout_s=timeout_s, dashboard=args.dashboard) as ws:
        where = f"{ws.workers} worker(s) of {'an embedded cluster' if ws.embedded else 'the scheduler'} at {ws.address}"
        err.print(f"fleet {command}: {len(refs)} file(s) on {where}", markup=False, soft_wrap=True)
        if ws.dashboard:
            err.print(f"dashboard: {ws.dashboard}", markup=False, soft_wrap=True)
        with _Progress(err, command, len(refs)) as progress:
            run = run_fleet(ws.client, job, refs, on_result=progress, file_timeout_s=file_timeout_s)
        workers, address = ws.workers, ws.address
    code = EXIT_FAILED if run.failed else EXIT_OK
    if args.json:
        import json

        print(json.dumps(_as_json(args, run, workers, address, code), indent=2))
    else:
        _print_summary(console, command, run, workers, args.out)
    return code


def _positive_duration(value: str, option: str) -> float:
    seconds = quantity(value, "s", option)
    if seconds <= 0:
        raise InputError(f"must be a duration > 0, got {value!r}", None, option)
    return seconds


def _select_files(args: argparse.Namespace, files: Any) -> list:
    """The run files of DIR or of the catalogue query (checked: exactly one of them)."""
    given = [f"--{d.replace('_', '-')}" for d in _FILTERS if getattr(args, d) is not None]
    if args.query:
        if args.dir is not None:
            raise InputError(f"give DIR or --query, not both (DIR {args.dir})", None, "--query")
        from bench.cli_catalog import query_runs

        return files.files_of_rows(query_runs(args))
    if given:
        raise InputError(f"{given[0]} filters catalogue rows: add --query (and no DIR)", None, given[0])
    if args.dir is None:
        raise InputError("give a directory of run files, or --query with the filters of 'bench runs'", None, "DIR")
    # the workers of an existing cluster may not share this process's working directory
    return files.files_in(args.dir.absolute() if args.scheduler else args.dir, exclude=args.out,
                          warn=lambda why: print(f"bench: warning: {why}", file=sys.stderr))


def _job(args: argparse.Namespace, command: str):
    from bench.analysis.per_file import calibration_options
    from bench.fleet.tasks import Job

    options: dict[str, Any] = {}
    if command == "calibrate":
        options = calibration_options(args.method, degree=args.degree, sensor=args.sensor)
    if command == "diagnose" and args.model is not None and not args.model.is_file():
        raise InputError(f"{args.model}: no such file", None, "--model")
    mapping = getattr(args, "map", None)
    return Job(command, str(args.out.resolve()), getattr(args, "method", None), tuple(sorted(options.items())),
               tuple(mapping) if mapping else None, str(args.model.resolve()) if getattr(args, "model", None) else None,
               args.force)


def _check_out(args: argparse.Namespace, refs: list, job: Any, files: Any) -> None:
    """The output directory can take the outputs (made if needed, writable, free space for replays'
    run files), and no output exists unless --force: else bad input, before anything runs."""
    from bench.errors import DestinationError
    from bench.record import check_destination

    need = sum(r.path.stat().st_size for r in refs if r.path.is_file()) if job.command == "replay" else 0
    try:
        check_destination(args.out, need)
    except DestinationError as exc:
        raise InputError(exc.message, None, "--out") from None
    if not args.force:
        exist = files.existing_outputs(args.out, refs, job.command, job.method)
        if exist:
            more = f" (and {len(exist) - 1} more)" if len(exist) > 1 else ""
            raise InputError(f"{exist[0]} exists{more}; choose another --out or delete them (--force overwrites them)", None, "--out")


class _Progress:
    """Files done / total and failures so far on stderr: a bar on a terminal, else a line every
    :data:`PROGRESS_LINE_S`; each failure on its own line as it happens."""

    def __init__(self, err: "Console", command: str, total: int):
        self.err, self.command, self.total = err, command, total
        self.done = self.failed = 0
        self.t0 = self.last = time.monotonic()
        self.bar: Any = None

    def __enter__(self) -> "_Progress":
        if self.err.is_terminal:
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

            self.bar = Progress(TextColumn(f"fleet {self.command}"), BarColumn(), MofNCompleteColumn(),
                                TextColumn("{task.fields[failed]} failed"), TimeElapsedColumn(), console=self.err, transient=True)
            self.bar.__enter__()
            self.task = self.bar.add_task("files", total=self.total, failed=0)
        return self

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.__exit__(*exc)

    def __call__(self, result: "FileResult") -> None:
        self.done += 1
        if not result.ok:
            self.failed += 1
            why = result.error or result.summary
            self.err.print(f"{result.verdict} {result.rel}: {why}", markup=False, highlight=False, soft_wrap=True)
        if self.bar is not None:
            self.bar.update(self.task, completed=self.done, failed=self.failed)
            return
        now = time.monotonic()
        if now - self.last >= PROGRESS_LINE_S or self.done == self.total:
            self.last = now
            print(f"fleet {self.command}: {self.done}/{self.total} files, {self.failed} failed, "
                  f"{self.done / max(now - self.t0, 1e-9):.2f} files/s", file=sys.stderr, flush=True)


def _totals(run: "FleetRun", workers: int) -> dict[str, Any]:
    busy = sum(r.wall_s for r in run.results)
    return {"files": len(run.results), "ok": len(run.results) - len(run.failed), "failed": len(run.failed),
            "wall_s": run.wall_s, "file_time_s": busy, "workers": workers,
            "files_per_s": len(run.results) / run.wall_s if run.wall_s > 0 else 0.0}


def _as_json(args: argparse.Namespace, run: "FleetRun", workers: int, address: str, code: int) -> dict[str, Any]:
    source = {"query": True} if args.query else {"dir": str(args.dir)}
    return {"command": args.fleet_command, **({"method": args.method} if args.fleet_command == "calibrate" else {}),
            **source, "out": str(args.out), "scheduler": address, "exit_code": code, "totals": _totals(run, workers),
            "files": [r.as_json() for r in run.results]}


def _detail(r: "FileResult", out: Path) -> str:
    """The table's detail of a file: its error (without the file's path, which the row names), else
    its summary, else its output (relative to OUT)."""
    if r.error:
        return r.error.removeprefix(f"{r.path}: ")
    if r.summary or not r.output:
        return r.summary
    try:
        return str(Path(r.output).relative_to(out.resolve()))
    except ValueError:
        return r.output


def _print_summary(console: "Console", command: str, run: "FleetRun", workers: int, out: Path) -> None:
    from rich.text import Text

    from bench.termtable import fit_tables

    colour = {0: "green", 1: "red", 2: "red"}
    rows = [[r.rel, Text(r.verdict, colour.get(r.exit_code, "white")), f"{r.wall_s:.2f}", _detail(r, out)] for r in run.results]
    for t in fit_tables(["file", "verdict", "time s", "detail"], rows, console.width, title=f"fleet {command}", prose=[3]):
        console.print(t)
    t = _totals(run, workers)
    console.print(f"{t['files']} file(s): {t['ok']} ok, {t['failed']} failed; {t['wall_s']:.2f} s wall on {workers} worker(s) "
                  f"({t['files_per_s']:.2f} files/s; {t['file_time_s']:.2f} s of per-file work)", markup=False, soft_wrap=True)
