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

from rich.console import Console
from rich.table import Table

from bench import __version__
from bench.errors import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_OK, KNOWN_ERRORS, InputError, InputErrors


class _Parser(argparse.ArgumentParser):
    """argparse that reports usage errors as one line and exit code 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="bench", description="Ground-support test benches for spacecraft attitude sensors.")
    p.add_argument("--version", action="version", version=f"bench {__version__}")
    p.add_argument("--debug", action="store_true", help="show tracebacks of errors")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    r = sub.add_parser("run", help="run a procedure (real instruments unless --sim)")
    r.add_argument("procedure", type=Path, help="procedure YAML file")
    r.add_argument("--config", type=Path, required=True, help="lab config YAML file")
    r.add_argument("--sim", action="store_true", help="simulated instruments behind the same drivers (virtual time)")
    r.add_argument("--realtime", action="store_true", help="with --sim: run at wall-clock pace")
    r.add_argument("--runs-dir", type=Path, default=Path("runs"), help="where run files go (default: runs/)")
    r.add_argument("--operator", default=None, help="operator name recorded in the run file (default: login name)")
    r.add_argument("-p", "--param", action="append", metavar="NAME=VALUE", help="override a procedure parameter, e.g. -p cold=-20degC")
    r.add_argument("--answers", type=Path, default=None, help="YAML file answering the procedure's operator prompts (id: yes)")
    r.add_argument("--inject-faults", metavar="SPEC", default=None,
                   help="with --sim: inject faults through the simulators, e.g. 'rate=6/h,seed=1' or 'serial_unplug@300s' (docs/reliability.md)")

    v = sub.add_parser("validate", help="check a procedure (and its limits against a lab config) without running it")
    v.add_argument("procedure", type=Path)
    v.add_argument("--config", type=Path, default=None, help="lab config: instrument names, drivers and this lab's limits")
    v.add_argument("-p", "--param", action="append", metavar="NAME=VALUE", help="override a procedure parameter")

    pl = sub.add_parser("plan", help="the expanded step list of a procedure with estimated durations")
    pl.add_argument("procedure", type=Path)
    pl.add_argument("--config", type=Path, default=None, help="lab config to validate against")
    pl.add_argument("-p", "--param", action="append", metavar="NAME=VALUE", help="override a procedure parameter")

    w = sub.add_parser("watch", help="live view of a run in progress (reads the run file)")
    w.add_argument("run_file", type=Path)
    w.add_argument("--interval", default="1 s", help="refresh interval (default '1 s')")
    w.add_argument("--once", action="store_true", help="print one snapshot and exit")

    from bench.replay.cli import add_replay_parser

    add_replay_parser(sub)

    i = sub.add_parser("inspect", help="summarise a run file (also while it is being written)")
    i.add_argument("run_file", type=Path)
    i.add_argument("--events", type=int, default=40, help="how many of the last events to list (default 40)")

    c = sub.add_parser("calibrate-bench", help="fit the stepper bench speed calibration n = k(1/v - b) from rotation timings")
    c.add_argument("timings", type=Path, help="CSV with columns n, rotation_time_s (repeated rows per n)")
    c.add_argument("--resolution", default="0.01 s", help="stopwatch resolution (default '0.01 s', ESTCube-2 section 3.2.2)")
    c.add_argument("--json", action="store_true", help="print a JSON object instead of a table")

    ic = sub.add_parser("instruments", help="instrument housekeeping")
    icsub = ic.add_subparsers(dest="instruments_command", metavar="ACTION", parser_class=_Parser, required=True)
    chk = icsub.add_parser("check", help="identify every instrument of a config and read one value from each")
    chk.add_argument("--config", type=Path, required=True, help="lab config YAML file")
    chk.add_argument("--sim", action="store_true", help="check the simulators behind the drivers (implied by 'mode: sim' in the config)")

    from bench.cli_analysis import add_analysis_parsers

    add_analysis_parsers(sub)

    sk = sub.add_parser("soak", help="run the procedure library back to back on the simulated lab with random faults")
    sk.add_argument("--config", type=Path, required=True, help="lab config YAML file (simulated lab)")
    sk.add_argument("--hours", type=float, required=True, help="run time to soak for (h of virtual time)")
    sk.add_argument("--faults-per-hour", type=float, default=3.0, help="mean injected faults per hour of run time (default 3)")
    sk.add_argument("--seed", type=int, default=0, help="seed of the order, fault times, classes and parameters (default 0)")
    sk.add_argument("--runs-dir", type=Path, default=Path("runs/soak"), help="where the run files go (default: runs/soak/)")
    sk.add_argument("--procedures", type=Path, nargs="+", default=None,
                    help="procedure files (default: every procedures/*.yaml next to the config's directory)")
    sk.add_argument("--answers", type=Path, default=None, help="answers to operator prompts (default: procedures/answers/ci.yaml)")
    sk.add_argument("--classes", default=None, help="fault classes to draw from, e.g. transient or serial_unplug+disk_full (default: all)")
    sk.add_argument("--json", action="store_true", help="print the report as JSON")

    s = sub.add_parser("sim", help="simulated instruments")
    ssub = s.add_subparsers(dest="sim_command", metavar="SIMCOMMAND", parser_class=_Parser)
    sv = ssub.add_parser("serve", help="serve the config's simulated serial instruments on pseudo-terminals")
    sv.add_argument("--config", type=Path, required=True)
    sv.add_argument("--instrument", action="append", help="only these instruments (repeatable)")
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not args.debug:
        # drivers turn pymodbus's failures into typed errors; its own log lines would only repeat them
        logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
        logging.getLogger("can").setLevel(logging.CRITICAL)
    console = Console(stderr=False, highlight=False)
    err = Console(stderr=True, highlight=False)
    try:
        if args.command == "run":
            return cmd_run(args, console)
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
            return cmd_instruments_check(args, console)
        if args.command in ("calibrate", "import", "report", "diagnose"):
            from bench import cli_analysis

            return getattr(cli_analysis, f"cmd_{args.command}")(args, console)
        if args.command == "soak":
            from bench.cli_soak import cmd_soak

            return cmd_soak(args, console)
        if args.command == "sim" and args.sim_command == "serve":
            return cmd_sim_serve(args, console)
        parser.print_help()
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
        if args.debug:
            raise
        err.print(f"bench: {exc}", markup=False, soft_wrap=True)
        return EXIT_FAILED
    except KeyboardInterrupt:
        err.print("bench: interrupted")
        return EXIT_FAILED
    except Exception as exc:  # noqa: BLE001 - last line of defence: one line, not a traceback
        if args.debug:
            raise
        err.print(f"bench: internal error: {type(exc).__name__}: {exc} (run with --debug for the traceback)", markup=False, soft_wrap=True)
        return EXIT_FAILED


# ---- run --------------------------------------------------------------------------------------
def cmd_run(args: argparse.Namespace, console: Console) -> int:
    from bench.cli_procedure import parse_params
    from bench.validate import load_checked
    from bench.record import check_destination
    from bench.runner.operator import Operator
    from bench.runner.progress import RichProgress
    from bench.runner.session import start_run

    procedure, config = load_checked(args.procedure, args.config, parse_params(args.param))
    args.sim = args.sim or config.mode == "sim"
    if args.realtime and not args.sim:
        raise InputError("--realtime only applies to simulated runs; add --sim", None, "--realtime")
    operator = Operator.from_file(args.answers, Operator.terminal()) if args.answers else Operator(None, Operator.terminal())
    unanswerable = [s for s in procedure.steps if (s.type == "prompt" or (s.type == "vibrate" and not args.sim))
                    and not operator.can_answer(s.params.get("id") or s.name, args.sim)]
    if unanswerable:
        raise InputErrors([InputError(f"prompt {s.params.get('id') or s.name!r} needs an operator: run on a terminal or give --answers FILE",
                                      s.location, "prompt") for s in unanswerable])
    if args.sim:
        no_sim = [n for n in procedure.instruments if config.instruments[n].sim is None]
        if no_sim:
            raise InputErrors([
                InputError("has no 'sim' section, so it cannot be simulated (--sim)", config.instruments[n].location, n) for n in no_sim
            ])
    fault_spec = None
    if args.inject_faults is not None:
        from bench.faults import parse_fault_spec

        if not args.sim:
            raise InputError("faults can only be injected into simulated runs; add --sim", None, "--inject-faults")
        fault_spec = parse_fault_spec(args.inject_faults)
    check_destination(args.runs_dir, _estimate_bytes(procedure))

    session = start_run(procedure, config, procedure_path=args.procedure, config_path=args.config, runs_dir=args.runs_dir,
                        sim=args.sim, realtime=args.realtime, operator=operator, progress=RichProgress(console),
                        operator_name=args.operator, fault_spec=fault_spec)
    runner, lab, recorder = session.runner, session.lab, session.recorder
    state = {"signals": 0}

    # Signal handlers only set flags and leave messages: printing from a handler can interrupt the
    # terminal library in the middle of rendering (or of a lazy import) and break it.
    def on_pause(signum: int, _frame) -> None:
        runner.toggle_pause()
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

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
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
    for text in runner.notices:
        console.print(text)
    _print_summary(console, result, recorder.path, args.sim and not args.realtime)
    return EXIT_OK if result.ok else EXIT_FAILED


def _estimate_bytes(procedure) -> int:
    """Rough run-file size: 38 float-ish values per sample at 1 kHz for the recording time, 8 B each."""
    return int(procedure.estimated_duration_s() * 1000 * 20 * 8) + 1_000_000


def _print_summary(console: Console, result, path: Path, virtual: bool) -> None:
    colours = {"passed": "green", "done": "green", "failed": "red", "aborted": "red"}
    t = Table(title="Steps", show_lines=False)
    for col in ("#", "step", "type", "outcome", "detail"):
        t.add_column(col)
    for o in result.outcomes:
        c = colours.get(o.outcome, "white")
        t.add_row(str(o.index + 1), o.name, o.type, f"[{c}]{o.outcome}[/]", o.message)
    console.print(t)
    for name, rows in result.rows.items():
        st = result.stream_stats.get(name, {})
        console.print(f"stream {name}: {rows} rows; link: {st.get('crc_errors', 0)} CRC errors, {st.get('dropped_frames', 0)} dropped frames, {st.get('garbage_bytes', 0)} garbage bytes")
    if result.checks:
        ct = Table(title="Checks")
        for col in ("check", "signal", "statistic", "window", "value", "limits", "outcome"):
            ct.add_column(col)
        for c in result.checks:
            lim = f"[{'' if c['min'] is None else format(c['min'], 'g')}, {'' if c['max'] is None else format(c['max'], 'g')}]"
            colour = "green" if c["outcome"] == "passed" else "red"
            ct.add_row(c["name"], c["signal"], c["statistic"], c["window"], f"{c['value']:.6g}", lim, f"[{colour}]{c['outcome']}[/]")
        console.print(ct)
    speed = f", {result.run_time_s / max(result.wall_time_s, 1e-9):.0f}x real time" if virtual else ""
    console.print(f"run time {result.run_time_s:.1f} s in {result.wall_time_s:.2f} s wall{speed}")
    console.print(f"run file: {path}")
    if result.status == "aborted":
        console.print(f"[bold red]ABORTED[/]: {result.abort_reason}")
    elif result.failed_steps:
        console.print(f"[bold red]FAILED[/]: {len(result.failed_steps)} step(s) failed: {', '.join(o.name for o in result.failed_steps)}")
    else:
        console.print("[bold green]COMPLETED[/]: all steps done, all checks passed")


# ---- watch ------------------------------------------------------------------------------------
def cmd_watch(args: argparse.Namespace, console: Console) -> int:
    from bench.units import to_units
    from bench.watch import watch

    interval = to_units(args.interval, "s", None, "--interval")
    if not 0.05 <= interval <= 60:
        raise InputError("the refresh interval must be between 0.05 s and 60 s", None, "--interval")
    return watch(args.run_file, console, interval_s=interval, once=args.once)


# ---- inspect ----------------------------------------------------------------------------------
def cmd_inspect(args: argparse.Namespace, console: Console) -> int:
    from bench.record import read_run_summary, render_summary

    summary = read_run_summary(args.run_file)
    render_summary(summary, console, max_events=args.events)
    return EXIT_OK


# ---- calibrate-bench --------------------------------------------------------------------------
def cmd_calibrate_bench(args: argparse.Namespace, console: Console) -> int:
    import json

    from bench.analysis.bench_speed_fit import fit_timings_file
    from bench.units import to_units

    resolution = to_units(args.resolution, "s", None, "--resolution")
    if resolution < 0:
        raise InputError("the stopwatch resolution must be >= 0 s", None, "--resolution")
    fit = fit_timings_file(args.timings, resolution)
    if args.json:
        print(json.dumps(fit.as_json(), indent=2))
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
    from bench.config import load_config
    from bench.instruments_check import check_instruments

    config = load_config(args.config)
    sim = args.sim or config.mode == "sim"
    rows = check_instruments(config, sim=sim)
    table = Table(title=f"{config.name} ({'simulated' if sim else 'hardware'})")
    for col in ("instrument", "transport", "endpoint", "identity", "reading", "status"):
        table.add_column(col, overflow="fold")
    for r in rows:
        table.add_row(r.instrument, r.transport, r.endpoint, r.identity, r.reading, r.status if r.ok else f"[red]{r.status}[/red]")
    console.print(table)
    bad = [r.instrument for r in rows if not r.ok]
    if bad:
        console.print(f"{len(bad)} of {len(rows)} instrument(s) not responding: {', '.join(bad)}")
        return EXIT_FAILED
    console.print(f"all {len(rows)} instrument(s) identified and responding")
    return EXIT_OK


# ---- sim serve --------------------------------------------------------------------------------
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
