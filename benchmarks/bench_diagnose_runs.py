"""``bench diagnose A B`` on two runs of one unit: wall time and peak memory of the whole command,
against the named baseline measured in the same run: each run diagnosed alone (``bench diagnose A``
plus ``bench diagnose B``, summed; the peak is the larger).

The runs are two 1-h sessions at 1 Hz of one simulated unit (``bench.sessions.make_session``: the
thermal-vacuum session, a warm-up of +0.04 deg/s, τ 300 s, and a random walk K 5e-5 deg/s/√s on x;
the second run another session seed), written as CSVs. The warm-up is named across the runs, so each
run is diagnosed twice (the second time with it fixed): the ratio shows that cost. Each measurement is
a fresh process timed on the wall clock, best of ``--repeat``, its peak memory the maximum resident
set size (``os.wait4``, :func:`bench_diagnose_runfile.timed`). The machine may be shared: say the load.

    python benchmarks/bench_diagnose_runs.py [--repeat 1] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from bench_diagnose_runfile import timed

ROOT = Path(__file__).resolve().parents[1]


def write_runs(out: Path) -> list[Path]:
    """The two runs' CSVs (module docstring)."""
    sys.path.insert(0, str(ROOT))
    from bench.sessions import BaselineSensor, make_session, write_csv

    paths = []
    for run in (0, 1):
        rng = np.random.default_rng([4, 32])
        base = BaselineSensor.random(rng, 1.0)
        eff = [{"effect": "rate_random_walk", "axis": "x", "params": {"k_dps_per_sqrt_s": 5e-5}},
               {"effect": "warmup_transient", "axis": "x", "params": {"amplitude_dps": 0.04, "tau_s": 300.0}}]
        s = make_session(3600.0, 1.0, eff, seed=int(rng.integers(2**31)) + 1000 * run, mount="z", base=base)
        paths.append(write_csv(s.dataset, out / f"run{run}.csv"))
    return paths


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        a, b = write_runs(Path(tmp))
        cmd = [sys.executable, "-m", "bench", "diagnose"]

        def best(*files: Path) -> tuple[float, float]:
            runs = [timed(cmd + [str(f) for f in files] + ["--json"]) for _ in range(args.repeat)]
            return min(r[0] for r in runs), max(r[1] for r in runs)

        alone = [best(a), best(b)]
        both = best(a, b)
    base_s, base_mb = sum(t for t, _ in alone), max(m for _, m in alone)
    out = {"load_1min": os.getloadavg()[0], "alone_s": [t for t, _ in alone], "alone_peak_mb": base_mb,
           "together_s": both[0], "together_peak_mb": both[1], "ratio_to_alone": both[0] / base_s}
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print(f"each run alone: {alone[0][0]:.1f} s + {alone[1][0]:.1f} s, peak {base_mb:.0f} MB; together: "
              f"{both[0]:.1f} s, peak {both[1]:.0f} MB ({out['ratio_to_alone']:.2f}x the runs alone; load {out['load_1min']:.1f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
