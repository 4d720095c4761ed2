"""Replay speed of a long recorded thermal ramp (the replay issue's benchmark).

Records an H-hour dry-run of a thermal ramp on the whole simulated lab (the board streaming at
100 Hz, four instruments polled at 1 Hz; the workload of benchmarks/bench_thermal_ramp.py), then
replays it in-process and reports simulated seconds per wall second (and per CPU second: other
processes' load inflates wall time) of:

* the replay proper, ``bench replay --no-board-check``: the recording loaded, the run re-executed
  against the recorded answers, recorded and compared (target >= 2000x, issue 19);
* ``bench replay`` as it runs by default: the same plus the check of the board's samples against a
  re-simulation of the dry-run (a second whole-lab dry-run, docs/replay.md), so it cannot be faster
  than the dry-run;

each as a ratio to the dry-run that recorded it (the baseline, measured in the same run). The
transports are the dry-run's default (in-process); ``--socket`` also replays over the socket
transports (``BENCH_DRYRUN_TRANSPORT=socket``).

    python benchmarks/bench_replay.py [--hours 8] [--socket] [--json]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import logging
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PROCEDURE = """schema: bench-procedure/1
name: thermal_ramp_replay_bench
instruments: [acs_board, tvac, thermocouples, rate_table, stepper_bench]
steps:
  - power: {{instrument: acs_board, on: true}}
  - configure: {{instrument: acs_board, odr: 100 Hz, moving_average: 1}}
  - set_temperature: {{instrument: tvac, set_point: 66 degC, ramp: 0.2 degC/min}}
  - record: {{instrument: acs_board, duration: {hours} h, window: ramp}}
  - set_temperature: {{instrument: tvac, set_point: 20 degC}}
"""


def timed(what) -> tuple[object, float, float]:
    """``what()``, its wall time (s) and its CPU time (s) of this process."""
    w0, c0 = time.perf_counter(), time.process_time()
    out = what()
    return out, time.perf_counter() - w0, time.process_time() - c0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=8.0)
    ap.add_argument("--socket", action="store_true", help="also replay over the socket transports")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    for name in ("pymodbus", "can", "canopen"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
    from bench.cli import main as bench_main
    from bench.lab import DRYRUN_TRANSPORT_ENV
    from bench.replay import replay
    import bench.cli_procedure  # noqa: F401 - imported before the timings: the command's own imports are not its speed
    import bench.runner.session  # noqa: F401

    out: dict = {"hours": args.hours}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        proc = tmp / "ramp.yaml"
        proc.write_text(PROCEDURE.format(hours=args.hours))
        warm = tmp / "warm-up.yaml"
        warm.write_text(PROCEDURE.format(hours=60 / 3600))
        with contextlib.redirect_stdout(io.StringIO()):  # the run's own summary is not this benchmark's output
            # an untimed minute of the same lab first: the instruments' drivers and simulators are
            # imported when a run first opens them (docs/instruments.md), and imports are not speed
            bench_main(["run", str(warm), "--config", str(ROOT / "configs" / "sim.yaml"), "--runs-dir", str(tmp / "warm-up")])
            rc, wall, cpu = timed(lambda: bench_main(["run", str(proc), "--config", str(ROOT / "configs" / "sim.yaml"),
                                                     "--runs-dir", str(tmp / "runs")]))
        if rc != 0:
            raise SystemExit(f"the dry-run failed (exit {rc})")
        (run_file,) = (tmp / "runs").glob("*.h5")
        cases = [("replay", "inprocess", False), ("replay_with_board_check", "inprocess", True)]
        if args.socket:
            cases.append(("replay_socket", "socket", False))
        sim_s = None
        for key, transport, check in cases:
            os.environ[DRYRUN_TRANSPORT_ENV] = transport
            try:
                result, r_wall, r_cpu = timed(lambda: replay(run_file, runs_dir=tmp / f"replays-{key}", check_board=check))
            finally:
                os.environ.pop(DRYRUN_TRANSPORT_ENV, None)
            sim_s = result.run_time_s
            out[key] = {"transport": transport, "board_check": check, "wall_s": r_wall, "cpu_s": r_cpu, "speed": sim_s / r_wall,
                        "cpu_speed": sim_s / r_cpu, "matches": result.ok, "commands": result.commands}
        out["simulated_s"] = sim_s
        out["dry_run"] = {"wall_s": wall, "cpu_s": cpu, "speed": sim_s / wall, "cpu_speed": sim_s / cpu}
        for key, *_ in cases:
            out[key]["vs_dry_run"] = out[key]["speed"] / out["dry_run"]["speed"]
            out[key]["cpu_vs_dry_run"] = out[key]["cpu_speed"] / out["dry_run"]["cpu_speed"]
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        dr = out["dry_run"]
        print(f"{args.hours:g} h thermal ramp ({sim_s:.0f} s simulated); baseline, the dry-run that recorded it: "
              f"{dr['wall_s']:.1f} s wall = {dr['speed']:.0f}x ({dr['cpu_speed']:.0f}x per CPU s)")
        for key, *_ in cases:
            r = out[key]
            print(f"{key:26s} {r['wall_s']:7.1f} s wall = {r['speed']:6.0f}x ({r['cpu_speed']:6.0f}x per CPU s), "
                  f"{r['vs_dry_run']:.2f} of the dry-run's speed; {r['commands']} commands, match: {r['matches']}")
    return 0 if all(out[k]["matches"] for k, *_ in cases) else 1


if __name__ == "__main__":
    raise SystemExit(main())
