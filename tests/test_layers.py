"""The layers of docs/architecture.md hold in the code: import-linter contracts in pyproject.toml."""

from __future__ import annotations

import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _lint_imports() -> str:
    exe = Path(sys.executable).with_name("lint-imports")
    found = str(exe) if exe.exists() else shutil.which("lint-imports")
    if found is None:
        pytest.skip("import-linter is not installed (it is in the test extras: python3 dev.py installs it)")
    return found


def test_import_contracts_hold() -> None:
    out = subprocess.run([_lint_imports(), "--no-cache", "--no-logo"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "0 broken" in out.stdout


def test_contracts_cover_the_documented_layers() -> None:
    """Each rule of the architecture has its contract (a deleted contract would silently pass)."""
    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    by_id = {c["id"]: c for c in contracts}
    expected = {
        "drivers": ({"drivers"}, {"bench"}),
        "model": ({"bench.model"}, {"bench.sim", "bench.analysis", "bench.runner", "drivers"}),
        "analysis": ({"bench.analysis"}, {"bench.sim", "bench.runner", "drivers"}),
        "sim": ({"bench.sim"}, {"bench.analysis", "bench.runner", "bench.record", "bench.cli"}),
        "procedure": ({"bench.procedure"}, {"bench.sim"}),
        "cli": (set(), {"bench.cli", "bench.cli_analysis", "bench.cli_procedure", "bench.cli_soak"}),
    }
    for cid, (sources, forbidden) in expected.items():
        assert cid in by_id, f"contract {cid!r} missing from pyproject.toml"
        assert sources <= set(by_id[cid]["source_modules"]), cid
        assert forbidden <= set(by_id[cid]["forbidden_modules"]), cid
    # nothing outside the CLI may import it: every top-level package and module is a source
    cli_sources = set(by_id["cli"]["source_modules"])
    for path in sorted((ROOT / "bench").iterdir()):
        name = path.stem if path.suffix == ".py" else path.name
        if name.startswith(("cli", "__")) or not (path.suffix == ".py" or (path / "__init__.py").exists()):
            continue
        mod = f"bench.{name}"
        if mod == "bench.replay":
            assert {"bench.replay.run", "bench.replay.lab"} <= cli_sources
            continue
        assert mod in cli_sources, f"{mod} is not checked by the 'nothing imports the CLI' contract"
