"""Dry-run of the whole procedure library at full length: simulated hours vs wall seconds.

Every ``procedures/*.yaml`` runs through the real CLI (``bench run ... --config configs/sim.yaml
--answers procedures/answers/ci.yaml``) with its default parameters, each in its own process.
Baseline in the same run: ``startup_profile`` (the sensor board alone, no polled instruments),
so each procedure's speed is also given relative to the cheapest kind of run.

    python benchmarks/bench_library.py [--only NAME ...] [--json]
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
BASELINE = "startup_profile"
TARGET_WALL_S = 240.0
"""Issue 19: the whole library at full length within 4 minutes on the 2-core development machine."""


def dry_run(name: str, runs: Path) -> dict:
    out = subprocess.run([sys.executable, "-m", "bench", "run", str(ROOT / "procedures" / f"{name}.yaml"), "--config",
                          str(ROOT / "configs" / "sim.yaml"), "--runs-dir", str(runs), "--answers",
                          str(ROOT / "procedures" / "answers" / "ci.yaml")],
                         cwd=ROOT, capture_output=True, text=True, timeout=6 * 3600, env=dict(os.environ, COLUMNS="200"))
    text = out.stdout + out.stderr
    m = re.search(r"run time ([\d.]+) s in ([\d.]+) s wall", text)
    if m is None:
        raise SystemExit(f"{name}: no run summary (exit {out.returncode}):\n{text[-3000:]}")
    verdicts = re.findall(r"^([A-Z][A-Z ]*[A-Z]):", out.stdout, flags=re.MULTILINE)  # "COMPLETED: all steps done; ..."
    final = verdicts[-1] if verdicts else f"exit {out.returncode}"
    sim_s, wall_s = float(m.group(1)), float(m.group(2))
    return {"procedure": name, "exit": out.returncode, "outcome": final.split(":")[0], "sim_h": sim_s / 3600, "wall_s": wall_s,
            "speed": sim_s / wall_s}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", default=None)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    names = args.only or sorted(p.stem for p in (ROOT / "procedures").glob("*.yaml"))
    with tempfile.TemporaryDirectory() as d:
        base = dry_run(BASELINE, Path(d) / "runs")
        rows = [base if n == BASELINE else dry_run(n, Path(d) / "runs") for n in names]
    total_h = sum(r["sim_h"] for r in rows)
    total_wall = sum(r["wall_s"] for r in rows)
    for r in rows:
        r["vs_baseline"] = r["speed"] / base["speed"]
    result = {"procedures": rows, "total_sim_h": total_h, "total_wall_s": total_wall, "total_speed": total_h * 3600 / total_wall,
              "baseline": BASELINE, "target_wall_s": TARGET_WALL_S}
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"{'procedure':36s} {'outcome':10s} {'sim h':>7s} {'wall s':>8s} {'x real':>8s} {'vs ' + BASELINE:>20s}")
    for r in rows:
        print(f"{r['procedure']:36s} {r['outcome']:10s} {r['sim_h']:7.2f} {r['wall_s']:8.1f} {r['speed']:8.0f} {r['vs_baseline']:20.2f}")
    print(f"{'total':36s} {'':10s} {total_h:7.2f} {total_wall:8.1f} {result['total_speed']:8.0f}")
    print(f"target: the library in <= {TARGET_WALL_S:g} s of wall time (issue 19): "
          f"{'met' if total_wall <= TARGET_WALL_S else 'missed'} ({total_wall:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
