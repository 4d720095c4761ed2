"""Recorder throughput: RunRecorder vs a bare h5py loop writing the same data, in the same run.

Workload: 16 float64 channels at 1 kHz, appended in 0.1-s batches (100 rows) for N simulated
seconds, with the 1-s flush policy. The recorder's wall clock is driven by the benchmark (+0.1 s
per batch), so it flushes exactly every 10 batches. The baseline writes the same arrays to the
same layout (16 resizable float64 datasets, 4096-row chunks, no compression, SWMR mode like the
recorder) with a resize + write per dataset per batch and ``file.flush()`` every 10 batches. The
recorder additionally writes the ``time`` column, the events table and the heartbeat.

    python benchmarks/bench_recorder.py [--seconds 600] [--repeat 3] [--json]

MB/s counts the 16 channels only (16 x 8 B per row) for both.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench import __version__  # noqa: E402
from bench.record import Column, RunRecorder  # noqa: E402

CHANNELS = 16
RATE_HZ = 1000
BATCH_ROWS = 100  # 0.1 s
BATCHES_PER_FLUSH = 10  # 1 s
CHUNK_ROWS = 4096
POOL = 10  # distinct data batches, reused cyclically


def make_pool(seed: int = 1) -> list[dict[str, np.ndarray]]:
    rng = np.random.default_rng(seed)
    return [{f"ch{c:02d}": rng.standard_normal(BATCH_ROWS) for c in range(CHANNELS)} for _ in range(POOL)]


def batch_times(i: int) -> np.ndarray:
    return (i * BATCH_ROWS + np.arange(BATCH_ROWS)) / RATE_HZ


def run_recorder(tmp: Path, batches: int, pool: list[dict[str, np.ndarray]]) -> float:
    """Wall time (s) to record ``batches`` batches with RunRecorder, including close."""
    wall = [0.0]
    rec = RunRecorder.create(
        tmp, procedure_name="bench_recorder", procedure_text="benchmark", procedure_path="-", config_text="-",
        config_path="-", mode="sim", software_version=__version__, flush_interval_s=1.0, wall_clock=lambda: wall[0],
    )
    key = rec.add_stream("daq", [Column(f"ch{c:02d}", "V") for c in range(CHANNELS)])
    rec.start()
    t0 = time.perf_counter()
    for i in range(batches):
        t = batch_times(i)
        rec.append(key, t, **pool[i % POOL])
        wall[0] += BATCH_ROWS / RATE_HZ
        rec.tick(float(t[-1]))
    rec.close("completed")
    elapsed = time.perf_counter() - t0
    assert rec.rows_written(key) == batches * BATCH_ROWS
    rec.path.unlink()
    return elapsed


def run_baseline(tmp: Path, batches: int, pool: list[dict[str, np.ndarray]]) -> float:
    """Wall time (s) for the bare h5py loop, including close."""
    path = tmp / "baseline.h5"
    f = h5py.File(path, "w", libver="latest")
    names = [f"ch{c:02d}" for c in range(CHANNELS)]
    ds = [f.create_dataset(n, shape=(0,), maxshape=(None,), chunks=(CHUNK_ROWS,), dtype="f8") for n in names]
    f.swmr_mode = True
    t0 = time.perf_counter()
    rows = 0
    for i in range(batches):
        data = pool[i % POOL]
        new = rows + BATCH_ROWS
        for n, d in zip(names, ds):
            d.resize(new, axis=0)
            d[rows:new] = data[n]
        rows = new
        if (i + 1) % BATCHES_PER_FLUSH == 0:
            f.flush()
    f.close()
    elapsed = time.perf_counter() - t0
    path.unlink()
    return elapsed


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=600.0, help="simulated seconds of data (default 600)")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each; the best counts (default 3)")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    args = ap.parse_args()
    batches = max(1, int(round(args.seconds * RATE_HZ / BATCH_ROWS)))
    rows = batches * BATCH_ROWS
    mbytes = rows * CHANNELS * 8 / 1e6
    pool = make_pool()
    best_rec = best_base = float("inf")
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeat):  # interleaved so both see the same machine state
            best_base = min(best_base, run_baseline(Path(tmp), batches, pool))
            best_rec = min(best_rec, run_recorder(Path(tmp), batches, pool))
    result = {
        "seconds_simulated": batches * BATCH_ROWS / RATE_HZ,
        "rows": rows,
        "channels": CHANNELS,
        "repeat": args.repeat,
        "recorder": {"wall_s": best_rec, "rows_per_s": rows / best_rec, "mb_per_s": mbytes / best_rec},
        "baseline": {"wall_s": best_base, "rows_per_s": rows / best_base, "mb_per_s": mbytes / best_base},
        "ratio_recorder_over_baseline": best_base / best_rec,
        "target_ratio": 0.8,
        "h5py": h5py.version.version,
        "hdf5": h5py.version.hdf5_version,
    }
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(f"{result['seconds_simulated']:.0f} s of {CHANNELS} channels at {RATE_HZ} Hz = {rows} rows, {mbytes:.1f} MB; best of {args.repeat}")
        for name in ("recorder", "baseline"):
            r = result[name]
            print(f"  {name:9s} {r['wall_s']:8.3f} s  {r['rows_per_s']:12,.0f} rows/s  {r['mb_per_s']:8.1f} MB/s")
        ratio = result["ratio_recorder_over_baseline"]
        print(f"  ratio recorder/baseline (throughput) {ratio:.2f} (target >= 0.8: {'met' if ratio >= 0.8 else 'NOT met'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
