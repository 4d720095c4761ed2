"""Dry-run speed and memory of a long thermal ramp on the whole simulated lab.

Workload (the instruments issue's benchmark): the chamber ramps +20 → +66 °C at 0.2 °C/min (the
vacuum rate of NPSAT1 FL2-1a) while the sensor board streams at 100 Hz into the run file and the
other four instruments (chamber, thermocouple logger, rate table, stepper bench) are polled at
1 Hz, for H simulated hours — through the real CLI, drivers, transports, runner and recorder, each
run in a process of its own.

Baseline in the same run (issue 19): the board-alone dry-run (the same recording with the sensor
board only, nothing polled), so the ratio is what polling four instruments over their transports
costs. Also measured: the whole lab at every length of ``--lengths`` (speed against run length:
it must not fall) with each run's peak RSS (the ratio ``--hours`` / ``--short-hours`` must stay
<= 1.05; given for the whole process and until the run ended, before ``bench run`` catalogues
the file), and, with ``--socket``, the whole lab again over the socket transports
(``BENCH_DRYRUN_TRANSPORT=socket``: Modbus TCP server, python-can virtual bus), the path before the
in-process transports. Speeds are simulated s per wall s of the run (the CLI's own figure) and per
CPU s of the run (load from other processes inflates the first; say which).

    python benchmarks/bench_thermal_ramp.py [--hours 8] [--short-hours 2] [--lengths 1,2,4,8] [--socket] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LAB = ["acs_board", "tvac", "thermocouples", "rate_table", "stepper_bench"]

PROCEDURE = """schema: bench-procedure/1
name: thermal_ramp_bench
instruments: [{instruments}]
steps:
  - power: {{instrument: acs_board, on: true}}
  - configure: {{instrument: acs_board, odr: 100 Hz, moving_average: 1}}
{ramp_up}  - record: {{instrument: acs_board, duration: {hours} h, window: ramp}}
{ramp_down}"""
RAMP_UP = "  - set_temperature: {instrument: tvac, set_point: 66 degC, ramp: 0.2 degC/min}\n"
RAMP_DOWN = "  - set_temperature: {instrument: tvac, set_point: 20 degC}\n"

CHILD = """
import resource, sys, time
from bench.runner import engine
cpu, peak = [], []
_run = engine.Runner.run
def run(self, *a, **k):
    c0 = time.process_time()
    try:
        return _run(self, *a, **k)
    finally:
        cpu.append(time.process_time() - c0)
        peak.append(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
engine.Runner.run = run
from bench.cli import main
rc = main(sys.argv[1:])
print(f"PEAK_RSS_KB {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}")
print(f"RUN_PEAK_RSS_KB {max(peak)}")
print(f"RUN_CPU_S {sum(cpu)}")
sys.exit(rc)
"""


def run(instruments: list[str], hours: float, tmp: Path, transport: str = "inprocess") -> dict:
    """One dry-run in a fresh process: speeds (wall and CPU), peak RSS (MB)."""
    chamber = "tvac" in instruments
    proc = tmp / f"ramp_{len(instruments)}_{hours:g}_{transport}.yaml"
    proc.write_text(PROCEDURE.format(instruments=", ".join(instruments), hours=hours,
                                     ramp_up=RAMP_UP if chamber else "", ramp_down=RAMP_DOWN if chamber else ""))
    env = dict(os.environ, BENCH_DRYRUN_TRANSPORT=transport)
    out = subprocess.run([sys.executable, "-c", CHILD, "run", str(proc), "--config", str(ROOT / "configs" / "sim.yaml"),
                          "--runs-dir", str(tmp / "runs")], cwd=ROOT, capture_output=True, text=True, timeout=7200, env=env)
    text = out.stdout + out.stderr
    m = re.search(r"run time ([\d.]+) s in ([\d.]+) s wall", text)
    rss = re.search(r"PEAK_RSS_KB (\d+)", text)
    cpu = re.search(r"RUN_CPU_S ([\d.]+)", text)
    run_rss = re.search(r"RUN_PEAK_RSS_KB (\d+)", text)
    if out.returncode != 0 or m is None or rss is None or cpu is None or run_rss is None:
        raise SystemExit(f"run failed ({out.returncode}):\n{text[-3000:]}")
    for f in (tmp / "runs").glob("*.h5"):
        f.unlink()  # an 8-h run file is ~1 GB; the next run needs the room
    sim_s, wall_s, cpu_s = float(m.group(1)), float(m.group(2)), float(cpu.group(1))
    return {"instruments": instruments, "hours": hours, "transport": transport, "sim_s": sim_s, "wall_s": wall_s,
            "speed": sim_s / wall_s, "cpu_s": cpu_s, "cpu_speed": sim_s / cpu_s, "peak_rss_mb": int(rss.group(1)) / 1024,
            "run_peak_rss_mb": int(run_rss.group(1)) / 1024}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=8.0, help="length of the headline run (h)")
    ap.add_argument("--short-hours", type=float, default=2.0, help="length the peak memory is compared with (h)")
    ap.add_argument("--lengths", default="1,2,4,8", help="comma-separated run lengths (h) of the speed-against-length series")
    ap.add_argument("--socket", action="store_true", help="also run the whole lab over the socket transports")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    try:
        lengths = sorted({float(x) for x in args.lengths.split(",") if x.strip()} | {args.hours, args.short_hours})
    except ValueError:
        ap.error(f"--lengths: expected hours separated by commas, got {args.lengths!r}")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        series = {h: run(LAB, h, tmp) for h in lengths}
        board = run(["acs_board"], args.hours, tmp)
        socket = run(LAB, args.hours, tmp, "socket") if args.socket else None
    full, short = series[args.hours], series[args.short_hours]
    result = {"full_lab": full, "full_lab_short": short, "baseline_board_alone": board,
              "speed_ratio_vs_board_alone": full["speed"] / board["speed"],
              "cpu_speed_ratio_vs_board_alone": full["cpu_speed"] / board["cpu_speed"],
              "memory_ratio_long_vs_short": full["peak_rss_mb"] / short["peak_rss_mb"],
              "run_memory_ratio_long_vs_short": full["run_peak_rss_mb"] / short["run_peak_rss_mb"],
              "by_length": [series[h] for h in lengths], "socket_transports": socket}
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    rows = [(f"whole lab {h:g} h", r) for h, r in series.items()] + [("baseline: board alone", board)]
    if socket is not None:
        rows.append(("whole lab, socket transports", socket))
    for name, r in rows:
        print(f"{name:30s} {r['hours']:4g} h simulated in {r['wall_s']:7.1f} s wall = {r['speed']:6.0f}x real time "
              f"({r['cpu_speed']:6.0f}x per CPU s), peak RSS {r['peak_rss_mb']:4.0f} MB (until the run ended {r['run_peak_rss_mb']:4.0f} MB)")
    print(f"whole lab {args.hours:g} h vs board alone: speed {result['speed_ratio_vs_board_alone']:.2f} "
          f"(per CPU s {result['cpu_speed_ratio_vs_board_alone']:.2f}); peak memory {args.hours:g} h / {args.short_hours:g} h: "
          f"{result['memory_ratio_long_vs_short']:.2f} for the whole 'bench run' process, cataloguing included "
          f"(until the run ended: {result['run_memory_ratio_long_vs_short']:.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
