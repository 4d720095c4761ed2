#!/usr/bin/env python3
"""Set up and run bench with one command (needs only python3 >= 3.11 and the package index).

    python3 dev.py dryrun   # create .venv if needed, install, dry-run the startup profile
    python3 dev.py test     # create .venv if needed, install, run the whole test suite

Extra arguments go to ``bench run`` (dryrun) or to pytest (test). The environment is reinstalled
only when ``pyproject.toml`` changes.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
STAMP = VENV / ".bench-install-stamp"
INSTALL_MODE = "editable_mode=compat"
"""An editable install through a plain path entry (.pth), not setuptools' import hook: the hook is
imported by every Python start in the venv (about 13 ms of each `bench` command; docs/benchmarks.md)."""
BIN = VENV / ("Scripts" if os.name == "nt" else "bin")
PY = BIN / ("python.exe" if os.name == "nt" else "python")

DRYRUN = ["run", "procedures/startup_profile.yaml", "--config", "configs/sim.yaml", "--sim"]


def _say(text: str) -> None:
    print(f"[dev.py] {text}", flush=True)


def example_packages() -> list[Path]:
    """The lab packages under ``examples/`` (each a directory with its own pyproject.toml: an instrument
    kind bench finds by entry point, docs/instruments.md). The tests install and exercise them."""
    return sorted(p.parent for p in (ROOT / "examples").glob("*/pyproject.toml"))


def ensure_env() -> None:
    """Create the virtual environment and install bench with its test extras, then the example
    packages, when needed."""
    if sys.version_info < (3, 11):
        sys.exit(f"[dev.py] bench needs Python >= 3.11, this is {sys.version.split()[0]}")
    if not PY.exists():
        _say(f"creating virtual environment in {VENV}")
        result = subprocess.run([sys.executable, "-m", "venv", str(VENV)])
        if result.returncode != 0 or not PY.exists():
            sys.exit("[dev.py] could not create a virtual environment; on Debian/Ubuntu install the 'python3-venv' package")
    # the stamp covers the install command too, so a change of how we install reinstalls
    examples = example_packages()
    want = hashlib.sha256(b"".join([(ROOT / "pyproject.toml").read_bytes(), INSTALL_MODE.encode(),
                                    *(p.name.encode() + (p / "pyproject.toml").read_bytes() for p in examples)])).hexdigest()
    if STAMP.exists() and STAMP.read_text().strip() == want:
        return
    _say("installing bench and its dependencies into .venv (once; again when pyproject.toml changes)")
    cmd = [str(PY), "-m", "pip", "install", "--disable-pip-version-check", "-q", "--config-settings", INSTALL_MODE,
           "-e", f"{ROOT}[test]"]
    if subprocess.run(cmd, cwd=ROOT).returncode != 0:
        sys.exit("[dev.py] installing dependencies failed (see the pip output above)")
    for example in examples:  # after bench: each depends on it (already installed, so pip fetches nothing for it)
        _say(f"installing the example package {example.relative_to(ROOT)}")
        cmd = [str(PY), "-m", "pip", "install", "--disable-pip-version-check", "-q", "--config-settings",
               INSTALL_MODE, "-e", str(example)]
        if subprocess.run(cmd, cwd=ROOT).returncode != 0:
            sys.exit(f"[dev.py] installing {example.relative_to(ROOT)} failed (see the pip output above)")
    STAMP.write_text(want + "\n")


OWN_PACKAGES = ("bench", "drivers", "examples")
"""Where bench's own Python modules are (the examples' packages included)."""


def compile_bytecode() -> None:
    """Write the bytecode of bench's own modules where it is missing or stale. pip compiles what it
    installs, but bench is installed editable, so only an import writes it, and none does where
    ``PYTHONDONTWRITEBYTECODE`` is set: every ``bench`` the tests start would then compile bench's
    modules again (0.25 s of a dry-run, 50 ms of ``bench validate``; docs/benchmarks.md). Takes
    ~0.7 s the first time, ~0.05 s when up to date; Python ignores a stale file."""
    subprocess.run([str(PY), "-m", "compileall", "-q", *OWN_PACKAGES], cwd=ROOT, stdout=subprocess.DEVNULL)


TEST_TOOLS = {"mbpoll": "mbpoll", "pg_ctl": "postgresql", "chromium": "chromium"}
"""Debian packages of third-party programs the tests use when present (command -> package): protocol
clients, the PostgreSQL server the catalogue tests start a throwaway cluster of (its initdb and
pg_ctl live in /usr/lib/postgresql/*/bin, off PATH), and the browser the web station's tests drive
with Playwright (tests/browser.py). Looked for as the tests look for them (tests/programs.py: PATH,
then the sbin and libexec places)."""


def ensure_test_tools() -> None:
    """Install missing third-party programs with apt-get where allowed (root on Debian); the tests that
    need one skip with the reason printed otherwise."""
    from tests.programs import find_program, with_system_dirs

    missing = [pkg for cmd, pkg in TEST_TOOLS.items() if find_program(cmd) is None]
    apt_get = find_program("apt-get")
    if not missing or apt_get is None or not hasattr(os, "geteuid") or os.geteuid() != 0:
        return
    _say(f"installing {', '.join(missing)} with apt-get (third-party programs the tests use)")
    # dpkg refuses to work without ldconfig and start-stop-daemon on PATH (/usr/sbin, /sbin)
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive", PATH=with_system_dirs(os.environ.get("PATH")))
    try:
        ok = subprocess.run([apt_get, "install", "-y", "-q", *missing], env=env, capture_output=True, timeout=300).returncode == 0
        if not ok:
            subprocess.run([apt_get, "update", "-q"], env=env, capture_output=True, timeout=300)
            ok = subprocess.run([apt_get, "install", "-y", "-q", *missing], env=env, capture_output=True, timeout=300).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        ok = False
    if not ok:
        _say(f"could not install {', '.join(missing)}; the tests that need it will say so")


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in ("dryrun", "test"):
        print(__doc__)
        return 2
    ensure_env()
    compile_bytecode()
    os.chdir(ROOT)
    if argv[0] == "dryrun":
        cmd = [str(PY), "-m", "bench", *DRYRUN, *argv[1:]]
    else:
        ensure_test_tools()
        cmd = [str(PY), "-m", "pytest", *argv[1:]]
    _say(" ".join(cmd[2:] if argv[0] == "dryrun" else cmd[1:]))
    return subprocess.run(cmd).returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
