"""Analysis commands: ``bench calibrate``, ``bench import``, ``bench report``, ``bench diagnose``.

Thin: each parses its arguments, loads the data (:func:`bench.analysis.dataset.load_dataset`: a
run file or a measured-data CSV) and calls into ``bench/analysis`` or ``bench/report``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from typing import TYPE_CHECKING

from bench import __version__
from bench.analysis.per_file import METHODS
from bench.cli_common import add_force, check_output, epilog
from bench.outputs import output_file
from bench.errors import EXIT_OK, InputError

if TYPE_CHECKING:  # rich, yaml and the analyses are imported where used: `bench --help` stays light
    from rich.console import Console

CALIBRATION_SCHEMA = "bench-calibration/1"


def add_analysis_parsers(sub: argparse._SubParsersAction) -> None:
    """Add ``calibrate``, ``import``, ``report`` and ``diagnose`` to the CLI."""
    data_bad = "unreadable or unsuitable data, a bad option, or an output that exists (without --force)"
    c = sub.add_parser(
        "calibrate", help="calibrate sensors from a run file or measured-data CSV (docs/calibration.md)",
        description="Calibrate sensors from a run file, a measured-data CSV (time_s, gyro_x_dps, temp_c, ...: units in "
                    "the column names) or another program's HDF5/netCDF-4 file with --map. Methods: thermal (bias and "
                    "scale factor vs temperature), rate-transfer (scale factor and bias from rate steps), two-level, "
                    "gauss-newton (accelerometer/gyro 12-parameter fit), six-position (six faces and three rotations, "
                    "Ferraris/imucal: accelerometer and gyro bias, scale, misalignment, gyro g-sensitivity), noise (Allan deviation: ARW, bias "
                    "instability, RRW), moving-average (noise vs the board's averaging). docs/calibration.md.",
        epilog=epilog("bench calibrate thermal runs/20261123T101500Z_thermal_ramp_ambient.h5 -o calibration.yaml",
                      "bench calibrate noise data.csv --json",
                      "bench calibrate gauss-newton DATA.nc --map accel=acceleration:m/s2 --map time=timestamp:s --sensor accel",
                      "bench calibrate six-position session.csv --map configs/mappings/imucal.yaml --map sample_rate_hz=102.4 "
                      "--sections session_list.json -o calibration.yaml",
                      ok="the calibration was computed (and written with -o)", bad=data_bad))
    c.add_argument("method", choices=list(METHODS), help="calibration method: " + ", ".join(METHODS))
    c.add_argument("data", type=Path, help="run file (.h5), measured-data CSV, or HDF5/netCDF-4 file with --map")
    _add_map_option(c)
    c.add_argument("--json", action="store_true", help="print the results as JSON (default: tables)")
    c.add_argument("-o", "--output", type=Path, default=None,
                   help="write the calibration YAML here (default: none; an existing file only with --force)")
    c.add_argument("--sensor", choices=["accel", "gyro"], default=None, help="gauss-newton: which sensor (default accel)")
    c.add_argument("--degree", type=int, default=None, help="thermal: polynomial degree (default 3, NPSAT1 Table 4)")
    c.add_argument("--sections", type=Path, default=None, metavar="FILE",
                   help="six-position: the section list (imucal's JSON or CSV, or YAML with start/end rows or "
                        "start_s/end_s); default: found in the data and reported")
    c.add_argument("--local-g", default=None, metavar="ACCEL",
                   help="six-position: gravity at the bench, e.g. '9.81 m/s^2' (default 9.80665 m/s², 1 g)")
    add_force(c)

    i = sub.add_parser(
        "import", help="turn a measured-data CSV or a mapped HDF5/netCDF-4 file into a run file (docs/analysis.md)",
        description="Turn a measured-data CSV (time_s, gyro_x_dps, accel_x_g, temp_c, ...: units in the column names) "
                    "or another program's HDF5/netCDF-4 file (with --map) into a run file that every analysis, "
                    "'bench inspect' and 'bench report' read (docs/analysis.md).",
        epilog=epilog("bench import data.csv -o imported.h5",
                      "bench import DATA.nc --map gyro=angular_velocity[3:6]:rad/s --map time=timestamp:s -o imported.h5",
                      ok="the run file was written", bad=data_bad))
    i.add_argument("csv", metavar="DATA", type=Path, help="measured-data CSV, or HDF5/netCDF-4 file with --map")
    _add_map_option(i)
    i.add_argument("-o", "--output", type=Path, required=True, help="run file to write (required; an existing file only with --force)")
    add_force(i)

    r = sub.add_parser(
        "report", help="self-contained HTML report of a run (docs/report.md)",
        description="Write one self-contained HTML page (figures inline) of a run: verdict and checks, unit, steps, "
                    "instruments, temperatures and rates, and the analyses that apply (docs/report.md).",
        epilog=epilog("bench report runs/20261123T101500Z_rate_transfer.h5 -o runs/20261123T101500Z_rate_transfer.html",
                      "bench report RUN.h5 -o report.html --force",
                      ok="the report was written", bad="not a readable run file, or the output exists (without --force)"))
    r.add_argument("run", type=Path, help="run file (.h5)")
    r.add_argument("-o", "--output", type=Path, required=True,
                   help="HTML file to write (required; an existing file only with --force, never the run file)")
    add_force(r)

    d = sub.add_parser(
        "diagnose", help="what the sensor model gets wrong, the physical cause, the gain (docs/diagnose.md)",
        description="Compare data with a sensor model and name what the model misses (thermal lag, hysteresis, "
                    "g-sensitivity, warm-up, ...) with its gain, or say UNEXPLAINED where no term explains the "
                    "structure left (docs/diagnose.md).",
        epilog=epilog("bench diagnose runs/20261123T101500Z_thermal_ramp_ambient.h5",
                      "bench diagnose data.csv --model configs/sensors/estcube_bmg160.yaml --json --report evidence.html -o extended.yaml",
                      "bench diagnose monday.csv tuesday.csv --power-on-at 0,12.5",
                      ok="the diagnosis was made (whatever it found)", bad=data_bad))
    d.add_argument("data", type=Path, nargs="+", metavar="DATA",
                   help="run file (.h5), measured-data CSV, or HDF5/netCDF-4 file with --map; several files: runs of "
                        "ONE unit, each from a power-on, diagnosed together (a warm-up repeats at each power-on, a "
                        "random walk does not; docs/diagnose.md, \"Several runs of one unit\")")
    _add_map_option(d)
    d.add_argument("--model", type=Path, default=None,
                   help="sensor model YAML whose known terms join the baseline (configs/sensors/NAME.yaml or an earlier -o output; default: the baseline alone)")
    d.add_argument("--power-on-at", action="append", default=None, metavar="TIME",
                   help="when the data have no power_on_s column: the time (s, on the data's time axis) the sensor was "
                        "powered on, at or before the first row (default: the # power_on_at_s metadata, else the "
                        "warm-up is not searched); with several files one value per file, in order (repeat the "
                        "option or give a comma list; '-' for a file with its own column or metadata)")
    d.add_argument("--json", action="store_true", help="print the findings as JSON (default: a summary)")
    d.add_argument("--report", type=Path, default=None,
                   help="write an HTML page with the evidence (default: none; an existing file only with --force; "
                        "one data file only)")
    d.add_argument("-o", "--output", type=Path, default=None,
                   help="write the extended sensor model YAML (default: none; an existing file only with --force; "
                        "with several files: the first run's model with the warm-up found across runs)")
    add_force(d)


def _seconds(text: str) -> float:
    """A finite number of seconds (``--power-on-at``)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a time in s, got {text!r}") from None
    if v != v or v in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"expected a finite time in s, got {text!r}")
    return v


