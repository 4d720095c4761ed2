"""Analysis commands: ``bench calibrate``, ``bench import``, ``bench report``, ``bench diagnose``.

Thin: each parses its arguments, loads the data (:func:`bench.analysis.dataset.load_dataset`: a
run file or a measured-data CSV) and calls into ``bench/analysis`` or ``bench/report``.
"""

from __future__ import annotations

import argparse
import importlib
import json
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import yaml
from rich.console import Console
from rich.table import Table

from bench import __version__
from bench.analysis.progress import Progress
from bench.errors import EXIT_OK, InputError

METHODS: dict[str, tuple[str, str]] = {
    "thermal": ("bench.analysis.thermal_cal", "calibrate"),
    "rate-transfer": ("bench.analysis.rate_transfer", "calibrate"),
    "two-level": ("bench.analysis.two_level", "calibrate"),
    "gauss-newton": ("bench.analysis.gauss_newton", "calibrate"),
    "noise": ("bench.analysis.noise_cal", "calibrate"),
    "moving-average": ("bench.analysis.noise_cal", "calibrate_moving_average"),
}
"""``bench calibrate`` method -> (module, function(Dataset, **options) -> CalibrationResult)."""

CALIBRATION_SCHEMA = "bench-calibration/1"


def add_analysis_parsers(sub: argparse._SubParsersAction) -> None:
    """Add ``calibrate``, ``import``, ``report`` and ``diagnose`` to the CLI."""
    c = sub.add_parser("calibrate", help="calibrate sensors from a run file or measured-data CSV (docs/calibration.md)")
    c.add_argument("method", choices=list(METHODS), help="calibration method")
    c.add_argument("data", type=Path, help="run file (.h5), measured-data CSV, or HDF5/netCDF-4 file with --map")
    _add_map_option(c)
    c.add_argument("--json", action="store_true", help="print the results as JSON")
    c.add_argument("-o", "--output", type=Path, default=None, help="write the calibration YAML here (never overwrites)")
    c.add_argument("--sensor", choices=["accel", "gyro"], default=None, help="gauss-newton: which sensor (default accel)")
    c.add_argument("--degree", type=int, default=None, help="thermal: polynomial degree (default 3, NPSAT1 Table 4)")

    i = sub.add_parser("import", help="turn a measured-data CSV or a mapped HDF5/netCDF-4 file into a run file (docs/analysis.md)")
    i.add_argument("csv", metavar="DATA", type=Path, help="measured-data CSV, or HDF5/netCDF-4 file with --map")
    _add_map_option(i)
    i.add_argument("-o", "--output", type=Path, required=True, help="run file to write (never overwrites)")

    r = sub.add_parser("report", help="self-contained HTML report of a run (docs/report.md)")
    r.add_argument("run", type=Path, help="run file (.h5)")
    r.add_argument("-o", "--output", type=Path, required=True, help="HTML file to write")

    d = sub.add_parser("diagnose", help="what the sensor model gets wrong, the physical cause, the gain (docs/diagnose.md)")
    d.add_argument("data", type=Path, help="run file (.h5), measured-data CSV, or HDF5/netCDF-4 file with --map")
    _add_map_option(d)
    d.add_argument("--model", type=Path, default=None, help="sensor model YAML to start from (configs/sensors/NAME.yaml)")
    d.add_argument("--json", action="store_true", help="print the findings as JSON")
    d.add_argument("--report", type=Path, default=None, help="write an HTML page with the evidence")
    d.add_argument("-o", "--output", type=Path, default=None, help="write the extended sensor model YAML (never overwrites)")


def _add_map_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--map", action="append", default=None, metavar="TARGET=VARIABLE[COLS]:UNITS | MAPPING.yaml",
                   help="read another program's HDF5/netCDF-4 file: which variable (and columns) becomes gyro, accel, "
                        "temp, time, ... and its units; repeatable, or a mapping YAML file (docs/analysis.md)")


def _load_data(args: argparse.Namespace):
    """The dataset of ``args.data`` (``--map``: a foreign HDF5/netCDF-4 file); how a mapped file was
    read (time source, dropped rows) goes to stderr, so ``--json`` output stays clean."""
    from bench.analysis.foreign import load_data

    ds, notes = load_data(args.data, args.map)
    for note in notes:
        Console(stderr=True, highlight=False).print(f"note: {note}", markup=False, soft_wrap=True)
    return ds


def _refuse_existing(path: Path | None, what: str) -> None:
    if path is not None and path.exists():
        raise InputError(f"{what} {path} exists; it is never overwritten (choose another name)", None, "-o")


def _print_tables(console: Console, tables) -> None:
    for t in tables:
        table = Table(title=t.title)
        for h in t.headers:
            table.add_column(str(h))
        for row in t.rows:
            table.add_row(*[f"{c:.6g}" if isinstance(c, float) else ("" if c is None else str(c)) for c in row])
        console.print(table)


