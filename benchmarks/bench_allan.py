"""Overlapping Allan deviation speed: bench.analysis.allan.overlapping_adev vs allantools.oadev.

Both compute the overlapping ADEV of the same rate series (white rate noise plus a rate random walk,
100 Hz) at the same octave-spaced τ (m = 1, 2, 4, … ≤ n/4) in the same run; the results must agree
to 1e-9 relative. Times are the best of ``--repeat`` rounds, the two alternating within each round;
peak memory (tracemalloc, numpy allocations included) is measured in a separate call of each so
that tracing does not slow the timed runs.

    python benchmarks/bench_allan.py [--samples 10000000] [--repeat 3] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import allantools  # noqa: E402

from bench.analysis.allan import octave_m, overlapping_adev  # noqa: E402

FS = 100.0  # Hz
REL = 1e-9


def make_rate(n: int, seed: int = 7) -> np.ndarray:
    """Gyro-like static output (deg/s): 0.3 deg/s bias, ARW 0.005 deg/√s, RRW 2e-5 deg/s/√s."""
    rng = np.random.default_rng(seed)
    rate = rng.standard_normal(n) * 0.005 * np.sqrt(FS)
    rate += np.cumsum(rng.standard_normal(n)) * 2e-5 / np.sqrt(FS)
    rate += 0.3
    return rate


def ours(rate: np.ndarray, taus: np.ndarray) -> np.ndarray:
    return overlapping_adev(rate, FS, taus).adev


def theirs(rate: np.ndarray, taus: np.ndarray) -> np.ndarray:
    return allantools.oadev(rate, rate=FS, data_type="freq", taus=taus)[1]


def best_interleaved(rate: np.ndarray, taus: np.ndarray, repeat: int) -> tuple[float, np.ndarray, float, np.ndarray]:
    """Best time of each over ``repeat`` rounds, ours and allantools alternating in every round (a
    shared machine's load then hits both alike)."""
    t_ours, t_theirs = [], []
    d_ours = d_theirs = np.empty(0)
    for _ in range(repeat):
        t0 = time.perf_counter()
        d_ours = ours(rate, taus)
        t1 = time.perf_counter()
        d_theirs = theirs(rate, taus)
        t2 = time.perf_counter()
        t_ours.append(t1 - t0)
        t_theirs.append(t2 - t1)
    return min(t_ours), d_ours, min(t_theirs), d_theirs


def peak_bytes(fn, rate: np.ndarray, taus: np.ndarray) -> int:
    tracemalloc.start()
    try:
        fn(rate, taus)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=10_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    if args.samples < 3:
        print("--samples must be >= 3", file=sys.stderr)
        return 2
    rate = make_rate(args.samples)
    taus = octave_m(args.samples) / FS
    t_ours, d_ours, t_theirs, d_theirs = best_interleaved(rate, taus, args.repeat)
    rel = float(np.max(np.abs(d_ours / d_theirs - 1.0)))
    if d_ours.shape != d_theirs.shape or not rel <= REL:
        print(f"results disagree: max relative difference {rel:.3g} (limit {REL:g})", file=sys.stderr)
        return 1
    mem_ours, mem_theirs = peak_bytes(ours, rate, taus), peak_bytes(theirs, rate, taus)
    out = {
        "samples": args.samples, "sample_rate_hz": FS, "taus": int(taus.size), "repeat": args.repeat,
        "ours_s": t_ours, "allantools_s": t_theirs, "ratio_allantools_to_ours": t_theirs / t_ours,
        "ours_msamples_per_s_per_tau": args.samples * taus.size / t_ours / 1e6,
        "ours_peak_mb": mem_ours / 1e6, "allantools_peak_mb": mem_theirs / 1e6, "input_mb": rate.nbytes / 1e6,
        "max_relative_difference": rel,
        "targets": {"ratio": 3, "max_relative_difference": REL},
    }
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print(f"{args.samples} samples at {FS:g} Hz ({rate.nbytes / 1e6:.0f} MB), {taus.size} octave taus "
              f"{taus[0]:g}-{taus[-1]:g} s, best of {args.repeat}")
        print(f"overlapping_adev   : {t_ours:7.3f} s  peak {out['ours_peak_mb']:7.1f} MB  "
              f"({out['ours_msamples_per_s_per_tau']:.0f} M samples·taus/s)")
        print(f"allantools.oadev   : {t_theirs:7.3f} s  peak {out['allantools_peak_mb']:7.1f} MB")
        print(f"ratio allantools/ours: {out['ratio_allantools_to_ours']:.1f}x  [target >= 3x]; "
              f"max relative difference {rel:.1e} [limit 1e-9]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