def _add_map_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--map", action="append", default=None, metavar="TARGET=VARIABLE[COLS]:UNITS | MAPPING.yaml",
                   help="read another program's HDF5/netCDF-4 file: which variable (and columns) becomes gyro, accel, "
                        "temp, time, ... and its units; repeatable, or a mapping YAML file (docs/analysis.md)")


def _note_on_stderr(note: str) -> None:
    """How a mapped file was read (time source, dropped rows), on stderr, so ``--json`` output
    stays clean (the ``on_note`` of :mod:`bench.analysis.per_file`)."""
    from rich.console import Console

    Console(stderr=True, highlight=False).print(f"note: {note}", markup=False, soft_wrap=True)


def _print_tables(console: Console, tables) -> None:
    """The result tables, every value in full: columns that do not fit the console's width side by
    side go to continuation tables that repeat the first column (``bench/termtable.py``)."""
    from bench.termtable import fit_tables

    for t in tables:
        rows = [[f"{c:.6g}" if isinstance(c, float) else ("" if c is None else str(c)) for c in row] for row in t.rows]
        for table in fit_tables([str(h) for h in t.headers], rows, console.width, title=t.title):
            console.print(table)


def cmd_calibrate(args: argparse.Namespace, console: Console) -> int:
    from datetime import datetime, timezone

    from bench.analysis.per_file import calibrate_file, calibration_options, json_text
    from bench.analysis.progress import Progress
    from bench.replay.recording import file_sha256

    check_output(args.output, "-o", force=args.force, inputs=[args.data])
    opts = calibration_options(args.method, degree=args.degree, sensor=args.sensor, sections=args.sections,
                               local_g=args.local_g)
    with Progress(f"calibrate {args.method}") as say:
        result = calibrate_file(args.method, args.data, args.map, opts, progress=say, on_note=_note_on_stderr)
    if args.json:
        print(json_text(result.json))
    else:
        _print_tables(console, result.tables)
        for note in result.notes:
            console.print(f"note: {note}", markup=False, soft_wrap=True)
    if args.output is not None:
        if result.calibration is None:
            raise InputError(f"method {args.method} produces no calibration file (use --json for its results)", None, "-o")
        doc = {
            "schema": CALIBRATION_SCHEMA,
            "method": args.method,
            "created_utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "software_version": __version__,
            "source": {"path": str(args.data), "sha256": file_sha256(args.data)},
            **result.calibration,
        }
        _write_yaml(args.output, doc, args.force)
        _info_console(args, console).print(f"calibration written to {args.output}", markup=False, soft_wrap=True)
    return EXIT_OK


