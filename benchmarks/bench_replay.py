"""Replay speed of a long recorded thermal ramp (the replay issue's benchmark).

Records an H-hour dry-run of a thermal ramp on the whole simulated lab (the board streaming at
100 Hz, four instruments polled at 1 Hz; the workload of benchmarks/bench_thermal_ramp.py), then
replays it with ``bench replay`` in-process and reports simulated seconds per wall second of the
replay (target >= 1000x) and its ratio to the dry-run's own speed measured in the same run.

    python benchmarks/bench_replay.py [--hours 8] [--json]
"""

from __future__ import annotations

import argparse
import json
import logging
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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=8.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    for name in ("pymodbus", "can", "canopen"):
        logging.getLogger(name).setLevel(logging.CRITICAL)
    from bench.cli import main as bench_main
    from bench.replay import replay

    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        proc = tmp / "ramp.yaml"
        proc.write_text(PROCEDURE.format(hours=args.hours))
        t0 = time.monotonic()
        rc = bench_main(["run", str(proc), "--config", str(ROOT / "configs" / "sim.yaml"), "--runs-dir", str(tmp / "runs")])
        record_wall = time.monotonic() - t0
        if rc != 0:
            raise SystemExit(f"the dry-run failed (exit {rc})")
        (run_file,) = (tmp / "runs").glob("*.h5")
        t0 = time.monotonic()
        result = replay(run_file, runs_dir=tmp / "replays")
        replay_wall = time.monotonic() - t0
    sim_s = result.run_time_s
    out = {"hours": args.hours, "simulated_s": sim_s, "dry_run_wall_s": record_wall, "dry_run_speed": sim_s / record_wall,
           "replay_wall_s": replay_wall, "replay_speed": sim_s / replay_wall, "replay_vs_dry_run": record_wall / replay_wall,
           "replay_matches": result.ok, "commands": result.commands}
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print(f"{args.hours:g} h thermal ramp, {result.commands} commands: dry-run {record_wall:.1f} s wall ({out['dry_run_speed']:.0f}x), "
              f"replay {replay_wall:.1f} s wall ({out['replay_speed']:.0f}x, {out['replay_vs_dry_run']:.2f} of the dry-run's time inverse), "
              f"match: {result.ok}")
    return 0 if result.ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
