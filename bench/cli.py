"""The ``bench`` command line. Thin: every command calls into the layers below.

Exit codes: 0 success, 1 run failed or aborted, 2 bad input (one located line per problem, no
traceback unless ``--debug``).
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from bench import __version__
from bench.cli_common import Parser as _Parser
from bench.cli_common import add_force, epilog, quantity
from bench.errors import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_OK, KNOWN_ERRORS, InputError, InputErrors
from bench.quantity_format import fmt_hms
from bench.startup_signals import STOP_SIGNALS, StartupSignals, StoppedDuringStartup, stop_within
from bench.terminal_text import printable

if TYPE_CHECKING:  # imported where used: `bench --help` and `bench --version` stay light (docs/benchmarks.md)
    from rich.console import Console


_PLAIN_COMMANDS = {"validate"}
"""Commands that print plain lines: their console is a :class:`_LazyConsole`."""


class _LazyConsole:
    """A rich ``Console`` made on first attribute use (``print``, ``width``…; not a context manager):
    a command that prints plainly (``validate``) never imports rich unless it fails, which is a
    tenth of its start-up time (docs/benchmarks.md)."""

    def __init__(self, **kwargs: object):
        self._kwargs = kwargs
        self._console: "Console | None" = None

    def __getattr__(self, name: str):
        if self._console is None:
            from rich.console import Console

            self._console = Console(**self._kwargs)
        return getattr(self._console, name)


PARAM_HELP = ("override a procedure parameter, with units where it has them, e.g. -p cold=-20degC -p hold=30min "
              "(repeatable; default: the procedure's values)")


class _OneCommand:
    """The subparsers of :func:`build_parser` when one command was asked for: that command's parser
    is made, every other one is :data:`_SKIPPED`. argparse builds the ~30 commands' parsers in
    ~10 ms, a twentieth of ``bench validate``'s start (docs/benchmarks.md, "Start-up")."""

    def __init__(self, sub: argparse._SubParsersAction, name: str) -> None:
        self._sub, self._name, self.found = sub, name, False

    def add_parser(self, name: str, **kwargs: object) -> argparse.ArgumentParser:
        if name != self._name:
            return _SKIPPED  # type: ignore[return-value]
        self.found = True
        return self._sub.add_parser(name, **kwargs)

    def __getattr__(self, name: str) -> object:
        return getattr(self._sub, name)


class _Skipped:
    """A command's parser that is not made: takes every call of argparse's API and keeps nothing."""

    def __getattr__(self, name: str) -> object:
        return self._ignore

    def _ignore(self, *args: object, **kwargs: object) -> "_Skipped":
        return self


_SKIPPED = _Skipped()

_ADDED_BY = {"bench.replay.cli": ("replay",), "bench.cli_analysis": ("calibrate", "import", "report", "diagnose"),
             "bench.cli_catalog": ("runs", "catalog"), "bench.cli_fleet": ("fleet",), "bench.cli_web": ("serve",),
             "bench.cli_unit": ("unit",)}
"""The commands whose parsers each module adds: a parser for another command does not import it.
A command missing here still works (its parser is then built whole; the CLI tests fail)."""


def _wanted(only: str | None, module: str) -> bool:
    return only is None or only in _ADDED_BY[module]


def build_parser() -> argparse.ArgumentParser:
    """The ``bench`` parser; every command's ``--help`` has its exit codes and examples."""
    return _build_parser(None)[0]


def parser_for(argv: list[str]) -> argparse.ArgumentParser:
    """The parser of the command line ``argv``: when it names a command first (after ``--debug``
    only), a parser with that command's subparser alone, which parses ``argv`` exactly as
    :func:`build_parser`'s does; for ``--version`` first, none; else (no command, ``--help``, a
    misspelt command) every command's."""
    first = next((i for i, word in enumerate(argv) if word != "--debug"), len(argv))
    if first < len(argv) and argv[first] == "--version":
        return _build_parser("")[0]  # it prints the version and exits before any command is looked at
    if first < len(argv) and not argv[first].startswith("-"):
        parser, found = _build_parser(argv[first])
        if found:
            return parser
    return build_parser()