def cmd_import(args: argparse.Namespace, console: Console) -> int:
    from bench.analysis.foreign import load_notes
    from bench.analysis.importer import import_data

    check_output(args.output, "-o", force=args.force, inputs=[args.csv])
    with output_file(args.output, "-o", force=args.force) as tmp:
        ds = import_data(args.csv, tmp, args.map)
    for note in load_notes(ds) if args.map else []:
        console.print(f"note: {note}", markup=False, soft_wrap=True)
    console.print(f"{len(ds)} rows of {args.csv} written to {args.output}", markup=False, soft_wrap=True)
    return EXIT_OK


def cmd_report(args: argparse.Namespace, console: Console) -> int:
    from bench.analysis.progress import Progress
    from bench.report.run_report import write_report

    check_output(args.output, "-o", force=args.force, inputs=[args.run])
    with Progress("report") as say, output_file(args.output, "-o", force=args.force) as tmp:
        say(f"writing {args.output} from {args.run}")
        write_report(args.run, tmp)
    console.print(f"report written to {args.output}", markup=False, soft_wrap=True)
    return EXIT_OK


def cmd_diagnose(args: argparse.Namespace, console: Console) -> int:
    from bench.analysis.diagnose import write_report
    from bench.analysis.per_file import diagnose_file, diagnose_files, json_text, rows_line
    from bench.analysis.progress import Progress

    files = list(args.data)
    power_on = _power_on_values(args.power_on_at, len(files))
    for path, option in ((args.report, "--report"), (args.output, "-o")):
        check_output(path, option, force=args.force, inputs=[*files, args.model])
    if args.report is not None and args.output is not None and args.report.resolve() == args.output.resolve():
        raise InputError("--report and -o name the same file; give two names", None, "-o")
    if len(files) > 1 and args.report is not None:
        raise InputError(f"--report is for one data file ({len(files)} given): diagnose each run alone for its "
                         "report; the runs together give the summary, --json and -o", None, "--report")
    info = _info_console(args, console)
    if len(files) > 1:
        with Progress("diagnose") as say:
            runs = diagnose_files(files, args.map, args.model, progress=say, on_note=_note_on_stderr, power_on_at=power_on)
        if args.json:
            print(json_text(runs.json))
        else:
            for line in runs.summary_lines():
                console.print(line, markup=False, soft_wrap=True)
        for k, r in enumerate(runs.runs, 1):
            analysed = rows_line(r)
            if analysed is not None:
                info.print(f"run {k}: {analysed}", markup=False, soft_wrap=True)
        if args.output is not None:
            _write_yaml(args.output, runs.extended_model(), args.force)
            info.print(f"extended model written to {args.output}", markup=False, soft_wrap=True)
        return EXIT_OK
    with Progress("diagnose") as say:
        result, ds = diagnose_file(files[0], args.map, args.model, progress=say, on_note=_note_on_stderr,
                                   power_on_at=power_on[0])
    if args.json:
        print(json_text(result.json))
    else:
        for line in result.summary_lines():
            console.print(line, markup=False, soft_wrap=True)
    analysed = rows_line(result)
    if analysed is not None:
        info.print(analysed, markup=False, soft_wrap=True)
    if args.report is not None:
        with Progress("diagnose") as say, output_file(args.report, "--report", force=args.force) as tmp:
            say(f"writing the report {args.report}")
            write_report(result, ds, tmp)
        info.print(f"report written to {args.report}", markup=False, soft_wrap=True)
    if args.output is not None:
        _write_yaml(args.output, result.extended_model(), args.force)
        info.print(f"extended model written to {args.output}", markup=False, soft_wrap=True)
    return EXIT_OK


