"""A config's safe values are checked against the instrument's limits (issue 21): the chamber's
safe set point is written to the controller on every abort."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.config import load_config
from bench.errors import InputErrors, InputError

CONFIG = """\
schema: bench-config/1
name: safe-values
mode: sim
instruments:
  tvac:
    driver: tvac
    port: modbus-tcp://127.0.0.1:5020
    gauge_port: /dev/null
    safe_set_point: {safe}
{limits}"""


def _load(tmp_path: Path, safe: str, limits: str = "") -> float:
    """Load the config; the chamber's safe set point it gives (degC)."""
    path = tmp_path / "lab.yaml"
    path.write_text(CONFIG.format(safe=safe, limits=limits))
    return load_config(path).instruments["tvac"].safe_set_point_c


@pytest.mark.parametrize("safe", ["500 degC", "-60 degC"])
def test_a_safe_set_point_beyond_the_chamber_defaults_is_refused_at_its_key(tmp_path: Path, safe: str) -> None:
    with pytest.raises((InputError, InputErrors)) as exc:
        _load(tmp_path, safe)
    text = str(exc.value)
    assert text.startswith(f"{tmp_path / 'lab.yaml'}:9:21: safe_set_point: ") and "-40..100 degC" in text, text


def test_the_lab_limits_narrow_what_is_safe(tmp_path: Path) -> None:
    with pytest.raises((InputError, InputErrors)) as exc:
        _load(tmp_path, "60 degC", "    limits: {set_point: [-20 degC, 50 degC]}\n")
    assert "-20..50 degC (lab config)" in str(exc.value)


@pytest.mark.parametrize("safe, degc", [("25 degC", 25.0), ("298.15 K", 25.0), ("-20 degC", -20.0), ("104 degF", 40.0)])
def test_a_safe_set_point_within_the_limits_loads(tmp_path: Path, safe: str, degc: float) -> None:
    """Within the lab's limits (their ends included) the set point loads, in degC whatever unit it was given in."""
    assert _load(tmp_path, safe, "    limits: {set_point: [-20 degC, 50 degC]}\n") == pytest.approx(degc, abs=1e-9)


def test_without_a_safe_set_point_the_chamber_goes_to_the_room(tmp_path: Path) -> None:
    """No ``safe_set_point`` key: an abort sets the chamber to 20 degC (the room)."""
    path = tmp_path / "lab.yaml"
    path.write_text("".join(line for line in CONFIG.format(safe="", limits="").splitlines(keepends=True)
                            if "safe_set_point" not in line))
    assert load_config(path).instruments["tvac"].safe_set_point_c == 20.0
