"""Run a soak and write its table at the end of ``docs/reliability.md`` (between the markers).

    python benchmarks/soak_reliability.py [--hours 24] [--faults-per-hour 3] [--seed 24]

Runs ``bench soak --config configs/sim.yaml --json`` (the procedure library back to back on the
simulated lab with random faults), then replaces the text between ``<!-- soak-table:start -->`` and
``<!-- soak-table:end -->`` with the per-class table (fault class -> injected -> survived ->
aborted safely -> data lost) and the totals. Rerun it when behaviour changes.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "reliability.md"
START, END = "<!-- soak-table:start -->", "<!-- soak-table:end -->"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=24.0)
    ap.add_argument("--faults-per-hour", type=float, default=3.0)
    ap.add_argument("--seed", type=int, default=24)
    ap.add_argument("--dry", action="store_true", help="print the table, leave the doc alone")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        cmd = [sys.executable, "-m", "bench", "soak", "--config", "configs/sim.yaml", "--hours", str(args.hours),
               "--faults-per-hour", str(args.faults_per_hour), "--seed", str(args.seed), "--runs-dir", d, "--json"]
        out = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if not out.stdout.strip():
        sys.exit(f"bench soak printed nothing (exit {out.returncode}):\n{out.stderr[-3000:]}")
    r = json.loads(out.stdout)
    from bench.faults import FAULT_CLASSES

    lines = [f"Soak of {r['run_time_h']:.1f} h of run time ({r['runs']} runs of the procedure library) with "
             f"{args.faults_per_hour:g} faults per hour, seed {args.seed}, in {r['wall_time_s']:.0f} s wall: "
             f"`python benchmarks/soak_reliability.py --hours {args.hours:g} --faults-per-hour {args.faults_per_hour:g} --seed {args.seed}`.",
             "",
             "| fault class | severity | injected | survived | aborted safely | data lost (rows) |",
             "|---|---|---|---|---|---|"]
    for name, cls in FAULT_CLASSES.items():
        c = r["by_class"].get(name, {"injected": 0, "survived": 0, "aborted_safely": 0, "data_lost_rows": 0})
        lines.append(f"| `{name}` | {cls.severity} | {c['injected']} | {c['survived']} | {c['aborted_safely']} | {c['data_lost_rows']} |")
    lines += [f"| **all** | | {r['faults_injected']} | {sum(c['survived'] for c in r['by_class'].values())} | "
              f"{sum(c['aborted_safely'] for c in r['by_class'].values())} | {r['data_lost_rows']} |", "",
              f"Runs {r['runs']}, aborts {r['aborts']} ({r['aborts_explained']} explained), crashes {r['crashes']}, "
              f"unreadable files {r['unreadable_files']}, data lost {r['data_lost_rows']} rows."]
    if r["problems"]:
        lines += ["", "Problems:", *[f"- {p}" for p in r["problems"]]]
    table = "\n".join(lines)
    if args.dry:
        print(table)
        return out.returncode
    text = DOC.read_text()
    if START not in text or END not in text:
        sys.exit(f"{DOC} lacks the markers {START} ... {END}")
    head, rest = text.split(START, 1)
    _, tail = rest.split(END, 1)
    DOC.write_text(f"{head}{START}\n{table}\n{END}{tail}")
    print(table)
    return out.returncode


if __name__ == "__main__":
    raise SystemExit(main())