def _power_on_values(given: list[str] | None, files: int) -> list[float | None]:
    """``--power-on-at`` as one value (s, or None for '-') per data file: repeated options and comma
    lists flattened; the wrong number of values is bad input located at the option."""
    if given is None:
        return [None] * files
    values: list[float | None] = []
    for text in given:
        for item in text.split(","):
            item = item.strip()
            if item == "-" and files > 1:
                values.append(None)
                continue
            try:
                values.append(_seconds(item))
            except argparse.ArgumentTypeError as exc:
                raise InputError(str(exc), None, "--power-on-at") from None
    if len(values) != files:
        raise InputError(f"{len(values)} value(s) for {files} data file(s); give one per file, in order "
                         "(repeat the option or a comma list)", None, "--power-on-at")
    return values


def _info_console(args: argparse.Namespace, console: Console) -> Console:
    """Where "written to" lines go: with --json stderr (stdout carries the JSON), else ``console``."""
    from rich.console import Console

    return Console(stderr=True, highlight=False) if getattr(args, "json", False) else console


def _write_yaml(path: Path, doc: Any, force: bool) -> None:
    """Write ``doc`` (numpy values as plain ones) as YAML to the ``-o`` file ``path``
    (:func:`bench.cli_common.output_file`: an existing file is replaced only with ``force``)."""
    import yaml

    from bench.analysis.per_file import plain_tree

    with output_file(path, "-o", force=force) as tmp:
        tmp.write_text(yaml.safe_dump(plain_tree(doc), sort_keys=False), encoding="utf-8")
