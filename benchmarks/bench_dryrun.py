"""Dry-run speed: simulated seconds per wall-clock second for procedures/startup_profile.yaml.

Runs the full path in-process (driver over sim://, decoder, recorder writing HDF5, runner) with the
board at 100 Hz, and, in the same run, the baseline "simulator alone": the same board producing the
same 30 minutes of frames in the same steps (the runner's poll period) with nobody decoding or recording them.

    python benchmarks/bench_dryrun.py [--repeat 3] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench import __version__  # noqa: E402
from bench.clock import VirtualClock  # noqa: E402
from bench.config import load_config  # noqa: E402
from bench.lab import open_lab  # noqa: E402
from bench.procedure import load_procedure  # noqa: E402
from bench.record import RunRecorder  # noqa: E402
from bench.runner import Runner  # noqa: E402
from bench.runner.engine import POLL_PERIOD_VIRTUAL_S  # noqa: E402
from bench.sim.factory import build_devices  # noqa: E402


class NullProgress:
    def start(self, procedure, total_s): ...
    def step(self, n, total, step): ...
    def advance(self, run_time_s, readings=""): ...
    def message(self, text): ...
    def stop(self, run_time_s): ...


def full_dry_run(procedure, config, runs_dir: Path) -> tuple[float, float, int]:
    rec = RunRecorder.create(
        runs_dir, procedure_name=procedure.name, procedure_text=procedure.text, procedure_path=str(procedure.path),
        config_text=config.text, config_path=str(config.path), mode="sim", software_version=__version__,
    )
    lab = open_lab(config, procedure.instruments, sim=True, realtime=False)
    t0 = time.perf_counter()
    result = Runner(procedure, lab, rec, NullProgress()).run()
    wall = time.perf_counter() - t0
    lab.close()
    assert result.status == "completed", result.abort_reason
    return result.run_time_s, wall, sum(result.rows.values())


def simulator_alone(config, seconds: float) -> tuple[float, float, int]:
    clock = VirtualClock()
    dev = build_devices(config, clock, ["acs_board"])["acs_board"].device
    from drivers import acs_protocol as proto

    dev.receive(proto.encode_frame(proto.FrameType.SENSOR_POWER, b"\x01") + proto.encode_frame(proto.FrameType.START_STREAM))
    dev.take_output(0.0)
    t0 = time.perf_counter()
    nbytes = 0
    while clock.now() < seconds:
        clock.sleep(POLL_PERIOD_VIRTUAL_S)
        nbytes += len(dev.take_output(clock.now()))
    return seconds, time.perf_counter() - t0, nbytes // proto.DATA_FRAME_LEN


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    procedure = load_procedure(ROOT / "procedures" / "startup_profile.yaml")
    config = load_config(ROOT / "configs" / "sim.yaml")
    best_full = best_sim = None
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeat):
            full = full_dry_run(procedure, config, Path(tmp))
            sim = simulator_alone(config, full[0])
            best_full = full if best_full is None or full[1] < best_full[1] else best_full
            best_sim = sim if best_sim is None or sim[1] < best_sim[1] else best_sim
    sim_s, wall, rows = best_full
    out = {
        "procedure": "startup_profile",
        "simulated_s": sim_s,
        "wall_s": wall,
        "speedup_sim_s_per_wall_s": sim_s / wall,
        "rows": rows,
        "baseline_simulator_alone_wall_s": best_sim[1],
        "baseline_speedup": best_sim[0] / best_sim[1],
        "ratio_full_to_simulator_alone": (sim_s / wall) / (best_sim[0] / best_sim[1]),
        "target_speedup": 1000,
    }
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print(f"startup_profile dry-run: {sim_s:.0f} simulated s in {wall:.3f} s wall = {out['speedup_sim_s_per_wall_s']:.0f}x real time ({rows} rows) [target >= 1000x]")
        print(f"baseline simulator alone: {best_sim[1]:.3f} s wall = {out['baseline_speedup']:.0f}x; full path runs at {out['ratio_full_to_simulator_alone']:.2f} of the simulator-alone speed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
