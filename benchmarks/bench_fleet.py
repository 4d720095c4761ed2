"""``bench fleet`` on 100 run files: serial in one process (the baseline) vs 1 and 2 dask workers,
efficiency per worker, and a per-file cost model that predicts 16 workers.

The run files are copies of the recorded sessions of ``tests/sessions/`` (``--source``), cycled to
``--files`` (default 100) in a temporary directory. For each command (``--commands``, default
``replay diagnose``):

* **baseline**: :func:`bench.fleet.tasks.run_file` (the very function a worker runs) on every file
  in a loop in this process, after one untimed file (imports paid);
* **fleet on N workers** (``--workers``, default 1 2): the embedded cluster of
  :func:`bench.fleet.cluster.connect` (processes, one thread each, 127.0.0.1), warmed with one
  untimed file per worker, then :func:`bench.fleet.fanout.run_fleet` on all files (wall time from
  submission to the last result; cluster start reported apart).

Cost model, per file (s): ``t`` the work (the files' mean wall time on their worker with 1 worker),
``o`` the overhead per task on the worker's critical path (idle time between tasks: the scheduler's
round trip, the result's way back: ``(N * wall - sum of per-file times) / files``), ``s`` the
scheduler's own time per task (a separate run of ``--noop`` trivial tasks on 2 workers; the
scheduler handles tasks one at a time, so ``files * s`` bounds the fleet from below whatever the
workers), ``b / B`` the file's bytes over the disk's read rate (``O_DIRECT`` reads of the files,
bypassing the page cache). Predicted wall time on ``W`` workers, each on its own core::

    T(W) = max(files * (t + o) / W + (1 - 1/W) * tail,  files * s,  files * b / B)

``tail``: the longest file's time; ``(1 - 1/W) * tail`` is the most a file started last can keep the
other workers waiting (Graham's bound for list scheduling; nothing for one worker). The term that
wins says what limits the fleet: the workers (per-file work), the scheduler, or the disk. The model
assumes a core per worker: on a machine busy with other work, ``t`` grows with the workers.

    python benchmarks/bench_fleet.py [--files 100] [--workers 1 2] [--commands replay diagnose]
                                     [--predict 16] [--source tests/sessions] [--json]
    python benchmarks/bench_fleet.py --show SAVED.json     # the model and tables again from saved measurements
"""

from __future__ import annotations

import argparse
import json
import mmap
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.fleet.cluster import connect  # noqa: E402
from bench.fleet.fanout import run_fleet  # noqa: E402
from bench.fleet.files import RunFileRef, files_in  # noqa: E402
from bench.fleet.tasks import Job, run_file  # noqa: E402


def make_files(source: Path, n: int, into: Path) -> list[RunFileRef]:
    """``n`` copies of the run files of ``source``, cycled, named ``run_000_<stem>.h5``."""
    originals = sorted(source.glob("*.h5"))
    if not originals:
        raise SystemExit(f"no *.h5 run file in {source}")
    for i in range(n):
        src = originals[i % len(originals)]
        shutil.copy(src, into / f"run_{i:03d}_{src.stem}.h5")
    return files_in(into)


def disk_read_rate(paths: list[Path]) -> tuple[float, str]:
    """Bytes per second reading ``paths`` whole, bypassing the page cache (``O_DIRECT``) where the
    filesystem allows it, else through the cache (then an upper bound); and which of the two."""
    buf = mmap.mmap(-1, 1 << 20)  # page-aligned, as O_DIRECT needs
    try:
        return _read_all(paths, buf, getattr(os, "O_DIRECT", 0)), "O_DIRECT"
    except OSError:
        return _read_all(paths, buf, 0), "page cache"


def _read_all(paths: list[Path], buf: mmap.mmap, flags: int) -> float:
    total, t0 = 0, time.perf_counter()
    for p in paths:
        fd = os.open(p, os.O_RDONLY | flags)
        try:
            while (got := os.readv(fd, [buf])) > 0:
                total += got
        finally:
            os.close(fd)
    return total / (time.perf_counter() - t0)


