"""Start-up time of the everyday ``bench`` commands, each in a fresh process.

``bench --version``, ``bench --help``, ``bench validate PROC`` (and with ``--config CONFIG``) and
``bench inspect RUN`` are run N times each, interleaved with two baselines measured in the same run:
``python -c pass`` (the interpreter alone) and ``python -c "import numpy"`` (the floor of anything
that reads a run file or converts units: h5py and pint import numpy). Prints the best and median
wall time (s) of each, the best and median CPU time (user + sys, s: steadier than wall time on a
shared machine), their ratios to both baselines and whether the 0.3-s target is met
(docs/benchmarks.md).

It also says whether bench's own modules start from bytecode: with ``PYTHONDONTWRITEBYTECODE`` set
and no ``__pycache__`` next to them (a source checkout run that way), every start compiles them
again, ≈ 50 ms of ``bench validate``; an installed bench (pip compiles it) never does.

    python benchmarks/bench_startup.py [--repeat 10] [--run RUN.h5] [--procedure PROC.yaml] [--config CONFIG] [--json]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 0.3
"""Wall time (s) each command must stay within (issue 17)."""


def bench_command() -> list[str]:
    """How an operator starts bench: the ``bench`` console script next to this interpreter, else
    ``python -m bench``."""
    script = Path(sys.executable).with_name("bench")
    return [str(script)] if script.exists() else [sys.executable, "-m", "bench"]


def wall_s(argv: list[str]) -> tuple[float, float]:
    """Wall time and CPU time (user + sys) in s of one run of ``argv`` in a fresh process (output
    discarded); it must exit 0."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    elapsed = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} exited {done.returncode}: {done.stderr.decode(errors='replace').strip()}")
    return elapsed, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def bytecode_note() -> str:
    """Whether the bench these commands import starts from bytecode (see the module docstring)."""
    spec = importlib.util.find_spec("bench")
    where = Path(spec.origin).parent if spec and spec.origin else None
    cached = where is not None and any((where / "__pycache__").glob("cli.*.pyc"))
    if cached:
        return f"bench's bytecode is cached ({where}/__pycache__)"
    if os.environ.get("PYTHONDONTWRITEBYTECODE"):
        return f"bench ({where}) is compiled from source at every start: PYTHONDONTWRITEBYTECODE is set and nothing is cached"
    return f"bench ({where}) had no bytecode cached: the first (untimed) runs write it"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=10, help="runs of each command, interleaved (default 10)")
    ap.add_argument("--run", type=Path, default=ROOT / "tests" / "sessions" / "chamber_short.h5",
                    help="run file for 'bench inspect' (default tests/sessions/chamber_short.h5)")
    ap.add_argument("--procedure", type=Path, default=ROOT / "procedures" / "startup_profile.yaml",
                    help="procedure for 'bench validate' (default procedures/startup_profile.yaml)")
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "sim.yaml",
                    help="lab config for 'bench validate PROC --config' (default configs/sim.yaml)")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    args = ap.parse_args()
    bench = bench_command()
    cases = {
        "python -c pass": [sys.executable, "-c", "pass"],
        "python -c 'import numpy'": [sys.executable, "-c", "import numpy"],
        "bench --version": [*bench, "--version"],
        "bench --help": [*bench, "--help"],
        f"bench validate {args.procedure.name}": [*bench, "validate", str(args.procedure)],
        f"  ... --config {args.config.name}": [*bench, "validate", str(args.procedure), "--config", str(args.config)],
        f"bench inspect {args.run.name}": [*bench, "inspect", str(args.run)],
    }
    for argv in cases.values():  # warm the file cache (and pint's definition cache) once
        wall_s(argv)
    times: dict[str, list[float]] = {name: [] for name in cases}
    cpu: dict[str, list[float]] = {name: [] for name in cases}
    for _ in range(args.repeat):  # interleaved so every command sees the same machine state
        for name, argv in cases.items():
            wall, used = wall_s(argv)
            times[name].append(wall)
            cpu[name].append(used)
    best = {n: min(t) for n, t in times.items()}
    median = {n: statistics.median(t) for n, t in times.items()}
    base, numpy_base = best["python -c pass"], best["python -c 'import numpy'"]
    result = {
        "repeat": args.repeat,
        "bench": " ".join(bench),
        "python": sys.version.split()[0],
        "target_s": TARGET_S,
        "bytecode": bytecode_note(),
        "load_average": os.getloadavg(),
        "commands": {n: {"best_s": best[n], "median_s": median[n], "cpu_best_s": min(cpu[n]),
                         "cpu_median_s": statistics.median(cpu[n]), "over_python": best[n] / base,
                         "over_import_numpy": best[n] / numpy_base} for n in cases},
    }
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"fresh process each, best and median of {args.repeat} (bench = {' '.join(bench)}); {result['bytecode']}; "
          f"load average {' '.join(f'{x:.2f}' for x in result['load_average'])}")
    print(f"  {'command':40s} {'best s':>7s} {'median s':>9s} {'CPU best':>9s} {'CPU med':>8s} {'/python':>8s} {'/numpy':>7s}")
    for n in cases:
        r = result["commands"][n]
        verdict = "" if n.startswith("python") else ("  target met" if r["best_s"] <= TARGET_S else f"  over {TARGET_S} s")
        print(f"  {n:40s} {r['best_s']:7.3f} {r['median_s']:9.3f} {r['cpu_best_s']:9.3f} {r['cpu_median_s']:8.3f} "
              f"{r['over_python']:8.1f} {r['over_import_numpy']:7.2f}{verdict}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
