"""A runs directory with several units of two part numbers, dry-runs mixed in, for the tests of
``bench unit`` and the web station's unit page (issue 30).

Every run is a real dry-run of ``tests/data/procedures/acceptance_short.yaml`` on the simulated lab
(``configs/sim.yaml``), each unit with its own gyro z bias (a copy of the simulator's sensor model
with ``gyro_bias_dps`` changed) and its own noise seed, so the units differ as a lot does. This
machine has no bench hardware: the runs that stand for runs on real instruments are dry-run files
whose ``mode`` attribute is rewritten to ``hardware`` afterwards, and every run's start time is
moved to spread the history over three weeks. Both rewrites are the fixture's, said here and in
the tests that use it; what is tested is how the history presents mixed modes and dates, not a
hardware run.
"""

from __future__ import annotations

import shutil
from datetime import datetime, timedelta
from pathlib import Path

import h5py
import yaml

from tests.conftest import ROOT, SIM_CONFIG

PROCEDURE = ROOT / "tests" / "data" / "procedures" / "acceptance_short.yaml"
START = datetime(2026, 11, 2, 8, 0, 0)

UNITS = {  # serial -> (part number, gyro z bias deg/s of its sensor model, seed)
    "SN10": ("PN-100", 0.010, 11),
    "SN11": ("PN-100", 0.020, 12),
    "SN12": ("PN-100", 0.150, 13),   # the outlier of its lot
    "SN13": ("PN-100", 0.015, 14),
    "SN14": ("PN-100", 0.005, 15),
    "SN20": ("PN-200", 0.030, 21),
}
RUNS = [  # (serial, mode, day): SN12 twice for real and once dry; dry-runs mixed in for the others
    ("SN10", "hardware", 0), ("SN11", "hardware", 1), ("SN12", "sim", 2), ("SN13", "hardware", 3), ("SN14", "hardware", 4),
    ("SN12", "hardware", 7), ("SN10", "sim", 8), ("SN20", "hardware", 9), ("SN12", "hardware", 14), ("SN11", "sim", 15),
]


def unit_config(directory: Path, serial: str) -> Path:
    """A copy of configs/sim.yaml whose simulated board is unit ``serial``."""
    _part, bias, seed = UNITS[serial]
    model = yaml.safe_load((ROOT / "configs" / "sensors" / "acs_board_simple.yaml").read_text())
    model["gyro_bias_dps"] = [0.0, 0.0, bias]
    (directory / "sensors").mkdir(parents=True, exist_ok=True)
    (directory / "sensors" / f"{serial}.yaml").write_text(yaml.safe_dump(model))
    config = yaml.safe_load(SIM_CONFIG.read_text())
    config["instruments"]["acs_board"]["sim"].update(sensor_model=f"sensors/{serial}.yaml", seed=seed, serial=f"SIM-{serial}")
    path = directory / f"{serial}.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def build_runs(directory: Path) -> Path:
    """Run :data:`RUNS` into ``directory/runs`` (catalogued) and return that directory."""
    from bench.catalog.rebuild import rebuild
    from bench.catalog.store import open_catalog, resolve_url
    from bench.identity import RunIdentity
    from bench.runner.operator import Operator
    from bench.runner.session import start_run
    from bench.validate import load_checked

    runs = directory / "runs"
    configs = directory / "configs"
    for i, (serial, mode, day) in enumerate(RUNS):
        config_path = unit_config(configs, serial)
        procedure, config = load_checked(PROCEDURE, config_path, {})
        session = start_run(procedure, config, procedure_path=PROCEDURE, config_path=config_path, runs_dir=runs, sim=True,
                            realtime=False, operator=Operator(None, None), progress=_Quiet(), operator_name="ana",
                            operator_origin="cli ana@pts/1", identity=RunIdentity(serial, UNITS[serial][0], "A", "gyro-lab-1"))
        try:
            result = session.runner.run()
        finally:
            session.lab.close()
        assert result.status == "completed", result.abort_reason
        started = START + timedelta(days=day, minutes=i)
        with h5py.File(session.recorder.path, "r+") as f:  # the fixture's rewrites (see the module's docstring)
            f.attrs["mode"] = mode
            f.attrs["started_utc"] = started.strftime("%Y-%m-%dT%H:%M:%SZ")
            f.attrs["ended_utc"] = (started + timedelta(minutes=2)).strftime("%Y-%m-%dT%H:%M:%SZ")
    (runs / "catalog.sqlite").unlink(missing_ok=True)
    with open_catalog(resolve_url(None, runs)) as cat:
        rebuild(cat, runs)
    shutil.rmtree(configs)
    return runs


class _Quiet:
    def start(self, procedure, total_s: float) -> None: ...

    def step(self, n: int, total: int, step) -> None: ...

    def advance(self, run_time_s: float, readings: str = "") -> None: ...

    def message(self, text: str) -> None: ...

    def stop(self, run_time_s: float) -> None: ...
