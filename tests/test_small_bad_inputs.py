"""The smaller cases of the adversarial pass (issue 21, "Smaller"): each gives exit 2 with a
located message before anything is created, where it used to validate and then fail in the run,
run for hours, evaluate an expression, or accept a meaningless number."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from bench.errors import InputError
from bench.units import to_units
from tests.cli_output import one_error_line

ROOT = Path(__file__).resolve().parents[1]


def _bench(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "bench", *args], cwd=cwd, capture_output=True, text=True, timeout=120)


def test_a_negative_simulator_seed_is_refused_at_its_line(tmp_path: Path) -> None:
    text = (ROOT / "configs" / "sim.yaml").read_text()
    assert "      seed: 1\n" in text
    lines = text.splitlines()
    line = lines.index("      seed: 1") + 1
    config = tmp_path / "lab.yaml"
    config.write_text(text.replace("      seed: 1\n", "      seed: -1\n", 1))
    res = _bench("validate", str(ROOT / "procedures" / "allan_static.yaml"), "--config", str(config), cwd=tmp_path)
    assert res.returncode == 2, res.stdout + res.stderr
    assert f"{config}:{line}:" in res.stderr and "seed" in res.stderr and "Traceback" not in res.stderr


def test_a_band_of_zero_is_refused_where_it_is_written(tmp_path: Path) -> None:
    proc = tmp_path / "p.yaml"
    proc.write_text("schema: bench-procedure/1\nname: band0\ninstruments: [tvac]\nsteps:\n"
                    "  - set_temperature: {instrument: tvac, set_point: 30 degC, wait: true, band: 0 degC}\n")
    res = _bench("validate", str(proc), cwd=tmp_path)
    assert res.returncode == 2, res.stdout + res.stderr
    assert f"{proc}:5:" in res.stderr and "band" in res.stderr and "above 0" in res.stderr


@pytest.mark.parametrize("text", ["66 degC * 0", "10 min + 5 s", "2 ** 3 s", "1 s**2*3", "(1+1) s", "3 s - 1 s"])
def test_expressions_are_not_evaluated_in_quantities(text: str) -> None:
    with pytest.raises(InputError, match="expressions are not evaluated"):
        to_units(text, "degC" if "degC" in text else "s")


@pytest.mark.parametrize("text, units, value", [
    ("-29 degC", "degC", -29.0), ("1e-5 Torr", "Torr", 1e-5), ("0.04 g0^2/Hz", "g0^2/Hz", 0.04),
    ("20 deg/s**2", "deg/s**2", 20.0), ("0.5 V/(deg/s)", "V/(deg/s)", 0.5), ("30 min", "s", 1800.0),
])
def test_quantities_with_compound_units_still_read(text: str, units: str, value: float) -> None:
    assert to_units(text, units) == pytest.approx(value)


def test_a_pathological_quantity_text_is_refused_quickly() -> None:
    import time

    t0 = time.perf_counter()
    for text in ("1 " + "a" * 190 + "1", "1 " + "a " * 99 + "1", "1 (" + "s*" * 90 + "1"):
        with pytest.raises(InputError):
            to_units(text, "s")
    assert time.perf_counter() - t0 < 1.0


@pytest.mark.parametrize("line, message", [
    ("# sample_rate_hz: abc", "sample_rate_hz: expected a number in Hz, got 'abc'"),
    ("# sample_rate_hz: 0", "sample_rate_hz: 0 Hz is outside the allowed range"),
    ("# latitude_deg: 200", "latitude_deg: 200 deg is outside the allowed range -90..90 deg"),
])
def test_csv_metadata_the_analyses_use_is_checked_at_its_line(tmp_path: Path, line: str, message: str) -> None:
    csv = tmp_path / "m.csv"
    csv.write_text(f"# station: lab 2\n{line}\ntime_s,gyro_x_dps\n0,1\n0.01,1\n0.02,1\n")
    res = _bench("calibrate", "noise", str(csv), cwd=tmp_path)
    line = one_error_line(res)
    assert line.startswith(f"{csv}:2: {message}"), res.stderr


def test_a_fault_for_an_instrument_the_procedure_does_not_use_is_refused_before_any_file(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    res = _bench("run", str(ROOT / "procedures" / "allan_static.yaml"), "--config", str(ROOT / "configs" / "sim.yaml"), "--sim",
                 "--runs-dir", str(runs), "--inject-faults", "table_stuck@10s", cwd=tmp_path)
    assert res.returncode == 2, res.stdout + res.stderr
    assert "--inject-faults" in res.stderr and "rate_table" in res.stderr
    assert not runs.exists() or not list(runs.glob("*.h5"))


@pytest.mark.parametrize("name", ["my table", "tvac.2", "../x", "t" * 65])
def test_an_instrument_name_that_is_not_plain_is_refused_at_its_entry(tmp_path: Path, name: str) -> None:
    from bench.config import load_config
    from bench.errors import InputErrors

    config = tmp_path / "lab.yaml"
    config.write_text("schema: bench-config/1\nname: n\nmode: sim\ninstruments:\n"
                      f"  \"{name}\":\n    driver: thermocouple_reader\n    port: /dev/null\n")
    with pytest.raises((InputError, InputErrors)) as exc:
        load_config(config)
    assert f"{config}:6:" in str(exc.value) and "instrument name" in str(exc.value)
