"""``bench diagnose`` and ``bench calibrate noise`` on a long static CSV: 1,000,000 rows at 100 Hz
(2.8 h) of an ADIS16405-like gyro, wall time and peak memory of the whole command against loading
the file alone (the named baseline, measured the same way in the same run).

The file is synthetic (no public ADIS16405 log is reachable from the package index): the figures of
the ADIS16405 data sheet (Analog Devices, Rev. B, Table 1, gyroscopes): angular random walk
2.0 deg/√h, in-run bias stability 0.007 deg/s (the Allan floor, so B = 0.007/0.664 deg/s); the
device filters its 819.2-SPS samples (Bartlett window) before the 100-Hz reads, which makes the
Allan curve flatter than −½ at the shortest τ: a first-order Gauss-Markov process of 0.05 s
correlation time holding the variance the filter removes [assumed shape]; a 20-Hz spectral line of
0.1 deg/s on z (the issue's log had one; it turned binning off and took 11.6 GB); temperature
25 °C ± 0.5 °C drifting over the run; accelerometer 1 g on z with 9 mg rms noise (data sheet).
Each measurement is a fresh process (as an operator runs it), its peak memory the maximum resident
set size (``os.wait4``), wall time best of ``--repeat``.

    python benchmarks/bench_diagnose_csv.py [--rows 1000000] [--repeat 1] [--json] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
TARGET_S = 30.0
TARGET_MB = 1000.0
FS = 100.0
ARW_DEG_SQRT_H = 2.0       # ADIS16405 data sheet, Table 1
BIAS_STABILITY_DPS = 0.007  # ADIS16405 data sheet, Table 1 (in-run bias stability, 1σ)
FILTER_TAU_S = 0.05         # assumed: the Bartlett filter's smoothing at 100-Hz reads
LINE_HZ, LINE_DPS = 20.0, 0.1
ACCEL_NOISE_G = 0.009       # ADIS16405 data sheet, Table 1 (accelerometer output noise)

LOAD = "import sys; from bench.analysis.dataset import load_dataset; load_dataset(sys.argv[1])"


def make_csv(path: Path, rows: int, seed: int = 16405) -> Path:
    """Write the ADIS16405-like static log (module docstring) to ``path``, in blocks."""
    from bench.model.effects import flicker_noise, gauss_markov_noise

    rng = np.random.default_rng(seed)
    t = np.arange(rows) / FS
    n_white = ARW_DEG_SQRT_H / 60.0 * math.sqrt(FS)
    b = BIAS_STABILITY_DPS / 0.6643
    cols = {"time_s": t, "temp_c": 25.0 + 0.5 * np.sin(2 * math.pi * t / t[-1])}
    for a in "xyz":
        g = rng.standard_normal(rows) * n_white * 0.5 + gauss_markov_noise(t, n_white * 0.8, FILTER_TAU_S, rng)
        g += flicker_noise(t, b, 1.0, t[-1], rng) + rng.uniform(-0.2, 0.2)
        if a == "z":
            g += LINE_DPS * np.sin(2 * math.pi * LINE_HZ * t + 0.3)
        cols[f"gyro_{a}_dps"] = g
    for a, g0 in zip("xyz", (0.0, 0.0, 1.0)):
        cols[f"accel_{a}_g"] = g0 + rng.standard_normal(rows) * ACCEL_NOISE_G
    names = list(cols)
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(f"# sample_rate_hz: {FS:g}\n# source: synthetic ADIS16405-like static log (benchmarks/bench_diagnose_csv.py)\n")
        fh.write(",".join(names) + "\n")
        step = 100_000
        for i in range(0, rows, step):
            np.savetxt(fh, np.column_stack([cols[c][i:i + step] for c in names]), delimiter=",", fmt="%.7g")
    return path


def timed(cmd: list[str]) -> tuple[float, float, str]:
    """(wall s, max RSS MB, stdout) of one process."""
    t0 = time.perf_counter()
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=out, stderr=err, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{stderr}")
    return wall, usage.ru_maxrss / 1024.0, stdout


def best(cmd: list[str], repeat: int) -> dict:
    runs = [timed(cmd) for _ in range(repeat)]
    return {"wall_s": min(r[0] for r in runs), "max_rss_mb": max(r[1] for r in runs), "stdout": runs[-1][2]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--keep", type=Path, default=None, help="write the CSV here (and reuse it if present)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = (args.keep or Path(tmp)) / f"adis16405_like_{args.rows}.csv"
        if not path.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
            make_csv(path, args.rows)
        py = [sys.executable]
        load = best(py + ["-c", LOAD, str(path)], args.repeat)
        diag = best(py + ["-m", "bench", "diagnose", str(path), "--json"], args.repeat)
        cal = best(py + ["-m", "bench", "calibrate", "noise", str(path), "--json"], args.repeat)
        doc = json.loads(diag["stdout"])
        out = {"rows": args.rows, "csv_mb": path.stat().st_size / 1e6, "load1": os.getloadavg()[0],
               "load_alone": {k: load[k] for k in ("wall_s", "max_rss_mb")},
               "diagnose": {k: diag[k] for k in ("wall_s", "max_rss_mb")},
               "calibrate_noise": {k: cal[k] for k in ("wall_s", "max_rss_mb")},
               "ratio_diagnose_to_load": diag["wall_s"] / load["wall_s"],
               "ratio_calibrate_to_load": cal["wall_s"] / load["wall_s"],
               "findings": [f"{f['effect']}:{f['axis']}" for f in doc["findings"]],
               "unexplained": [u["axis"] for u in doc["unexplained"]],
               "targets": {"wall_s": TARGET_S, "max_rss_mb": TARGET_MB}}
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print(f"{args.rows:,} rows ({out['csv_mb']:.0f} MB), load average {out['load1']:.1f}")
        for k in ("load_alone", "diagnose", "calibrate_noise"):
            print(f"  {k:16s} {out[k]['wall_s']:7.1f} s  {out[k]['max_rss_mb']:7.0f} MB")
        print(f"  diagnose / load {out['ratio_diagnose_to_load']:.1f}x; findings {out['findings']}; "
              f"unexplained {out['unexplained']}")
    ok = all(out[k]["wall_s"] <= TARGET_S and out[k]["max_rss_mb"] <= TARGET_MB for k in ("diagnose", "calibrate_noise"))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
