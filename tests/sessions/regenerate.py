"""Regenerate the recorded sessions that CI replays (tests/test_replay.py replays every .h5 here).

    .venv/bin/python tests/sessions/regenerate.py [NAME ...]     # all, or the sessions named

Each session is a dry-run (``bench run --sim``) of a small procedure written below, recorded with
the simulator; the old files are replaced. The procedures are kept next to the files
(``*.yaml``) so the sessions can be inspected and re-recorded by hand with ``bench run``.
"""

from __future__ import annotations

import re
import shutil
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]

CHAMBER = """schema: bench-procedure/1
name: chamber_short
instruments: [tvac, thermocouples]
interlocks:
  - {{name: mount over temperature, signal: thermocouples.ch101, min: -33 degC, max: {limit}}}
steps:
  - set_temperature: {{instrument: tvac, set_point: 24 degC, ramp: 2 degC/min, wait: true, band: 1 degC, timeout: 20 min, name: warm up}}
  - wait: {{duration: 20 s, name: soak}}
  - set_temperature: {{instrument: tvac, set_point: 20 degC, name: back to ambient}}
"""


def rate_transfer_short() -> str:
    """procedures/rate_transfer.yaml with short defaults: one axis, three rates, 2 s dwells."""
    t = (ROOT / "procedures" / "rate_transfer.yaml").read_text(encoding="utf-8")
    t = t.replace("  axes: [z, x, y]", "  axes: [z]")
    t = re.sub(r"  rates: \[5 deg/s.*?0\.006 deg/s\]", "  rates: [1 deg/s, 0.5 deg/s, 0.005 deg/s]", t, flags=re.S)
    t = t.replace("long_dwell: 260 s", "long_dwell: 3 s").replace("dwell: 60 s", "dwell: 2 s")
    t = t.replace("settle: 5 s", "settle: 0 s").replace("sample_sets: 2 ", "sample_sets: 1 ")
    return t


STEPPER = """schema: bench-procedure/1
name: stepper_two_rates
title: The stepper bench (stock GRBL 1.1) at 1 and 0.2 deg/s, then stopped
instruments: [stepper_bench]
steps:
  - bench_rate: {instrument: stepper_bench, rate: 1 deg/s, settle: 20 s, name: one degree per second}
  - bench_rate: {instrument: stepper_bench, rate: 0.2 deg/s, settle: 20 s, name: a fifth of a degree per second}
  - bench_rate: {instrument: stepper_bench, rate: 0 deg/s, name: stop}
"""

SESSIONS = {
    "rate_transfer_short": (rate_transfer_short, []),
    "chamber_short": (lambda: CHAMBER.format(limit="70 degC"), []),
    "chamber_interlock_abort": (lambda: CHAMBER.format(limit="22 degC").replace("chamber_short", "chamber_interlock_abort"), []),
    "stepper_two_rates": (lambda: STEPPER, []),
}
ELSEWHERE = {"stepper_two_rates": ROOT / "tests" / "data"}
"""Sessions kept out of this directory (whose files other tests count): replayed by their own tests
(tests/test_stepper_bench.py)."""


def record(procedure: Path, out_dir: Path, extra: list[str]) -> Path:
    """Dry-run ``procedure`` into ``out_dir``; the run file's path."""
    from bench.cli import main

    before = set(out_dir.glob("*.h5"))
    main(["run", str(procedure), "--config", str(ROOT / "configs" / "sim.yaml"), "--runs-dir", str(out_dir),
          "--answers", str(ROOT / "procedures" / "answers" / "ci.yaml"), *extra])
    (new,) = set(out_dir.glob("*.h5")) - before
    return new


def main(argv: list[str] | None = None) -> int:
    sys.path.insert(0, str(ROOT))
    names = (sys.argv[1:] if argv is None else argv) or list(SESSIONS)
    for name in names:
        text, extra = SESSIONS[name]
        where = ELSEWHERE.get(name, HERE)
        proc = where / f"{name}.yaml"
        proc.write_text(text(), encoding="utf-8")
        with tempfile.TemporaryDirectory() as d:
            f = record(proc, Path(d), extra)
            shutil.copy(f, where / f"{name}.h5")
        print(f"{where / (name + '.h5')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
