"""tests/programs.py finds the third-party programs the tests use off PATH too (issue 33: with
PATH=/usr/bin:/bin all PostgreSQL tests skipped, although /usr/sbin/runuser was there)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests import programs
from tests.conftest import ROOT
from tests.programs import find_program, with_system_dirs


def _executable(path: Path, mode: int = 0o755) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("#!/bin/sh\n")
    path.chmod(mode)
    return path


@pytest.fixture
def places(tmp_path: Path, monkeypatch) -> Path:
    """A PATH of one empty directory, a private sbin as the only system directory, a private lib as libexec."""
    monkeypatch.setenv("PATH", str(tmp_path / "onpath"))
    monkeypatch.setattr(programs, "SYSTEM_DIRS", (str(tmp_path / "sbin"), str(tmp_path / "bin")))
    monkeypatch.setattr(programs, "LIBEXEC_DIRS", (str(tmp_path / "libexec"), str(tmp_path / "lib" / "*" / "*" / "bin")))
    return tmp_path


def test_path_first_then_the_system_directories_then_libexec(places: Path) -> None:
    assert find_program("runuser") is None
    in_lib = _executable(places / "lib" / "postgresql" / "15" / "bin" / "runuser")
    assert find_program("runuser") == str(in_lib)
    in_sbin = _executable(places / "sbin" / "runuser")
    assert find_program("runuser") == str(in_sbin)
    on_path = _executable(places / "onpath" / "runuser")
    assert find_program("runuser") == str(on_path)


def test_the_newest_version_of_a_libexec_program_wins(places: Path) -> None:
    for major in ("9", "15", "13"):
        _executable(places / "lib" / "postgresql" / major / "bin" / "pg_ctl")
    assert find_program("pg_ctl") == str(places / "lib" / "postgresql" / "15" / "bin" / "pg_ctl")  # 15 > 13 > 9, not "9" > "15"


def test_a_file_that_cannot_be_executed_is_not_a_program(places: Path) -> None:
    _executable(places / "libexec" / "mbpoll", mode=0o644)
    _executable(places / "sbin" / "mbpoll", mode=0o644)
    assert find_program("mbpoll") is None


def test_with_system_dirs_keeps_the_order_and_adds_only_what_is_missing(monkeypatch) -> None:
    monkeypatch.setattr(programs, "SYSTEM_DIRS", ("/usr/sbin", "/usr/bin", "/sbin", "/bin"))
    assert with_system_dirs("/opt/x/bin:/usr/bin:/bin") == "/opt/x/bin:/usr/bin:/bin:/usr/sbin:/sbin"
    assert with_system_dirs("") == with_system_dirs(None) == "/usr/sbin:/usr/bin:/sbin:/bin"


@pytest.mark.skipif(not os.access("/usr/sbin/runuser", os.X_OK), reason="no /usr/sbin/runuser on this machine")
def test_runuser_is_found_from_the_shell_of_the_issue() -> None:
    """``env -i PATH=/usr/bin:/bin``: the case of the issue, on this machine's real /usr/sbin."""
    code = "from tests.programs import find_program; print(find_program('runuser'))"
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env={"PATH": "/usr/bin:/bin"},
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout.strip() == "/usr/sbin/runuser", out.stderr
