"""``bench diagnose`` on a recorded 6.4-h thermal-ramp run file: wall time and peak memory of the
whole command, against loading the run file alone.

The run file is made with ``bench run procedures/thermal_ramp_ambient.yaml --config configs/sim.yaml
--sim`` (drivers, transports, recorder; 6.4 h of run time, the board streaming at 100 Hz while it
records: 1.3 M rows, ~180 MB) unless ``--run PATH`` names one. Each measurement is a fresh process
(``python -m bench diagnose RUN --json --report out.html``, as an operator runs it: imports, reading
the run file, binning, search, structure analysis, report), timed on the wall clock, best of
``--repeat``; its peak memory is the process's maximum resident set size (``os.wait4``). The named
baseline, measured the same way in the same run, is reading the run file into a Dataset alone
(``load_dataset``): ``ratio`` says how many loads the whole diagnosis costs. ``--stages`` adds one
in-process run split into load, prepare (binning), search + structure, report. ``--unbinned``
also measures diagnose with binning switched off (the method before binning: ~75 s, 2.6 GB).
The machine may be shared: run it when idle for stable figures.

    python benchmarks/bench_diagnose_runfile.py [--run RUN.h5] [--repeat 3] [--stages] [--unbinned] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 15.0
"""Wall time of the whole ``bench diagnose --report`` command on the 6.4-h run file (s)."""

LOAD = "import sys; from bench.analysis.dataset import load_dataset; load_dataset(sys.argv[1])"
UNBINNED = ("import sys; import bench.analysis.diagnose.data as d; d.BIN_MIN_ROWS = 10**12; "
            "from bench.cli import main; sys.exit(main(sys.argv[1:]))")


def make_run(out_dir: Path) -> Path:
    """Record procedures/thermal_ramp_ambient.yaml on the simulated lab into ``out_dir``."""
    r = subprocess.run([sys.executable, "-m", "bench", "run", str(ROOT / "procedures" / "thermal_ramp_ambient.yaml"),
                        "--config", str(ROOT / "configs" / "sim.yaml"), "--sim", "--runs-dir", str(out_dir)],
                       cwd=ROOT, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"recording the run failed:\n{r.stdout}\n{r.stderr}")
    (path,) = sorted(out_dir.glob("*.h5"))
    return path


def timed(cmd: list[str]) -> tuple[float, float, str, str]:
    """(wall s, max RSS MB, stdout, stderr) of one process."""
    t0 = time.perf_counter()
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=out, stderr=err, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{stderr}")
    return wall, usage.ru_maxrss / 1024.0, stdout, stderr


def best(cmd: list[str], repeat: int) -> dict:
    runs = [timed(cmd) for _ in range(repeat)]
    wall = min(r[0] for r in runs)
    return {"wall_s": wall, "max_rss_mb": max(r[1] for r in runs), "stdout": runs[-1][2], "stderr": runs[-1][3]}


def stages(run: Path, report: Path) -> dict:
    """One in-process run split into its stages (wall s each)."""
    sys.path.insert(0, str(ROOT))
    from bench.analysis.dataset import load_dataset
    from bench.analysis.diagnose import diagnose, write_report
    from bench.analysis.diagnose.data import prepare

    out = {}
    t = time.perf_counter()
    ds = load_dataset(run)
    out["load_s"] = time.perf_counter() - t
    t = time.perf_counter()
    p = prepare(ds)
    out["prepare_s"] = time.perf_counter() - t
    out["rows"] = p.rows_line()
    t = time.perf_counter()
    result = diagnose(ds)
    out["diagnose_s"] = time.perf_counter() - t
    out["search_and_structure_s"] = out["diagnose_s"] - out["prepare_s"]
    t = time.perf_counter()
    write_report(result, ds, report)
    out["report_s"] = time.perf_counter() - t
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", type=Path, default=None, help="an existing run file (default: record the 6.4-h ramp)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--stages", action="store_true", help="also one in-process run split into stages")
    ap.add_argument("--unbinned", action="store_true", help="also diagnose without binning (slow)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        run = args.run if args.run is not None else make_run(tmp / "runs")
        made_s = None if args.run is not None else time.perf_counter() - t0
        py = [sys.executable]
        out: dict = {"run": str(run), "run_mb": run.stat().st_size / 1e6, "recorded_in_s": made_s,
                     "targets": {"wall_s": TARGET_S}}
        load = best(py + ["-c", LOAD, str(run)], args.repeat)
        diag = best(py + ["-m", "bench", "diagnose", str(run), "--json", "--report", str(tmp / "out.html"), "--force"], args.repeat)
        plain = best(py + ["-m", "bench", "diagnose", str(run), "--json"], args.repeat)
        rows = next((line for line in diag["stderr"].splitlines() if line.startswith("analysed ")), "")
        out["rows"] = rows
        out["findings"] = [f"{f['effect']}:{f['axis']}" for f in json.loads(diag["stdout"])["findings"]]
        out["load_alone"] = {k: load[k] for k in ("wall_s", "max_rss_mb")}
        out["diagnose_report"] = {k: diag[k] for k in ("wall_s", "max_rss_mb")}
        out["diagnose"] = {k: plain[k] for k in ("wall_s", "max_rss_mb")}
        out["ratio_diagnose_report_to_load"] = diag["wall_s"] / load["wall_s"]
        out["ratio_diagnose_to_load"] = plain["wall_s"] / load["wall_s"]
        if args.unbinned:
            raw = best(py + ["-c", UNBINNED, "diagnose", str(run), "--json"], 1)
            out["diagnose_unbinned"] = {k: raw[k] for k in ("wall_s", "max_rss_mb")}
            out["ratio_unbinned_to_binned"] = raw["wall_s"] / plain["wall_s"]
        if args.stages:
            out["stages"] = stages(run, tmp / "stages.html")
    ok = out["diagnose_report"]["wall_s"] <= TARGET_S
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        made = f", recorded in {out['recorded_in_s']:.0f} s" if out["recorded_in_s"] is not None else ""
        print(f"run file {out['run']} ({out['run_mb']:.0f} MB{made})")
        print(out["rows"])
        ld = out["load_alone"]
        print(f"load alone (baseline)      {ld['wall_s']:6.2f} s wall, max RSS {ld['max_rss_mb']:5.0f} MB")
        for key, label in (("diagnose", "diagnose --json"), ("diagnose_report", "diagnose --json --report")):
            c = out[key]
            print(f"{label:26s} {c['wall_s']:6.2f} s wall, max RSS {c['max_rss_mb']:5.0f} MB; "
                  f"{c['wall_s'] / ld['wall_s']:.1f}x the load" + (f"  [target <= {TARGET_S:g} s]" if key == "diagnose_report" else ""))
        if "diagnose_unbinned" in out:
            c = out["diagnose_unbinned"]
            print(f"{'diagnose, no binning':26s} {c['wall_s']:6.2f} s wall, max RSS {c['max_rss_mb']:5.0f} MB; "
                  f"{out['ratio_unbinned_to_binned']:.1f}x binned")
        if "stages" in out:
            s = out["stages"]
            print(f"stages (in process): load {s['load_s']:.2f} s, prepare {s['prepare_s']:.2f} s, search + structure "
                  f"{s['search_and_structure_s']:.2f} s, report {s['report_s']:.2f} s")
        print(f"findings {out['findings']} (best of {args.repeat})")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