def serial(job: Job, refs: list[RunFileRef]) -> tuple[float, list[Any]]:
    """The baseline: every file through ``run_file`` in this process (one untimed file first)."""
    run_file(job, str(refs[0].path), "warmup/" + refs[0].rel)
    t0 = time.perf_counter()
    results = [run_file(job, str(r.path), r.rel) for r in refs]
    return time.perf_counter() - t0, results


def on_workers(job: Job, refs: list[RunFileRef], workers: int, timeout_s: float) -> dict[str, Any]:
    """One timed fleet run on ``workers`` embedded workers (started and warmed first, untimed)."""
    t0 = time.perf_counter()
    with connect(None, workers=workers, timeout_s=timeout_s) as ws:
        start_s = time.perf_counter() - t0
        warm = [RunFileRef(r.path, f"warmup/{i}/{r.rel}") for i, r in enumerate(refs[:workers])]
        run_fleet(ws.client, job, warm)
        run = run_fleet(ws.client, job, refs)
    per_file = [r.wall_s for r in run.results]
    return {"workers": workers, "cluster_start_s": start_s, "wall_s": run.wall_s, "busy_s": sum(per_file),
            "per_file_mean_s": statistics.fmean(per_file), "per_file_max_s": max(per_file),
            "overhead_per_task_s": max(workers * run.wall_s - sum(per_file), 0.0) / len(per_file),
            "processes": len({r.worker for r in run.results}), "failed": len(run.failed),
            "verdicts": [(r.verdict, r.exit_code) for r in run.results]}


def scheduler_cost(n_tasks: int, timeout_s: float) -> float:
    """Wall time per trivial task (``abs``) through the scheduler to 2 workers (s): its own cost."""
    from distributed import wait

    with connect(None, workers=2, timeout_s=timeout_s) as ws:
        wait(ws.client.map(abs, range(100), pure=False), timeout=timeout_s)  # warm
        t0 = time.perf_counter()
        futures = ws.client.map(abs, range(n_tasks), pure=False)
        wait(futures, timeout=timeout_s)
        return (time.perf_counter() - t0) / n_tasks


def model(files: int, t: float, o: float, tail: float, s: float, b: float, B: float, w: int) -> dict[str, Any]:
    terms = {"workers": files * (t + o) / w + (1 - 1 / w) * tail, "scheduler": files * s, "disk": files * b / B}
    limit = max(terms, key=terms.get)
    return {"workers": w, "predicted_s": terms[limit], "limited_by": limit, "terms_s": terms}


