"""Input files are read bounded and confined (issue 21 part 3, bench/inputs.py).

Special files (``/dev/zero``, a FIFO), oversized files, and files a procedure or config names
outside its own tree or the project's ``procedures/`` / ``configs/`` are refused with exit code 2
and one located line, promptly, and never quote the foreign file's contents.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SIM_CONFIG = ROOT / "configs" / "sim.yaml"
HEAD = "schema: bench-procedure/1\nname: x\ninstruments: [acs_board]\nsteps:\n"


def bench(*args: str | Path) -> subprocess.CompletedProcess:
    """``bench ARGS`` in a subprocess that must finish within 5 s (a FIFO must not block it)."""
    return subprocess.run([sys.executable, "-m", "bench", *map(str, args)], capture_output=True, text=True,
                          timeout=5, cwd=ROOT)


def assert_refused(proc: subprocess.CompletedProcess, *needles: str) -> str:
    out = proc.stdout + proc.stderr
    assert proc.returncode == 2, out
    assert "Traceback" not in out and "root:" not in out, out
    lines = out.strip().splitlines()
    assert len(lines) == 1, out
    for needle in needles:
        assert needle in lines[0], out
    return lines[0]


@pytest.fixture
def fifo(tmp_path: Path) -> Path:
    path = tmp_path / "fifo.yaml"
    os.mkfifo(path)
    return path


def test_validate_refuses_dev_zero():
    """``bench validate /dev/zero`` was a MemoryError."""
    assert_refused(bench("validate", "/dev/zero", "--config", SIM_CONFIG), "/dev/zero", "not a regular file")


def test_validate_refuses_a_fifo(fifo: Path):
    assert_refused(bench("validate", fifo, "--config", SIM_CONFIG), str(fifo), "not a regular file")


def test_validate_refuses_an_oversized_procedure(tmp_path: Path):
    """A 50-MB procedure took 509 s and 5.6 GB to be refused; now the 1-MiB limit refuses at once."""
    path = tmp_path / "big.yaml"
    path.write_text(HEAD + "# " + "x" * (2 << 20) + "\n")
    assert_refused(bench("validate", path, "--config", SIM_CONFIG), str(path), "larger than 1 MiB")


def test_config_refuses_dev_zero():
    assert_refused(bench("validate", ROOT / "procedures" / "allan_static.yaml", "--config", "/dev/zero"),
                   "/dev/zero", "not a regular file")


@pytest.mark.parametrize("name", ["/etc/passwd", "/dev/zero", "../../x.yaml", "sub/../../../etc/passwd"])
def test_call_outside_the_trees_is_refused_at_the_key(tmp_path: Path, name: str):
    """``call:`` to /dev/zero or a FIFO hung ``bench validate``; /etc/passwd was read and quoted."""
    (tmp_path / "a" / "b").mkdir(parents=True)
    path = tmp_path / "a" / "b" / "p.yaml"
    path.write_text(HEAD + f"  - call: {{procedure: {name!r}}}\n")
    line = assert_refused(bench("validate", path, "--config", SIM_CONFIG), f"{path}:5:", "procedure:", "outside")
    assert "procedures/ and configs/" in line


def test_call_of_a_fifo_in_the_tree_is_refused(tmp_path: Path, fifo: Path):
    path = tmp_path / "p.yaml"
    path.write_text(HEAD + f"  - call: {{procedure: {fifo.name}}}\n")
    assert_refused(bench("validate", path, "--config", SIM_CONFIG), f"{path}:5:", "not a regular file")


def test_symlink_out_of_the_tree_is_refused(tmp_path: Path):
    (tmp_path / "link.yaml").symlink_to("/etc/passwd")
    path = tmp_path / "p.yaml"
    path.write_text(HEAD + "  - call: {procedure: link.yaml}\n")
    assert_refused(bench("validate", path, "--config", SIM_CONFIG), f"{path}:5:", "outside")


@pytest.mark.parametrize("name,says", [("/dev/zero", "outside"), ("/etc/passwd", "outside"), ("fifo.yaml", "not a regular file")])
def test_vibration_profile_special_or_foreign_is_refused(tmp_path: Path, fifo: Path, name: str, says: str):
    """``vibrate: {profile: /dev/zero}`` was killed at 24 GB."""
    path = tmp_path / "p.yaml"
    path.write_text(HEAD + f"  - vibrate: {{profile: {name}, axis: z}}\n")
    assert_refused(bench("validate", path, "--config", SIM_CONFIG), f"{path}:5:", "profile", says)


@pytest.mark.parametrize("key,name", [("sensor_model", "/etc/passwd"), ("sensor_model", "../../../../../../etc/passwd"),
                                      ("sensor_model", "/dev/zero"), ("calibration", "/etc/passwd")])
def test_config_names_outside_its_trees_are_refused(tmp_path: Path, key: str, name: str):
    text = SIM_CONFIG.read_text().replace("sensor_model: sensors/", f"sensor_model: {SIM_CONFIG.parent}/sensors/")
    if key == "sensor_model":
        text = text.replace(f"sensor_model: {SIM_CONFIG.parent}/sensors/acs_board_simple.yaml", f"sensor_model: {name}")
    else:
        text = text.replace("  acs_board:\n", f"  acs_board:\n    calibration: {name}\n", 1)
    assert name in text
    config = tmp_path / "c.yaml"
    config.write_text(text)
    assert_refused(bench("validate", ROOT / "procedures" / "allan_static.yaml", "--config", config),
                   f"{config}:", f"{key}:", "outside the config's directory and configs/")


def test_files_in_the_project_trees_are_accepted(tmp_path: Path):
    """A procedure elsewhere may still name the shipped files (absolute, or relative into configs/)."""
    shutil.copy(ROOT / "procedures" / "functional_test.yaml", tmp_path / "functional_test.yaml")
    path = tmp_path / "p.yaml"
    path.write_text(HEAD + f"  - vibrate: {{profile: {ROOT}/configs/vibration/gevs_workmanship.yaml, axis: z}}\n")
    proc = bench("validate", path, "--config", SIM_CONFIG)
    assert "outside" not in proc.stdout + proc.stderr


@pytest.mark.parametrize("procedure", sorted((ROOT / "procedures").glob("*.yaml")), ids=lambda p: p.name)
def test_shipped_procedures_still_validate(procedure: Path):
    proc = bench("validate", procedure, "--config", SIM_CONFIG)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_csv_special_file_is_refused(fifo: Path):
    """Reading a CSV from a FIFO blocked forever; in a subprocess so that a hang fails the test."""
    code = ("import sys\nfrom bench.csvsrc import read_csv_table\nfrom bench.errors import InputError\n"
            "try:\n    read_csv_table(sys.argv[1])\nexcept InputError as exc:\n    print(exc)\n")
    proc = subprocess.run([sys.executable, "-c", code, str(fifo)], capture_output=True, text=True, timeout=5, cwd=ROOT)
    assert proc.stdout.strip() == f"{fifo}: cannot read CSV file: not a regular file (a directory, device or FIFO)", proc