def _build_parser(only: str | None) -> tuple[argparse.ArgumentParser, bool]:
    """The ``bench`` parser with every command's subparser, or with ``only``'s (and whether there is
    such a command)."""
    p = _Parser(prog="bench", top_level=True,
                description="Ground-support test benches for spacecraft attitude sensors: run YAML test procedures on real "
                            "or simulated instruments, record every run to an HDF5 run file, analyse and report it.",
                epilog=epilog("bench run procedures/startup_profile.yaml --config configs/sim.yaml --sim",
                              "bench validate procedures/thermal_ramp_ambient.yaml --config configs/lab.yaml",
                              "bench COMMAND --help                      # each command's options, exit codes and examples",
                              ok="success",
                              failed="a run failed (a check did not pass) or aborted, a replay diverged, an instrument did "
                                     "not answer; or an unexpected error (one line; --debug shows the traceback)",
                              notes="From the instruments on the bench to a first real run: docs/hardware.md."))
    p.add_argument("--version", action="version", version=f"bench {__version__}", help="print the version and exit")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    if only is not None:
        sub = _OneCommand(sub, only)  # type: ignore[assignment]

    r = sub.add_parser(
        "run", help="run a procedure (real instruments unless --sim)",
        description="Run a procedure on the instruments of the lab config: on their ports, or with --sim on the config's "
                    "simulators behind the same drivers, in virtual time. The run is recorded to "
                    "RUNS_DIR/<UTC time>_<procedure>.h5; Ctrl-Z pauses, Ctrl-C stops (instruments to their safe state).",
        epilog=epilog("bench run procedures/startup_profile.yaml --config configs/sim.yaml --sim",
                      "bench run procedures/thermal_ramp_ambient.yaml --config configs/lab.yaml -p cold=-20degC --unit SN0042",
                      "bench run procedures/functional_test.yaml --config configs/sim.yaml --sim "
                      "--answers procedures/answers/ci.yaml --inject-faults rate=6/h,seed=1",
                      ok="the run completed: every step done, every check passed",
                      failed="a check failed (the run went on to its end), or the run aborted (operator stop, instrument "
                             "fault, interlock, full disk) after putting the instruments in their safe state",
                      bad="bad input (procedure, config, options, runs directory): one located line per problem; "
                          "nothing moved"))
    r.add_argument("procedure", type=Path, help="procedure YAML file (docs/procedures.md)")
    r.add_argument("--config", type=Path, required=True, help="lab config YAML file: instruments, ports, limits, simulators (required)")
    r.add_argument("--sim", action="store_true", help="simulated instruments behind the same drivers, in virtual time "
                                                       "(default: real instruments unless the config says 'mode: sim')")
    r.add_argument("--realtime", action="store_true", help="with --sim: run at wall-clock pace (default: virtual time, hours in seconds)")
    r.add_argument("--runs-dir", type=Path, default=Path("runs"), help="where run files go (default: runs/)")
    r.add_argument("--operator", metavar="NAME", default=None,
                   help="who runs it, recorded in the run file with where it came from (default: the login name; one of the "
                        "lab config's 'operators:' when it lists them)")
    r.add_argument("-p", "--param", action="append", metavar="NAME=VALUE", help=PARAM_HELP)
    r.add_argument("--answers", type=Path, default=None,
                   help="YAML file answering the procedure's operator prompts (id: yes) (default: ask on the terminal)")
    r.add_argument("--inject-faults", metavar="SPEC", default=None,
                   help="with --sim: inject faults through the simulators: a rate per hour of run time and a seed, e.g. "
                        "'rate=6/h,seed=1', or faults at run times, e.g. 'serial_unplug@300s' (docs/reliability.md)")
    r.add_argument("--unit", metavar="SERIAL", default=None, help="serial number of the unit under test, recorded in the run file (docs/units-under-test.md)")
    r.add_argument("--part", metavar="PN", default=None, help="part number of the unit under test")
    r.add_argument("--revision", metavar="REV", default=None, help="revision of the unit under test")
    r.add_argument("--station", metavar="NAME", default=None, help="test station name (default: the config's 'station:', else the host name)")
    r.add_argument("--catalog", metavar="URL", default=None, help="catalogue of runs to record the run in (default: the config's 'catalog:', else RUNS_DIR/catalog.sqlite; docs/catalog.md)")
    r.add_argument("--accept-overdue-calibration", action="store_true",
                   help="confirm a run on instruments past their config 'calibration_due' date without asking (recorded)")
    r.add_argument("--json", action="store_true",
                   help="print the run's result as one JSON object on stdout at the end; progress and the summary go to stderr "
                        "(fields: docs/run-file.md)")

    v = sub.add_parser(
        "validate", help="check a procedure (and its limits against a lab config) without running it",
        description="Check a procedure without running it: schema, units, parameters, loops and calls expanded, and with "
                    "--config the instrument names, drivers and this lab's hardware limits. Prints the step count and "
                    "the estimated procedure time.",
        epilog=epilog("bench validate procedures/startup_profile.yaml",
                      "bench validate procedures/thermal_ramp_ambient.yaml --config configs/lab.yaml -p cold=-20degC",
                      ok="the procedure is valid", bad="invalid: one located line per problem (file:line:column: field: message)"))
    v.add_argument("procedure", type=Path, help="procedure YAML file (docs/procedures.md)")
    v.add_argument("--config", type=Path, default=None,
                   help="lab config: instrument names, drivers and this lab's limits (default: the standard instrument names)")
    v.add_argument("-p", "--param", action="append", metavar="NAME=VALUE", help=PARAM_HELP)

    pl = sub.add_parser(
        "plan", help="the expanded step list of a procedure with estimated durations",
        description="Validate a procedure like 'bench validate' and print its expanded steps with what each does (in "
                    "units), its estimated duration and start time (h:mm:ss of procedure time).",
        epilog=epilog("bench plan procedures/thermal_ramp_ambient.yaml --config configs/lab.yaml",
                      ok="the plan was printed", bad="invalid procedure or config: one located line per problem"))
    pl.add_argument("procedure", type=Path, help="procedure YAML file (docs/procedures.md)")
    pl.add_argument("--config", type=Path, default=None, help="lab config to validate against (default: the standard instrument names)")
    pl.add_argument("-p", "--param", action="append", metavar="NAME=VALUE", help=PARAM_HELP)

    w = sub.add_parser(
        "watch", help="live view of a run in progress (reads the run file)",
        description="Live view of a run in progress from another terminal: current step, latest readings, checks, "
                    "events. Reads the run file only (SWMR); Ctrl-C leaves the run alone (docs/watch.md).",
        epilog=epilog("bench watch runs/20261123T101500Z_thermal_ramp_ambient.h5",
                      "bench watch RUN.h5 --once --interval 0.5s",
                      ok="the run ended, Ctrl-C, or --once printed its snapshot", bad="not a run file, or a bad --interval"))
    w.add_argument("run_file", type=Path, help="run file (.h5) being written by 'bench run' (or a finished one)")
    w.add_argument("--interval", default="1 s", help="refresh interval, a duration: 500ms, 2 s; a bare number is s (default '1 s'; 0.05 s to 60 s)")
    w.add_argument("--once", action="store_true", help="print one snapshot and exit")

    if _wanted(only, "bench.replay.cli"):
        from bench.replay.cli import add_replay_parser

        add_replay_parser(sub)

    i = sub.add_parser(
        "inspect", help="summarise a run file (also while it is being written)",
        description="Summary of a run file: procedure, operator, unit, status (running, completed, aborted, crashed), "
                    "instruments, steps and their outcomes, checks, streams (rows, rate, span) and the last events.",
        epilog=epilog("bench inspect runs/20261123T101500Z_startup_profile.h5 --events 100",
                      "bench inspect runs/20261123T101500Z_startup_profile.h5 --verify",
                      ok="the summary was printed, whatever the run's own status; with --verify: every chunk passed its checksum",
                      failed="with --verify only: a chunk is damaged (its stream and run times are printed), or the file "
                             "has no checksums (written before them: unverified)",
                      bad="not a run file or unreadable (one line saying why)"))
    i.add_argument("run_file", type=Path, help="run file (.h5) of 'bench run', 'bench import' or 'bench replay'")
    i.add_argument("--events", type=int, default=40, help="how many of the last events to list (default 40; instrument traffic, "
                                                          "command and reply events, is summarised per instrument, not listed)")
    i.add_argument("--traffic", action="store_true", help="also list the command and reply events (default: summarised per instrument)")
    i.add_argument("--json", action="store_true", help="print one JSON object instead of tables (fields: docs/run-file.md)")
    i.add_argument("--verify", action="store_true", help="read every chunk of every stream and of the event log and check its "
                                                         "Fletcher-32 checksum; print per stream verified, failed (rows and run "
                                                         "times) or unverified (docs/run-file.md)")

    c = sub.add_parser(
        "calibrate-bench", help="stepper bench speed calibration from rotation timings: GRBL's steps per degree, or n = k(1/v - b)",
        description="From stopwatch timings of full rotations: on stock GRBL (columns rate_dps, rotation_time_s) the "
                    "corrected steps per degree and the $100 line that sets it; on the ESTCube-2 thesis firmware "
                    "(columns n, rotation_time_s) n = k·(1/v − b) (Eq. 3.1). Type A, B and combined uncertainties "
                    "as the thesis (docs/stepper-bench.md).",
        epilog=epilog("bench calibrate-bench tests/data/estcube2_table_3_1.csv",
                      "bench calibrate-bench grbl_timings.csv --steps-per-deg 894.33",
                      "bench calibrate-bench timings.csv --resolution 0.1s --json",
                      ok="the fit was printed", bad="bad CSV, --resolution or --steps-per-deg (one located line per problem)"))
    c.add_argument("timings", type=Path, help="CSV with columns rate_dps (commanded, deg/s) or n (thesis firmware), and "
                                              "rotation_time_s (s per revolution); repeated rows per level")
    c.add_argument("--steps-per-deg", default=None, help="GRBL: the $100 (steps per degree) the bench ran with while timed")
    c.add_argument("--axis", default="X", choices=["X", "Y", "Z"], help="GRBL: the bench's axis (default X: $100)")
    c.add_argument("--resolution", default="0.01 s", help="stopwatch resolution, a duration: 10ms; a bare number is s (default '0.01 s', ESTCube-2 section 3.2.2)")
    c.add_argument("--json", action="store_true", help="print a JSON object instead of a table")

    ic = sub.add_parser("instruments", help="instrument housekeeping",
                        description="Instrument housekeeping; 'bench instruments check' is the first command on a new bench.",
                        epilog=epilog("bench instruments check --config configs/lab.yaml", ok="see 'bench instruments check --help'",
                                      failed="see 'bench instruments check --help'"))
    icsub = ic.add_subparsers(dest="instruments_command", metavar="ACTION", parser_class=_Parser, required=True)
    chk = icsub.add_parser(
        "check", help="identify every instrument of a config and read one value from each",
        description="Open every instrument of the config on its own port, identify it and read one value that changes "
                    "nothing (no motion, no power, no set point). One line per instrument; a failure says what to do "
                    "(serial permissions, port names, CAN bring-up, Modbus host/port, baud rate and wiring; docs/hardware.md).",
        epilog=epilog("bench instruments check --config configs/lab.yaml", "bench instruments check --config configs/sim.yaml",
                      ok="every instrument identified and answering",
                      failed="at least one instrument could not be opened or did not answer (its line says what to do)",
                      bad="bad config (one located line per problem)"))
    chk.add_argument("--config", type=Path, required=True, help="lab config YAML file (required)")
    chk.add_argument("--sim", action="store_true", help="check the simulators behind the drivers (implied by 'mode: sim' in the config)")
    kd = icsub.add_parser(
        "kinds", help="list the installed instrument kinds and the package each comes from",
        description="The instrument kinds bench knows here (a config's 'driver:'), found by entry point (group "
                    "bench.instruments): bench's own and those of installed packages, with the package, whether it has a "
                    "simulator, the procedure steps it adds and its signals with units (docs/instruments.md). It reads every "
                    "package's entry points afresh and refreshes bench's cache of them (~/.cache/bench/kinds).",
        epilog=epilog("bench instruments kinds", "bench instruments kinds --json",
                      ok="every kind listed", failed="a package declares a kind that could not be loaded (its line says why)"))
    kd.add_argument("--json", action="store_true", help="print one JSON object instead of a table")

    lb = sub.add_parser("lab", help="set up a lab config", description="Lab config housekeeping.",
                        epilog=epilog("bench lab init -o configs/lab.yaml", ok="see 'bench lab init --help'",
                                      failed="see 'bench lab init --help'"))
    lbsub = lb.add_subparsers(dest="lab_command", metavar="ACTION", parser_class=_Parser, required=True)
    li = lbsub.add_parser(
        "init", help="write a lab config skeleton from the serial ports and CAN interfaces of this computer",
        description="Write a lab config skeleton: one instrument entry per serial port found (its description, "
                    "VID:PID and stable /dev/serial/by-id path) and per CAN interface, the drivers to choose from, "
                    "commented sim sections, and the station name. Choose each driver (delete ports that are no "
                    "instrument), then run 'bench instruments check --config FILE' (docs/hardware.md).",
        epilog=epilog("bench lab init -o configs/lab.yaml --station gyro-lab-2", "bench lab init -o - | less",
                      ok="the skeleton was written", bad="the output exists (without --force) or cannot be written"))
    li.add_argument("-o", "--output", type=Path, default=Path("lab.yaml"),
                    help="config file to write, '-' for standard output (default: lab.yaml)")
    li.add_argument("--station", default=None, help="station name recorded in every run file (default: the host name)")
    add_force(li)

    if _wanted(only, "bench.cli_analysis"):
        from bench.cli_analysis import add_analysis_parsers

        add_analysis_parsers(sub)
    if _wanted(only, "bench.cli_catalog"):
        from bench.cli_catalog import add_catalog_parsers

        add_catalog_parsers(sub)
    if _wanted(only, "bench.cli_fleet"):
        from bench.cli_fleet import add_fleet_parser

        add_fleet_parser(sub)
    if _wanted(only, "bench.cli_web"):
        from bench.cli_web import add_serve_parser

        add_serve_parser(sub)
    if _wanted(only, "bench.cli_unit"):
        from bench.cli_unit import add_unit_parser

        add_unit_parser(sub)

    sk = sub.add_parser(
        "soak", help="run the procedure library back to back on the simulated lab with random faults",
        description="Run the procedure library back to back on the simulated lab, in virtual time, with faults injected "
                    "at random (Poisson) times, and check that nothing crashed, every file is readable, no row was lost "
                    "and every abort is explained (docs/reliability.md).",
        epilog=epilog("bench soak --config configs/sim.yaml --duration 24h --faults-per-hour 3",
                      "bench soak --config configs/sim.yaml --hours 0.5 --faults-per-hour 0.2/min --classes transient --json",
                      ok="nothing crashed, no file is unreadable, no row was lost, every abort is explained",
                      failed="a crash, an unreadable run file, lost rows or an unexplained abort (listed as problems)"))
    sk.add_argument("--config", type=Path, required=True, help="lab config YAML file of a simulated lab (required)")
    how_long = sk.add_mutually_exclusive_group(required=True)
    how_long.add_argument("--duration", metavar="DURATION", help="run time to soak for, with units: 24h, 90min, 2 d (virtual time; a bare number is hours)")
    how_long.add_argument("--hours", metavar="HOURS", help="run time to soak for in hours (virtual time); units are accepted too: 90min")
    sk.add_argument("--faults-per-hour", metavar="RATE", default="3/h",
                    help="mean injected faults per hour of run time; units are accepted: 0.1/min (default 3/h)")
    sk.add_argument("--seed", type=int, default=0, help="seed of the order, fault times, classes and parameters (default 0)")
    sk.add_argument("--runs-dir", type=Path, default=Path("runs/soak"), help="where the run files go (default: runs/soak/)")
    sk.add_argument("--procedures", type=Path, nargs="+", default=None,
                    help="procedure files (default: every procedures/*.yaml next to the config's directory)")
    sk.add_argument("--answers", type=Path, default=None, help="answers to operator prompts (default: procedures/answers/ci.yaml)")
    sk.add_argument("--classes", default=None, help="fault classes to draw from, e.g. transient or serial_unplug+disk_full (default: all)")
    sk.add_argument("--json", action="store_true", help="print the report as JSON")

    s = sub.add_parser("sim", help="simulated instruments", description="Simulated instruments for other processes.",
                       epilog=epilog("bench sim serve --config configs/sim.yaml", ok="see 'bench sim serve --help'",
                                     failed="see 'bench sim serve --help'"))
    ssub = s.add_subparsers(dest="sim_command", metavar="SIMCOMMAND", parser_class=_Parser)
    sv = ssub.add_parser(
        "serve", help="serve the config's simulated instruments to other processes (pseudo-terminals, Modbus TCP, SLCAN)",
        description="Serve the config's simulated instruments on the wall clock for other processes: serial ones on "
                    "pseudo-terminals, the chamber controller on Modbus TCP, the rate table's CAN bus through a simulated "
                    "SLCAN adapter, the logger as a SCPI socket. Prints every endpoint; Ctrl-C stops.",
        epilog=epilog("bench sim serve --config configs/sim.yaml",
                      "bench sim serve --config configs/sim.yaml --instrument tvac --instrument acs_board",
                      ok="stopped with Ctrl-C or SIGTERM",
                      bad="bad config, unknown --instrument, or its ports are taken (another 'bench sim serve'?)"))
    sv.add_argument("--config", type=Path, required=True, help="lab config YAML file whose 'sim' sections are served (required)")
    sv.add_argument("--instrument", action="append", help="only these instruments (repeatable; default: every one with a 'sim' section)")
    return p, only is None or sub.found  # type: ignore[attr-defined]