def analyse(out: dict[str, Any], predict: int) -> dict[str, Any]:
    """The cost model of each command from the measurements in ``out``: its parameters (``t``,
    ``o``, ``tail`` of the 1-worker run), the predicted wall time on the measured worker counts and
    on ``predict`` workers, and a check of the model's form: each measured run predicted from its
    own per-file figures (which carry the contention of a busy machine)."""
    s, b, B = out["scheduler_s_per_task"], out["bytes_per_file"], out["disk_read_B_per_s"]
    for row in out["commands"].values():
        one = next((f for f in row["fleet"] if f["workers"] == 1), row["fleet"][0])
        t, o, tail = one["per_file_mean_s"], one["overhead_per_task_s"], one["per_file_max_s"]
        row["model"] = {"t_s": t, "o_s": o, "tail_s": tail, "s_s": s, "b_bytes": b, "B_bytes_per_s": B}
        row["predictions"] = [model(out["files"], t, o, tail, s, b, B, w)
                              for w in sorted({*(f["workers"] for f in row["fleet"]), predict})]
        for f in row["fleet"]:
            own = model(out["files"], f["per_file_mean_s"], f["overhead_per_task_s"], f["per_file_max_s"], s, b, B, f["workers"])
            f["model_from_own_figures_s"] = own["predicted_s"]
            f["contention"] = f["per_file_mean_s"] / t  # per-file time vs the 1-worker run's
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--files", type=int, default=100)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--commands", nargs="+", default=["replay", "diagnose"], choices=["replay", "diagnose", "report"])
    ap.add_argument("--predict", type=int, default=16, help="workers to predict the wall time of (default 16)")
    ap.add_argument("--source", type=Path, default=ROOT / "tests" / "sessions")
    ap.add_argument("--noop", type=int, default=2000, help="trivial tasks timing the scheduler (default 2000)")
    ap.add_argument("--timeout", type=float, default=120.0, help="cluster start timeout, s")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--show", type=Path, default=None, metavar="FILE",
                    help="measure nothing: the model and tables of a saved --json output (its measurements)")
    args = ap.parse_args()
    if args.show is not None:
        out = analyse(json.loads(args.show.read_text()), args.predict)
        print(json.dumps(out, indent=2)) if args.json else _print(out)
        return 0
    out: dict[str, Any] = {"files": args.files, "cores": os.cpu_count(), "load_before": os.getloadavg(), "commands": {}}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        (tmp / "runs").mkdir()
        refs = make_files(args.source, args.files, tmp / "runs")
        sizes = [r.path.stat().st_size for r in refs]
        rate, how = disk_read_rate([r.path for r in refs])
        out["bytes_per_file"] = statistics.fmean(sizes)
        out["disk_read_B_per_s"], out["disk_read_how"] = rate, how
        out["scheduler_s_per_task"] = scheduler_cost(args.noop, args.timeout)
        for command in args.commands:
            job = Job(command, str(tmp / f"out-{command}"), force=True)
            base_s, base = serial(job, refs)
            row: dict[str, Any] = {"serial_s": base_s, "serial_per_file_s": base_s / len(refs),
                                   "serial_failed": sum(1 for r in base if not r.ok), "fleet": []}
            for w in args.workers:
                shutil.rmtree(tmp / f"out-{command}", ignore_errors=True)
                f = on_workers(job, refs, w, args.timeout)
                f["speedup"] = base_s / f["wall_s"]
                f["efficiency_per_worker"] = f["speedup"] / w
                f["same_verdicts_as_serial"] = [(r.verdict, r.exit_code) for r in base] == f.pop("verdicts")
                row["fleet"].append(f)
            out["commands"][command] = row
    out["load_after"] = os.getloadavg()
    out = analyse(out, args.predict)
    if args.json:
        print(json.dumps(out, indent=2, default=str))
    else:
        _print(out)
    return 0


def _print(out: dict[str, Any]) -> None:
    print(f"{out['files']} run files, {out['bytes_per_file'] / 1e6:.2f} MB each on average; {out['cores']} cores; "
          f"load {out['load_before'][0]:.1f} before, {out['load_after'][0]:.1f} after")
    print(f"disk read ({out['disk_read_how']}): {out['disk_read_B_per_s'] / 1e6:.0f} MB/s; "
          f"scheduler: {out['scheduler_s_per_task'] * 1e3:.2f} ms per trivial task")
    for command, row in out["commands"].items():
        refused = f"; {row['serial_failed']} files not done (exit 1 or 2, as the serial command)" if row["serial_failed"] else ""
        print(f"\n{command}: serial (baseline) {row['serial_s']:.1f} s = {row['serial_per_file_s']:.3f} s/file{refused}")
        for f in row["fleet"]:
            print(f"  {f['workers']} worker(s): {f['wall_s']:.1f} s (cluster start {f['cluster_start_s']:.1f} s apart), "
                  f"speed-up {f['speedup']:.2f}x, efficiency per worker {f['efficiency_per_worker']:.2f}; per file "
                  f"{f['per_file_mean_s']:.3f} s mean, {f['per_file_max_s']:.2f} s max, overhead {f['overhead_per_task_s'] * 1e3:.1f} ms/task; "
                  f"{f['processes']} process(es); verdicts as serial: {f['same_verdicts_as_serial']}; per-file time "
                  f"{f['contention']:.2f}x the 1-worker run's; model from its own figures {f['model_from_own_figures_s']:.1f} s")
        m = row["model"]
        print(f"  model: t = {m['t_s']:.3f} s, o = {m['o_s'] * 1e3:.1f} ms, tail = {m['tail_s']:.2f} s, s = {m['s_s'] * 1e3:.2f} ms, "
              f"b/B = {m['b_bytes'] / m['B_bytes_per_s'] * 1e3:.1f} ms")
        for p in row["predictions"]:
            terms = ", ".join(f"{k} {v:.1f} s" for k, v in p["terms_s"].items())
            print(f"  predicted on {p['workers']} worker(s): {p['predicted_s']:.1f} s, limited by the {p['limited_by']} ({terms})")


if __name__ == "__main__":
    sys.exit(main())
