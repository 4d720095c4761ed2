"""Dry-run speed and memory of a long thermal ramp on the whole simulated lab.

Workload (the instruments issue's benchmark): the chamber ramps +20 → +66 °C at 0.2 °C/min (the
vacuum rate of NPSAT1 FL2-1a) while the sensor board streams at 100 Hz into the run file and the
other four instruments (chamber, thermocouple logger, rate table, stepper bench) are polled at
1 Hz, for H simulated hours — through the real CLI, drivers, transports, runner and recorder.

Baseline in the same run: the same procedure with the board alone (no polled instruments), so the
ratio is the cost of polling four instruments over their real transports at 1 Hz. Memory: the
peak RSS of each run (a separate process) for two lengths, to show it is flat in run length.

    python benchmarks/bench_thermal_ramp.py [--hours 8] [--short-hours 2] [--json]
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

PROCEDURE = """schema: bench-procedure/1
name: thermal_ramp_bench
instruments: {instruments}
steps:
  - power: {{instrument: acs_board, on: true}}
  - configure: {{instrument: acs_board, odr: 100 Hz, moving_average: 1}}
  - set_temperature: {{instrument: tvac, set_point: 66 degC, ramp: 0.2 degC/min}}
  - record: {{instrument: acs_board, duration: {hours} h, window: ramp}}
  - set_temperature: {{instrument: tvac, set_point: 20 degC}}
"""

CHILD = """
import resource, sys
from bench.cli import main
rc = main(sys.argv[1:])
print(f"PEAK_RSS_KB {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}")
sys.exit(rc)
"""


def run(instruments: list[str], hours: float, tmp: Path) -> dict:
    proc = tmp / f"ramp_{len(instruments)}_{hours:g}.yaml"
    proc.write_text(PROCEDURE.format(instruments="[" + ", ".join(instruments) + "]", hours=hours))
    out = subprocess.run([sys.executable, "-c", CHILD, "run", str(proc), "--config", str(ROOT / "configs" / "sim.yaml"),
                          "--runs-dir", str(tmp / "runs")], cwd=ROOT, capture_output=True, text=True, timeout=7200)
    text = out.stdout + out.stderr
    m = re.search(r"run time ([\d.]+) s in ([\d.]+) s wall", text)
    rss = re.search(r"PEAK_RSS_KB (\d+)", text)
    if out.returncode != 0 or m is None or rss is None:
        raise SystemExit(f"run failed ({out.returncode}):\n{text[-3000:]}")
    sim_s, wall_s = float(m.group(1)), float(m.group(2))
    return {"instruments": instruments, "hours": hours, "sim_s": sim_s, "wall_s": wall_s, "speed": sim_s / wall_s,
            "peak_rss_mb": int(rss.group(1)) / 1024}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=8.0)
    ap.add_argument("--short-hours", type=float, default=2.0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    lab = ["acs_board", "tvac", "thermocouples", "rate_table", "stepper_bench"]
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        full = run(lab, args.hours, tmp)
        short = run(lab, args.short_hours, tmp)
        board = run(["acs_board", "tvac"], args.hours, tmp)  # tvac only for the set point; polled too
    result = {"full_lab": full, "full_lab_short": short, "baseline_board_and_chamber": board,
              "speed_ratio_vs_baseline": full["speed"] / board["speed"],
              "memory_ratio_long_vs_short": full["peak_rss_mb"] / short["peak_rss_mb"]}
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    for name, r in (("full lab", full), ("full lab (short)", short), ("baseline: board + chamber", board)):
        print(f"{name:26s} {r['hours']:4g} h simulated in {r['wall_s']:7.1f} s wall = {r['speed']:6.0f}x real time, peak RSS {r['peak_rss_mb']:6.0f} MB")
    print(f"full lab vs baseline speed: {result['speed_ratio_vs_baseline']:.2f}; peak memory {args.hours:g} h vs {args.short_hours:g} h: "
          f"{result['memory_ratio_long_vs_short']:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