def main(argv: list[str] | None = None) -> int:
    parser = parser_for(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    if not args.debug:
        # drivers turn pymodbus's failures into typed errors; its own log lines would only repeat them
        logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
        logging.getLogger("can").setLevel(logging.CRITICAL)
    if args.command in _PLAIN_COMMANDS:
        console = _LazyConsole(stderr=False, highlight=False)
    else:
        from rich.console import Console

        console = Console(stderr=False, highlight=False)
    err = _LazyConsole(stderr=True, highlight=False)  # only ever asked to print
    if args.command != "run" and StartupSignals.current is not None:
        StartupSignals.current.uninstall()  # the other commands keep Python's own Ctrl-C (bench/__main__.py)
    try:
        if args.command == "run":
            guard = StartupSignals.install()  # stop signals until the runner's handlers: one line, no half-made file
            try:
                return cmd_run(args, console)
            finally:
                guard.uninstall()
        if args.command in ("validate", "plan"):
            from bench.cli_procedure import cmd_plan, cmd_validate

            return (cmd_validate if args.command == "validate" else cmd_plan)(args, console)
        if args.command == "watch":
            return cmd_watch(args, console)
        if args.command == "replay":
            from bench.replay.cli import cmd_replay

            return cmd_replay(args, console)
        if args.command == "inspect":
            return cmd_inspect(args, console)
        if args.command == "calibrate-bench":
            return cmd_calibrate_bench(args, console)
        if args.command == "instruments":
            if args.instruments_command == "kinds":
                return cmd_instruments_kinds(args, console)
            return cmd_instruments_check(args, console)
        if args.command == "lab":
            return cmd_lab_init(args, console)
        if args.command in ("calibrate", "import", "report", "diagnose"):
            from bench import cli_analysis

            return getattr(cli_analysis, f"cmd_{args.command}")(args, console)
        if args.command == "soak":
            from bench.cli_soak import cmd_soak

            return cmd_soak(args, console)
        if args.command == "sim" and args.sim_command == "serve":
            return cmd_sim_serve(args, console)
        if args.command == "serve":
            from bench.cli_web import cmd_serve

            return cmd_serve(args, console)
        if args.command == "unit":
            from bench.cli_unit import cmd_unit

            return cmd_unit(args, console)
        if args.command in ("runs", "catalog"):
            from bench.cli_catalog import cmd_catalog

            return cmd_catalog(args, console)
        if args.command == "fleet":
            from bench.cli_fleet import cmd_fleet

            return cmd_fleet(args, console)
        build_parser().print_help()  # every command's, not only the one asked for
        return EXIT_BAD_INPUT
    except InputErrors as exc:
        if args.debug:
            raise
        for e in exc.errors:
            err.print(e.one_line(), markup=False, soft_wrap=True)
        return EXIT_BAD_INPUT
    except InputError as exc:
        if args.debug:
            raise
        err.print(exc.one_line(), markup=False, soft_wrap=True)
        return EXIT_BAD_INPUT
    except KNOWN_ERRORS as exc:
        if (stop := stop_within(exc)) is not None:  # a library turned the stop signal into its own error
            return _stopped(err, stop)
        if args.debug:
            raise
        err.print(f"bench: {printable(exc)}", markup=False, soft_wrap=True)
        return EXIT_FAILED
    except StoppedDuringStartup as exc:
        return _stopped(err, exc)
    except KeyboardInterrupt:
        err.print("bench: interrupted")
        return EXIT_FAILED
    except BrokenPipeError:
        return stdout_gone()
    except Exception as exc:  # noqa: BLE001 - last line of defence: one line, not a traceback
        if (stop := stop_within(exc)) is not None:  # a library turned the stop signal into its own error
            return _stopped(err, stop)
        if args.debug:
            raise
        err.print(f"bench: internal error: {type(exc).__name__}: {printable(exc)} (run with --debug for the traceback)", markup=False,
                  soft_wrap=True)
        return EXIT_FAILED


def _stopped(err: Console | _LazyConsole, stop: StoppedDuringStartup) -> int:
    """The one line of a start-up stopped by a signal (``bench: stopped during start-up by …``)."""
    err.print(f"bench: {printable(stop)}", markup=False, soft_wrap=True)
    return EXIT_FAILED


def stdout_gone() -> int:
    """The reader of stdout went away (``bench runs --json | head -c 10``): stop quietly with exit
    code 1, as ``cat`` stops, instead of an internal error; stdout is pointed at /dev/null so that
    Python's own flush at exit does not complain about the pipe again."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # no real stdout (a test's capture)
        pass
    return EXIT_FAILED


# ---- run --------------------------------------------------------------------------------------
def cmd_run(args: argparse.Namespace, console: Console) -> int:
    from bench.cli_procedure import parse_params
    from bench.validate import load_checked
    from bench.procedure.estimate import run_file_bytes
    from bench.record import check_destination
    from bench.runner.operator import Operator
    from bench.runner.progress import RichProgress
    from bench.cli_catalog import run_catalog
    from bench.runner.session import start_run
    from bench.identity import utc_today
    from bench.runner.unit_identity import check_confirmable, overdue_calibrations, run_identity
    from rich.markup import escape

    if args.json:  # stdout carries the JSON object only; everything for people goes to stderr
        from rich.console import Console

        console = Console(stderr=True, highlight=False)
    procedure, config = load_checked(args.procedure, args.config, parse_params(args.param))
    args.sim = args.sim or config.mode == "sim"
    if args.realtime and not args.sim:
        raise InputError("--realtime only applies to simulated runs; add --sim", None, "--realtime")
    from bench import operators

    who = operators.resolve(args.operator, config.operators, origin=operators.cli_origin(), allowed_at=config.operators_location)
    operator = Operator.from_file(args.answers, Operator.terminal()) if args.answers else Operator(None, Operator.terminal())
    unanswerable = [s for s in procedure.steps if (s.type == "prompt" or (s.type == "vibrate" and not args.sim))
                    and not operator.can_answer(s.params.get("id") or s.name, args.sim)]
    if unanswerable:
        raise InputErrors([InputError(f"prompt {s.params.get('id') or s.name!r} needs an operator: run on a terminal or give --answers FILE",
                                      s.location, "prompt") for s in unanswerable])
    identity = run_identity(procedure, config, unit=args.unit, part=args.part, revision=args.revision, station=args.station)
    overdue = overdue_calibrations(config, procedure.instruments, utc_today())
    check_confirmable(overdue, operator, args.accept_overdue_calibration)
    for o in overdue:
        console.print(f"[bold yellow]warning:[/] {escape(o.describe())}", highlight=False)
    if args.sim:
        no_sim = [n for n in procedure.instruments if config.instruments[n].sim is None]
        if no_sim:
            raise InputErrors([
                InputError("has no 'sim' section, so it cannot be simulated (--sim)", config.instruments[n].location, n) for n in no_sim
            ])
    fault_spec = None
    if args.inject_faults is not None:
        from bench.faults import parse_fault_spec, plan_faults

        if not args.sim:
            raise InputError("faults can only be injected into simulated runs; add --sim", None, "--inject-faults")
        fault_spec = parse_fault_spec(args.inject_faults)
        # the faults' targets checked against this procedure's instruments before a run file exists
        plan_faults(fault_spec, {n: config.instruments[n].driver for n in procedure.instruments}, procedure.estimated_duration_s())
    if not args.sim:  # an absent port or CAN interface: said before anything is created, naming the instrument
        from bench.lab import check_ports

        check_ports(config, procedure.instruments)
    check_destination(args.runs_dir, run_file_bytes(procedure))

    progress = RichProgress(console, dry_run=args.sim)
    session = start_run(procedure, config, procedure_path=args.procedure, config_path=args.config, runs_dir=args.runs_dir,
                        sim=args.sim, realtime=args.realtime, operator=operator, progress=progress,
                        operator_name=who.name, operator_origin=who.origin, fault_spec=fault_spec, identity=identity,
                        overdue=overdue, accept_overdue=args.accept_overdue_calibration, catalog=run_catalog(args.catalog, config),
                        startup=StartupSignals.current)
    runner, lab, recorder = session.runner, session.lab, session.recorder
    state = {"signals": 0}

    # Signal handlers only set flags and leave messages: printing from a handler can interrupt the
    # terminal library in the middle of rendering (or of a lazy import) and break it.
    def on_pause(signum: int, _frame) -> None:
        runner.toggle_pause()
        progress.paused = runner.paused
        runner.notices.append(f"[bold yellow]{'pause' if runner.paused else 'resume'} requested ({signal.Signals(signum).name}); "
                              f"{'send it again to resume' if runner.paused else 'continuing'}[/]")

    def on_signal(signum: int, _frame) -> None:
        state["signals"] += 1
        name = signal.Signals(signum).name
        if state["signals"] == 1:
            runner.request_abort(f"{name} received (operator stop)")
            runner.notices.append(f"[bold yellow]{name}: stopping; instruments go to their safe state, data is kept[/]")
        elif state["signals"] == 2:
            runner.notices.append(f"[yellow]{name} again: the safe-state sequence is running and will not be skipped[/]")

    # SIGHUP (the terminal closed, the ssh session dropped) and every other terminating signal take
    # the same path as Ctrl-C
    old = {s: signal.signal(s, on_signal) for s in STOP_SIGNALS}
    if StartupSignals.current is not None and StartupSignals.current.signum is not None:
        on_signal(StartupSignals.current.signum, None)  # arrived between the run's start-up and these handlers
    pause_signals = [getattr(signal, n) for n in ("SIGUSR1", "SIGTSTP") if hasattr(signal, n)]
    old_pause = {s: signal.signal(s, on_pause) for s in pause_signals}
    try:
        result = runner.run()
    finally:
        lab.close()
        for s, h in old_pause.items():
            signal.signal(s, h)
        for s, h in old.items():
            # after an operator stop the process is on its way out: further signals are ignored, even
            # during interpreter shutdown (which would otherwise die of them)
            signal.signal(s, signal.SIG_IGN if state["signals"] else h)
    if session.catalog is not None:
        session.catalog.run_ended()  # the closed file's row: status, verdict, hash (a failure only warns)
    for text in runner.notices:
        console.print(text)
    _print_summary(console, result, recorder.path, args.sim and not args.realtime, "sim" if args.sim else "hardware")
    _print_next_commands(console, recorder.path, sensor_data=any(result.rows.values()))
    code = EXIT_OK if result.ok else EXIT_FAILED
    if args.json:
        import json

        print(json.dumps({"run_file": str(recorder.path), "exit_code": code, **result.as_json()}, indent=2))
    return code


def _print_summary(console: Console, result, path: Path, virtual: bool, mode: str) -> None:
    """The end of ``bench run``: steps, streams, checks (values and limits with units), times, the
    outcome; a run not on real instruments says so first and last (:mod:`bench.run_mode`)."""
    from rich.markup import escape
    from rich.text import Text

    from bench.inspect_view import OUTCOME_STYLE, banner_text, check_rows
    from bench.record.checks import check_from_result
    from bench.run_mode import is_evidence, mode_word
    from bench.termtable import fit_tables

    evidence = is_evidence(mode)
    rows = [[str(o.index + 1), o.name, o.type, Text(o.outcome, OUTCOME_STYLE.get(o.outcome, "white")), o.message] for o in result.outcomes]
    for t in fit_tables(["#", "step", "type", "outcome", "detail"], rows, console.width, title="Steps", prose=[1, 4]):
        console.print(t)
    for name, rows in result.rows.items():
        st = result.stream_stats.get(name, {})
        faults = [f"{st.get(k, 0):,} {what}" for k, what in (("crc_errors", "CRC errors"), ("dropped_frames", "dropped frames"),
                                                               ("garbage_bytes", "garbage bytes")) if st.get(k, 0)]
        console.print(f"stream {name}: {rows} rows; link: {', '.join(faults) if faults else 'clean'}", markup=False, highlight=False)
    if result.checks:
        headers, rows = check_rows([check_from_result(c, int(c.get("step", -1)), str(c["outcome"])) for c in result.checks],
                                   evidence=evidence)
        for ct in fit_tables(headers, rows, console.width, title="Checks", prose=[0, 2]):
            console.print(ct)
    speed = f", {result.run_time_s / max(result.wall_time_s, 1e-9):.0f}x real time" if virtual else ""
    console.print(f"run time {fmt_hms(result.run_time_s)} ({result.run_time_s:.1f} s) in {result.wall_time_s:.2f} s wall{speed}")
    console.print(f"run file: {path}", markup=False, highlight=False)
    loud = banner_text(mode)
    if result.status == "aborted":
        console.print(f"[bold red]ABORTED[/]: {escape(result.abort_reason)}")
    elif result.failed_steps:
        console.print(f"[bold red]FAILED[/]: {len(result.failed_steps)} step(s) failed: {escape(', '.join(o.name for o in result.failed_steps))}")
    elif evidence:
        console.print(f"[bold green]COMPLETED[/]: all steps done; {result.verdict}")
    else:
        console.print(f"[bold]COMPLETED ({mode_word(mode)})[/]: all steps done; {result.verdict}")
    if loud is not None:
        console.print(loud)


def next_commands(path: Path, *, sensor_data: bool) -> list[tuple[str, str]]:
    """The commands worth running on a finished run file ``path``, each with what it gives:
    inspect, report (next to the run, ``.html``), replay, and diagnose when the run recorded
    sensor data (a stream with rows)."""
    import shlex

    run = shlex.quote(str(path))
    out = [(f"bench inspect {run}", "summary: steps, checks, streams, events"),
           (f"bench report {run} -o {shlex.quote(str(path.with_suffix('.html')))}", "HTML report for the acceptance record"),
           (f"bench replay {run}", "re-run against the recorded instrument answers and compare")]
    if sensor_data:
        out.append((f"bench diagnose {run}", "what the sensor model misses"))
    return out


def _print_next_commands(console: Console, path: Path, *, sensor_data: bool) -> None:
    console.print("next:", markup=False)
    for command, what in next_commands(path, sensor_data=sensor_data):
        console.print(f"  {command}  # {what}", markup=False, highlight=False, soft_wrap=True)


# ---- watch ------------------------------------------------------------------------------------
def cmd_watch(args: argparse.Namespace, console: Console) -> int:
    from bench.watch import watch

    interval = quantity(args.interval, "s", "--interval")
    if not 0.05 <= interval <= 60:
        raise InputError("the refresh interval must be between 0.05 s and 60 s", None, "--interval")
    return watch(args.run_file, console, interval_s=interval, once=args.once)


# ---- inspect ----------------------------------------------------------------------------------
def cmd_inspect(args: argparse.Namespace, console: Console) -> int:
    from bench.record import read_run_summary, render_summary

    if args.events < 0:
        raise InputError(f"expected a number of events >= 0, got {args.events}", None, "--events")
    if args.verify:
        return _inspect_verify(args)
    summary = read_run_summary(args.run_file, traffic=args.traffic)
    if args.json:
        import json

        from bench.record.summary_json import summary_json

        print(json.dumps(summary_json(summary, max_events=args.events), indent=2))
        return EXIT_OK
    # texts of the file are data: render_summary shows their escape sequences and line breaks, never acts on them
    render_summary(summary, console, max_events=args.events, traffic=args.traffic)
    return EXIT_OK


def _inspect_verify(args: argparse.Namespace) -> int:
    """``bench inspect --verify``: exit 0 when every chunk verified, 1 when one is damaged or the
    file has no checksums, 2 (an InputError) when the file is unreadable."""
    from bench.record.verify import VERIFIED, render_verification, verification_json, verify_run_file

    check = verify_run_file(args.run_file)
    if args.json:
        import json

        print(json.dumps(verification_json(check), indent=2))
    else:
        print("\n".join(render_verification(check)))
    return EXIT_OK if check.status == VERIFIED else EXIT_FAILED


# ---- calibrate-bench --------------------------------------------------------------------------
def cmd_calibrate_bench(args: argparse.Namespace, console: Console) -> int:
    import json

    from bench.analysis.bench_speed_fit import fit_timings_file

    resolution = quantity(args.resolution, "s", "--resolution")
    if resolution < 0:
        raise InputError("the stopwatch resolution must be >= 0 s", None, "--resolution")
    steps = None
    if args.steps_per_deg is not None:
        steps = quantity(args.steps_per_deg, "1/deg", "--steps-per-deg")
        if not 0 < steps < 1e6:
            raise InputError("the steps per degree must be > 0", None, "--steps-per-deg")
    fit = fit_timings_file(args.timings, resolution, steps, args.axis)
    if args.json:
        print(json.dumps(fit.as_json(), indent=2))
        return EXIT_OK
    from rich.table import Table

    from bench.analysis.bench_speed_fit import GrblStepsFit

    if isinstance(fit, GrblStepsFit):
        t = Table(title=f"Stepper bench (GRBL) steps per degree from {args.timings} ({fit.rows} timings)")
        for col in ("rate deg/s", "repeats", "mean rotation time s", "std s", "true rate deg/s"):
            t.add_column(col, justify="right")
        for lv in fit.levels:
            t.add_row(f"{lv['rate_dps']:g}", str(lv["repeats"]), f"{lv['mean_time_s']:.3f}", f"{lv['std_time_s']:.3f}",
                      f"{lv['true_rate_dps']:.5f}")
        console.print(t)
        console.print(f"steps per degree {fit.steps_per_deg:.3f} ± {fit.u_steps_per_deg:.3f} (extended, k = {fit.coverage_factor:.3f}: "
                      f"{fit.u_steps_extended:.3f}); GRBL ran with {fit.set_steps_per_deg:g}: the table turned "
                      f"{abs(100 * fit.rate_error):.3f} % {'faster' if fit.rate_error > 0 else 'slower'} than commanded")
        console.print(f"u_A = {fit.u_a_s:.3f} s, u_B = {fit.u_b_stopwatch_s:.4f} s, u_C = {fit.u_c_s:.3f} s; largest residual {fit.largest_residual_s:.3f} s")
        console.print(f"set it: send {fit.command} to GRBL, and steps_per_deg: {fit.steps_per_deg:.3f} in the lab config", markup=False)
        return EXIT_OK

    t = Table(title=f"Stepper bench speed calibration from {args.timings} ({fit.rows} timings)")
    for col in ("n", "repeats", "mean rotation time s", "std s", "speed deg/s", "fit speed deg/s"):
        t.add_column(col, justify="right")
    from drivers.stepper_speed import BenchSpeedCalibration

    cal = BenchSpeedCalibration(fit.k, fit.b_s_per_rad)
    for lv in fit.levels:
        t.add_row(f"{lv['n']:g}", str(lv["repeats"]), f"{lv['mean_time_s']:.3f}", f"{lv['std_time_s']:.3f}",
                  f"{lv['speed_dps']:.4f}", f"{cal.speed_for_n(lv['n']):.4f}")
    console.print(t)
    console.print(f"n = k·(1/v − b), 1/v in s/rad:  k = {fit.k:.4f} ± {fit.u_k:.4f},  b = {fit.b_s_per_rad:.4f} ± {fit.u_b:.4f} s/rad")
    console.print(f"u_A = {fit.u_a_s:.3f} s, u_B = {fit.u_b_stopwatch_s:.4f} s, u_C = {fit.u_c_s:.3f} s")
    console.print(f"speed uncertainty {fit.u_speed_dps:.4f} deg/s (extended, k = {fit.coverage_factor:.3f}: {fit.u_speed_extended_dps:.3f} deg/s); "
                  f"n uncertainty {fit.u_n:.2f} (extended {fit.u_n_extended:.2f})")
    return EXIT_OK


def cmd_instruments_check(args: argparse.Namespace, console: Console) -> int:
    """One line per instrument: ``NAME: ok (identity; reading) [transport endpoint]`` or
    ``NAME: PROBLEM [transport endpoint] → what to do``; exit 1 if any instrument failed."""
    from rich.text import Text

    from bench.config import load_config
    from bench.instruments_check import check_instruments

    config = load_config(args.config)
    sim = args.sim or config.mode == "sim"
    console.print(f"{config.name} ({'simulated' if sim else 'hardware'}), {len(config.instruments)} instrument(s):", markup=False)
    rows = check_instruments(config, sim=sim)
    for r in rows:
        line = Text.assemble((r.instrument, "bold"), ": ", (r.status, "green" if r.ok else "red"))
        if r.ok:
            line.append(f" ({'; '.join(x for x in (r.identity, r.reading) if x)})")
        line.append(f" [{r.transport}" + ("]" if r.endpoint in r.status else f" {r.endpoint}]"), "dim")
        if r.hint:
            line.append(f" → {r.hint}")
        console.print(line, soft_wrap=True)
    bad = [r.instrument for r in rows if not r.ok]
    if bad:
        console.print(f"{len(bad)} of {len(rows)} instrument(s) not responding: {', '.join(bad)}", markup=False, soft_wrap=True)
        return EXIT_FAILED
    console.print(f"all {len(rows)} instrument(s) identified and responding", markup=False)
    return EXIT_OK


def cmd_instruments_kinds(args: argparse.Namespace, console: Console) -> int:
    """The installed kinds (bench.kinds.registry): one line each, what could not be loaded after."""
    import json

    from bench.kinds import registry

    reg = registry.rediscover()  # afresh: this is the command that says what is installed
    if args.json:
        print(json.dumps({"kinds": {k.name: {"package": k.package, "summary": k.summary, "simulator": k.sim is not None,
                                             "streams": k.streams, "steps": [d.type for d in k.steps],
                                             "signals": {s.shown: s.units for s in k.signals}, "docs": k.docs}
                                    for k in reg.kinds.values()},
                          "not_loaded": reg.problems}, indent=2))
        return EXIT_FAILED if reg.problems else EXIT_OK
    console.print(f"{len(reg.kinds)} instrument kind(s) installed (entry-point group {registry.GROUP}):", markup=False)
    for k in reg.kinds.values():
        extras = [f"steps: {', '.join(d.type for d in k.steps)}" if k.steps else "",
                  "simulator" if k.sim is not None else "no simulator",
                  f"signals: {', '.join(f'{s.shown} ({s.units or 1})' for s in k.signals)}" if k.signals else ""]
        console.print(f"{k.name} ({k.package}): {k.summary}; " + "; ".join(e for e in extras if e), markup=False, soft_wrap=True)
    for key, why in reg.problems.items():
        console.print(f"NOT LOADED {key}: {why}", markup=False, soft_wrap=True)
    return EXIT_FAILED if reg.problems else EXIT_OK


def cmd_lab_init(args: argparse.Namespace, console: Console) -> int:
    """Write the lab config skeleton (:mod:`bench.lab_init`) to ``-o`` (``-`` for stdout)."""
    from bench import instruments_check, lab_init
    from bench.cli_common import check_output
    from bench.outputs import output_file

    to_stdout = str(args.output) == "-"
    if not to_stdout:
        check_output(args.output, "-o", force=args.force)
    ports, cans = instruments_check.list_serial_ports(), lab_init.can_interfaces()
    text = lab_init.skeleton(ports, cans, args.station if args.station is not None else lab_init.default_station())
    if to_stdout:
        sys.stdout.write(text)
        return EXIT_OK
    with output_file(args.output, "-o", force=args.force) as tmp:
        tmp.write_text(text, encoding="utf-8")
    found = f"{len(ports)} serial port(s), {len(cans)} CAN interface(s)"
    console.print(f"wrote {args.output} ({found}); next: choose each driver in it, then", markup=False, soft_wrap=True)
    console.print(f"  bench instruments check --config {args.output}", markup=False, soft_wrap=True)
    return EXIT_OK


# ---- sim serve --------------------------------------------------------------------------------
def _refuse_taken_ports(config, names: list[str], path: Path) -> None:
    """:class:`InputError` (exit 2) when a TCP port the served simulators listen on is taken (by
    another 'bench sim serve' on the same config, or any program): checked before any starts."""
    from bench.kinds import registry

    for name in names:
        inst = config.instruments[name]
        if inst.sim is None or not inst.kind.sim.tcp_ports:
            continue
        for port, kind in registry.load(inst.kind.sim.tcp_ports)(inst.sim):
            _refuse_taken_port(port, kind, name, path)


def _refuse_taken_port(port: int, kind: str, name: str, path: Path) -> None:
    import errno
    import socket

    if port:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the servers bind: TIME_WAIT is no obstacle
            try:
                probe.bind(("127.0.0.1", port))
            except OSError as exc:
                why = "is in use (another 'bench sim serve'?)" if exc.errno == errno.EADDRINUSE else f"cannot be bound: {exc.strerror}"
                raise InputError(f"{path}: {name}: {kind} port {port} {why}", None, "--config") from None


def cmd_sim_serve(args: argparse.Namespace, console: Console) -> int:
    from bench.clock import WallClock
    from bench.config import load_config
    from bench.sim.factory import build_devices
    from bench.sim.pty_server import close_endpoints, open_endpoint, serve

    config = load_config(args.config)
    names = args.instrument or [n for n, i in config.instruments.items() if i.sim is not None]
    unknown = [n for n in names if n not in config.instruments]
    if unknown:
        raise InputError(f"no instrument {unknown[0]!r} in {args.config} (has: {', '.join(config.instruments)})", None, "--instrument")
    _refuse_taken_ports(config, names, args.config)
    clock = WallClock()
    try:
        sims = build_devices(config, clock, names, fixed_ports=True)
    except ValueError as exc:
        raise InputError(str(exc)) from None
    except OSError as exc:
        raise InputError(f"cannot start a simulated server: {exc} (is another 'bench sim serve' running?)", None, "--config") from None
    endpoints = []
    stop = {"flag": False}

    def on_signal(signum: int, _frame) -> None:
        stop["flag"] = True

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        for name, sim in sims.items():
            for transport, address in sim.endpoints:
                print(f"{name}: {transport} {address}", flush=True)
            for sub, dev in sim.serial.items():
                ep = open_endpoint(name if not sub else f"{name}.{sub}", dev)
                endpoints.append(ep)
                print(f"{ep.name}: serial {ep.path}", flush=True)
        print(f"serving {len(sims)} simulated instrument(s) on the wall clock; Ctrl-C to stop (pid {os.getpid()})", file=sys.stderr, flush=True)
        serve(endpoints, clock, lambda: stop["flag"])
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        close_endpoints(endpoints)
        for sim in sims.values():
            sim.close()
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
