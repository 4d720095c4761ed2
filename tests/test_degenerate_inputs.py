"""Degenerate inputs found by an adversarial pass (issue 21): each is bad input, exit 2 with one
located line, never an internal error (exit 1), a traceback or a numpy RuntimeWarning.

* ``diagnose``/``calibrate thermal``/``calibrate noise`` on a constant or all-zero gyro, or a
  single sample: ``nothing to fit: ...``; on values like 1e300: refused at their CSV line;
* ``sim serve`` while its Modbus TCP port is taken: ``--config: ... port N is in use``;
* ``replay --runs-dir`` a directory that cannot take the replay's file: names the directory.
"""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from tests.cli_output import one_error_line
from tests.conftest import ROOT, run_cli
from tests.test_foreign_data import bench_in_process

SESSION = ROOT / "tests" / "sessions" / "rate_transfer_short.h5"


def write_csv(path: Path, gyro: str, rows: int = 400) -> Path:
    """A measured-data CSV (docs/analysis.md) at 1 Hz, temperature ramping 20-29 °C, every gyro cell ``gyro``."""
    lines = ["# sample_rate_hz: 1", "time_s,temp_c,gyro_x_dps,gyro_y_dps,gyro_z_dps"]
    lines += [f"{i},{20 + i * 10 // rows},{gyro},{gyro},{gyro}" for i in range(rows)]
    path.write_text("\n".join(lines) + "\n")
    return path


COMMANDS = [("diagnose",), ("calibrate", "thermal"), ("calibrate", "noise")]


@pytest.mark.parametrize("command", COMMANDS, ids=" ".join)
@pytest.mark.parametrize("gyro", ["0", "0.5"], ids=["all_zero", "constant"])
def test_constant_gyro_is_nothing_to_fit(tmp_path, capsys, command, gyro):
    data = write_csv(tmp_path / "flat.csv", gyro)
    line = one_error_line(bench_in_process(capsys, *command, str(data), "--json"))
    assert line.startswith(f"{data}: gyro_x_dps: nothing to fit: gyro_x_dps is constant ({gyro} in all 400 rows)"), line


@pytest.mark.parametrize("command", COMMANDS[1:], ids=" ".join)  # diagnose: "needs at least 200 rows"
def test_single_sample_is_nothing_to_fit(tmp_path, capsys, command):
    data = write_csv(tmp_path / "one.csv", "0.1", rows=1)
    line = one_error_line(bench_in_process(capsys, *command, str(data)))
    assert line.startswith(f"{data}: gyro_x_dps: nothing to fit: "), line
    assert ("1 usable row(s)" if "thermal" in command else "1 row(s)") in line, line


@pytest.mark.parametrize("command", COMMANDS, ids=" ".join)
def test_absurd_magnitudes_are_refused_at_their_line(tmp_path, capsys, command):
    data = write_csv(tmp_path / "big.csv", "1e300")
    line = one_error_line(bench_in_process(capsys, *command, str(data), "--json"))
    assert line.startswith(f"{data}:3: gyro_x_dps: value 1e+300 is beyond ±1e+09: not a measurement"), line


def test_diagnose_leaves_out_a_dead_axis_and_says_so(tmp_path, capsys):
    import numpy as np

    rng = np.random.default_rng(21)
    lines = ["# sample_rate_hz: 1", "time_s,temp_c,gyro_x_dps,gyro_y_dps,gyro_z_dps"]
    lines += [f"{i},{20 + i // 40},0,{rng.normal(0, 0.01):.6f},{rng.normal(0, 0.01):.6f}" for i in range(400)]
    data = tmp_path / "dead_x.csv"
    data.write_text("\n".join(lines) + "\n")
    res = bench_in_process(capsys, "diagnose", str(data))
    assert res.returncode == 0, res.stderr
    assert "left out gyro_x_dps is constant (0 in all 400 rows)" in res.stdout, res.stdout


def test_sim_serve_on_a_taken_modbus_port_names_the_port(tmp_path):
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        text = (ROOT / "configs" / "sim.yaml").read_text()
        assert "modbus_port: 5020 " in text
        config = tmp_path / "sim.yaml"
        config.write_text(text.replace("modbus_port: 5020 ", f"modbus_port: {port} ")
                          .replace("sensor_model: sensors/", f"sensor_model: {ROOT / 'configs' / 'sensors'}/"))
        line = one_error_line(run_cli("sim", "serve", "--config", str(config), "--instrument", "tvac", timeout=60))
    assert line == f"--config: {config}: tvac: Modbus TCP port {port} is in use (another 'bench sim serve'?)"


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc (unwritable even for root)")
def test_replay_into_an_unwritable_runs_dir_is_bad_input(capsys):
    # /proc refuses new files for root too, where a chmod 555 directory would not
    line = one_error_line(bench_in_process(capsys, "replay", str(SESSION), "--runs-dir", "/proc"))
    assert line.startswith("runs directory /proc is not writable: "), line


def test_replay_into_a_runs_dir_under_a_file_is_bad_input(tmp_path, capsys):
    (tmp_path / "file.txt").write_text("")
    line = one_error_line(bench_in_process(capsys, "replay", str(SESSION), "--runs-dir", str(tmp_path / "file.txt" / "sub")))
    assert line.startswith(f"runs directory {tmp_path / 'file.txt' / 'sub'} cannot be created: "), line
