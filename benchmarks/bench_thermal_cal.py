"""Thermal calibration of an 8-hour 1-Hz ramp: wall time of ``bench calibrate thermal``'s fit.

The data: an 8-h ramp -29 -> +66 -> -29 degC at 1 Hz (28,800 rows), three gyro axes with the
NPSAT1 Table 4 X cubic as bias plus white noise, reference rate 0. Timed: the whole method
(``bench.analysis.thermal_cal.calibrate``: static-row selection, cubic per axis with standard
errors, residual statistics, heating/cooling hysteresis fits). Baseline in the same run: a bare
``numpy.polyfit`` of degree 3 per axis on the same rows (the least-squares core alone).

    python benchmarks/bench_thermal_cal.py [--hours 8] [--rate-hz 1] [--repeat 5] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.analysis.dataset import Dataset  # noqa: E402
from bench.analysis.thermal_cal import calibrate  # noqa: E402

POLY = [-0.0217, 9.40e-4, -1.51e-5, -2.42e-7]  # shape of a ground cubic (deg/s vs degC); any cubic does


def ramp(hours: float, rate_hz: float, seed: int = 3) -> Dataset:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, hours * 3600.0, 1.0 / rate_hz)
    half = t[-1] / 2
    temp = np.where(t < half, -29 + 95 * t / half, 66 - 95 * (t - half) / half)
    bias = np.polyval(POLY[::-1], temp)
    cols = {"time_s": t, "power_on_s": t + 3600.0, "temp_c": temp}
    for a in "xyz":
        cols[f"gyro_{a}_dps"] = bias + rng.normal(0, 0.01, t.size)
        cols[f"ref_rate_{a}_dps"] = np.zeros(t.size)
    return Dataset(cols, {"sample_rate_hz": rate_hz}, "synthetic ramp")


def best(f, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=8.0)
    ap.add_argument("--rate-hz", type=float, default=1.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    ds = ramp(args.hours, args.rate_hz)
    ours = best(lambda: calibrate(ds), args.repeat)
    base = best(lambda: [np.polyfit(ds["temp_c"], ds[f"gyro_{a}_dps"], 3) for a in "xyz"], args.repeat)
    fit = calibrate(ds).json["axes"]["x"]["poly_degc"]
    out = {"rows": len(ds), "calibrate_s": ours, "polyfit_baseline_s": base, "ratio": ours / base,
           "poly_x": fit, "poly_true": POLY}
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print(f"{len(ds)} rows ({args.hours:g} h at {args.rate_hz:g} Hz): calibrate thermal {ours * 1e3:.1f} ms, "
              f"bare polyfit x3 {base * 1e3:.2f} ms (ratio {ours / base:.1f}x; best of {args.repeat})")
        print("x cubic: " + ", ".join(f"{c:.4g}" for c in fit) + "  (true: " + ", ".join(f"{c:.4g}" for c in POLY) + ")")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