def cmd_calibrate(args: argparse.Namespace, console: Console) -> int:
    from bench.replay.recording import file_sha256

    _refuse_existing(args.output, "calibration file")
    module_name, func_name = METHODS[args.method]
    module = importlib.import_module(module_name)
    opts: dict[str, Any] = {}
    if args.degree is not None:
        if args.method != "thermal":
            raise InputError("--degree applies to the thermal method only", None, "--degree")
        opts["degree"] = args.degree
    if args.sensor is not None:
        if args.method != "gauss-newton":
            raise InputError("--sensor applies to the gauss-newton method only", None, "--sensor")
        opts["sensor"] = args.sensor
    with Progress(f"calibrate {args.method}") as say:
        say(f"reading {args.data}")
        if args.method == "rate-transfer" and args.data.suffix.lower() not in (".h5", ".hdf5") and module.is_summary_csv(args.data):
            result = module.calibrate_summary_csv(args.data, **opts)
        else:
            ds = _load_data(args)
            say(f"fitting {len(ds):,} rows")
            result = getattr(module, func_name)(ds, **opts)
    if args.json:
        print(json.dumps(result.json, indent=2, default=_plain))
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
        _write_new(args.output, yaml.safe_dump(_plain_tree(doc), sort_keys=False))
        _info_console(args, console).print(f"calibration written to {args.output}", markup=False, soft_wrap=True)
    return EXIT_OK


def cmd_import(args: argparse.Namespace, console: Console) -> int:
    from bench.analysis.foreign import load_notes
    from bench.analysis.importer import import_data

    _refuse_existing(args.output, "run file")
    ds = import_data(args.csv, args.output, args.map)
    for note in load_notes(ds) if args.map else []:
        console.print(f"note: {note}", markup=False, soft_wrap=True)
    console.print(f"{len(ds)} rows of {args.csv} written to {args.output}", markup=False, soft_wrap=True)
    return EXIT_OK


def cmd_report(args: argparse.Namespace, console: Console) -> int:
    from bench.report.run_report import write_report

    with Progress("report") as say:
        say(f"writing {args.output} from {args.run}")
        write_report(args.run, args.output)
    console.print(f"report written to {args.output}", markup=False, soft_wrap=True)
    return EXIT_OK


def cmd_diagnose(args: argparse.Namespace, console: Console) -> int:
    from bench.analysis.diagnose import diagnose, write_report

    _refuse_existing(args.output, "model file")
    info = _info_console(args, console)
    with Progress("diagnose") as say:
        say(f"reading {args.data}")
        ds = _load_data(args)
        say(f"{len(ds):,} rows read, preparing")
        result = diagnose(ds, model_path=str(args.model) if args.model else None, progress=say)
    if args.json:
        print(json.dumps(result.json, indent=2, default=_plain))
    else:
        for line in result.summary_lines():
            console.print(line, markup=False, soft_wrap=True)
    prepared = (getattr(result, "_internal", None) or (None,))[0]
    if hasattr(prepared, "rows_line"):
        info.print(prepared.rows_line(), markup=False, soft_wrap=True)
    if args.report is not None:
        with Progress("diagnose") as say:
            say(f"writing the report {args.report}")
            write_report(result, ds, args.report)
        info.print(f"report written to {args.report}", markup=False, soft_wrap=True)
    if args.output is not None:
        _write_new(args.output, yaml.safe_dump(_plain_tree(result.extended_model()), sort_keys=False))
        info.print(f"extended model written to {args.output}", markup=False, soft_wrap=True)
    return EXIT_OK


def _info_console(args: argparse.Namespace, console: Console) -> Console:
    """Where "written to" lines go: with --json stderr (stdout carries the JSON), else ``console``."""
    return Console(stderr=True, highlight=False) if getattr(args, "json", False) else console


def _write_new(path: Path, text: str) -> None:
    try:
        with open(path, "x", encoding="utf-8") as fh:
            fh.write(text)
    except FileExistsError:
        raise InputError(f"{path} exists; it is never overwritten", None, "-o") from None
    except OSError as exc:
        raise InputError(f"cannot write {path}: {exc.strerror or exc}", None, "-o") from None


def _plain(v: Any) -> Any:
    """numpy scalars and arrays as plain Python for JSON/YAML."""
    import numpy as np

    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, Path):
        return str(v)
    raise TypeError(f"not serialisable: {type(v).__name__}")


def _plain_tree(v: Any) -> Any:
    if isinstance(v, dict):
        return {str(k): _plain_tree(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain_tree(x) for x in v]
    if isinstance(v, (str, int, float, bool)) or v is None:
        return v
    return _plain_tree(_plain(v))
