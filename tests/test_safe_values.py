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


def _load(tmp_path: Path, safe: str, limits: str = "") -> None:
    path = tmp_path / "lab.yaml"
    path.write_text(CONFIG.format(safe=safe, limits=limits))
    load_config(path)


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


def test_a_safe_set_point_within_the_limits_loads(tmp_path: Path) -> None:
    _load(tmp_path, "25 degC", "    limits: {set_point: [-20 degC, 50 degC]}\n")
