"""The procedure library (procedures/*.yaml): every file validates against the simulated lab,
dry-runs to completion with CI-length parameters, refuses out-of-range set points with a location,
and mutated procedure text only ever raises located input errors."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench.validate import load_checked
from bench.config import load_config
from bench.errors import InputError, InputErrors
from bench.procedure import parse_procedure

ROOT = Path(__file__).resolve().parents[1]
PROCEDURES = ROOT / "procedures"
SIM_CONFIG = ROOT / "configs" / "sim.yaml"
ANSWERS = PROCEDURES / "answers" / "ci.yaml"
LIBRARY = sorted(PROCEDURES.glob("*.yaml"))


# CI-length parameters.
CI_PARAMS: dict[str, list[str]] = {
    "startup_profile": [],
    "functional_test": ["dwell=2s", "settle=0s"],
    "rate_transfer": ["dwell=2s", "long_dwell=2s", "sample_sets=1", "settle=0s"],
    "vibe_functional": ["dwell=2s", "settle=0s"],
    "thermal_ramp_ambient": ["hot=24degC", "cold=17degC", "ramp=2degC/min", "soak=2min", "hold=2min", "ramp_record=5min"],
    "thermal_ramp_vacuum": ["vacuum=9e-5Torr", "hot=21degC", "cold=19degC", "ambient=20degC", "ramp=1degC/min",
                            "soak=1min", "hold=1min", "band=2degC", "ramp_record=2min"],
    "hysteresis": ["start=22degC", "turn=20degC", "end=22degC", "ramp_down=2degC/min", "ramp_up=2degC/min",
                   "down_record=2min", "up_record=2min", "soak=5min", "warmup=10min", "hold=5min", "band=0.3degC"],
    "startup_temperature_repeatability": ["t1=22degC", "t2=19degC", "t3=21degC", "t4=20degC", "soak=1min",
                                          "startup_record=2min", "skip=30s"],
    "estcube_gyro_thermal": ["t1=21degC", "t2=19degC", "t3=20degC", "t4=22degC", "hold=1min", "settle=1s"],
    "moving_average_sweep": ["n_max=3"],
    "allan_static": ["warmup=1min", "duration=5min"],
}

# Checks expected to fail on the simulators, and why (none: the `mount` step turns the simulated
# unit so each axis in turn is on the table axis, and every check of the library passes).
EXPECTED_FAILURES: dict[str, set[str]] = {}

LONG = ["thermal_ramp_ambient", "thermal_ramp_vacuum", "hysteresis", "startup_temperature_repeatability",
        "rate_transfer", "vibe_functional", "estcube_gyro_thermal", "moving_average_sweep", "allan_static"]


def _run(name: str, params: list[str], runs_dir: Path, timeout: float) -> subprocess.CompletedProcess:
    args = [sys.executable, "-m", "bench", "run", str(PROCEDURES / f"{name}.yaml"), "--config", str(SIM_CONFIG),
            "--runs-dir", str(runs_dir), "--answers", str(ANSWERS)]
    for p in params:
        args += ["-p", p]
    env = dict(os.environ, COLUMNS="1000")  # keep the summary line (failed check names) on one line
    return subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=timeout, env=env)


def _assert_outcome(name: str, proc: subprocess.CompletedProcess) -> None:
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith(("COMPLETED", "FAILED", "ABORTED"))]
    assert lines, f"no outcome line; stdout: {proc.stdout[-2000:]}; stderr: {proc.stderr[-2000:]}"
    final = lines[-1]  # the summary's outcome line (the next useful commands follow it)
    expected = EXPECTED_FAILURES.get(name, set())
    if not expected:
        assert proc.returncode == 0, f"exit {proc.returncode}: {final}\n{proc.stderr[-2000:]}"
        assert final.startswith("COMPLETED"), final
        return
    # Exit 1: the run completed, only the expected checks failed.
    assert proc.returncode == 1, f"exit {proc.returncode}: {final}\n{proc.stderr[-2000:]}"
    m = re.match(r"FAILED: \d+ step\(s\) failed: (.*)$", final)
    assert m, final
    failed = {s.strip() for s in m.group(1).split(",")}
    assert failed == expected, f"unexpected set of failed checks: {sorted(failed)}"


def test_every_library_procedure_has_ci_parameters():
    assert {p.stem for p in LIBRARY} == set(CI_PARAMS)


@pytest.mark.parametrize("path", LIBRARY, ids=lambda p: p.stem)
def test_procedure_validates_against_sim_lab(path):
    procedure, config = load_checked(path, SIM_CONFIG, {})
    assert config is not None
    assert procedure.steps
    assert set(procedure.instruments) <= set(config.instruments)
    used = {s.params.get("instrument") for s in procedure.steps} | {s.params.get("record") for s in procedure.steps}
    used |= {lock.signal.split(".", 1)[0] for lock in procedure.interlocks}
    used |= {s.params["signal"].split(".", 1)[0] for s in procedure.steps if "signal" in s.params}
    assert set(procedure.instruments) <= used, f"declared but unused: {set(procedure.instruments) - used}"
    assert path.read_text().startswith("#"), "header comment citing the sources"


@pytest.mark.parametrize("name", sorted(CI_PARAMS))
def test_procedure_dry_runs_with_ci_parameters(name, tmp_path):
    proc = _run(name, CI_PARAMS[name], tmp_path, timeout=60)
    _assert_outcome(name, proc)


@pytest.mark.slow
@pytest.mark.parametrize("name", LONG)
def test_procedure_dry_runs_full_length(name, tmp_path):
    proc = _run(name, [], tmp_path, timeout=4 * 3600)
    _assert_outcome(name, proc)


@pytest.mark.parametrize("name, param, line_of", [
    ("thermal_ramp_ambient", "hot=80degC", "set_temperature: {instrument: tvac, set_point: $hot"),
    ("thermal_ramp_vacuum", "cold=-45degC", "set_temperature: {instrument: tvac, set_point: $cold"),
    ("estcube_gyro_thermal", "t4=70degC", "set_temperature: {instrument: tvac, set_point: $T"),
])
def test_out_of_range_set_point_is_refused_with_location(name, param, line_of):
    path = PROCEDURES / f"{name}.yaml"
    proc = subprocess.run([sys.executable, "-m", "bench", "validate", str(path), "--config", str(SIM_CONFIG), "-p", param],
                          cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    out = proc.stdout + proc.stderr
    line = next(i for i, text in enumerate(path.read_text().splitlines(), 1) if line_of in text)
    assert re.search(rf"{re.escape(path.name)}:{line}:\d+", out), out
    assert "set_point" in out and "limits" in out, out


# ---- mutation property test -------------------------------------------------------------------------
BAD_VALUES = ["abc", "5 furlongs", "-1e9 degC", "1e9 deg/s", "[1, 2]", "{a: 1}", "true", "null", "12 Torr/s",
              "-5", "3.5 parsecs", "$nope", "${nope}x", "'0 Hz'", "1000000", "nan", "-inf deg", "'*'", "[]", "{}"]
BAD_KEYS = ["recrod", "set_temp", "rate_step", "for-each", "calll", "vibrat", "unknown_field", "1abc"]
MUTATION_TARGETS = [p for p in LIBRARY if p.stem in ("rate_transfer", "hysteresis", "estcube_gyro_thermal",
                                                     "vibe_functional", "moving_average_sweep")]
_TEXTS = {p: p.read_text() for p in MUTATION_TARGETS}
_KINDS = load_config(SIM_CONFIG).kinds()
"""Instrument name -> kind of the simulated lab the library is written for."""


def _mutate(text: str, line_idx: int, mode: int, choice: int) -> str:
    lines = text.splitlines()
    candidates = [i for i, ln in enumerate(lines) if ":" in ln and not ln.lstrip().startswith("#")]
    i = candidates[line_idx % len(candidates)]
    ln = lines[i]
    if mode == 0:  # replace the value after the last "key:" with a bad value
        cut = ln.rfind(": ")
        if cut < 0:
            cut = ln.rfind(":")
        lines[i] = ln[:cut] + ": " + BAD_VALUES[choice % len(BAD_VALUES)]
    elif mode == 1:  # rename the first key on the line
        m = re.search(r"([A-Za-z_][A-Za-z0-9_]*)\s*:", ln)
        if m:
            lines[i] = ln[:m.start(1)] + BAD_KEYS[choice % len(BAD_KEYS)] + ln[m.end(1):]
    elif mode == 2:  # replace a number inside the line with something out of range or of the wrong type
        nums = list(re.finditer(r"-?\d+(\.\d+)?", ln))
        if nums:
            m = nums[choice % len(nums)]
            lines[i] = ln[:m.start()] + BAD_VALUES[choice % len(BAD_VALUES)].strip("'") + ln[m.end():]
    else:  # delete the line
        del lines[i]
    return "\n".join(lines) + "\n"


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(target=st.sampled_from(MUTATION_TARGETS), line_idx=st.integers(0, 10_000), mode=st.integers(0, 3),
       choice=st.integers(0, 10_000))
def test_mutated_procedure_raises_only_located_input_errors(target, line_idx, mode, choice):
    text = _mutate(_TEXTS[target], line_idx, mode, choice)
    try:
        parse_procedure(text, path=str(target), kinds=_KINDS)
    except InputError as exc:
        errors = exc.errors if isinstance(exc, InputErrors) else [exc]
        assert errors
        for err in errors:
            assert err.location is not None, f"unlocated error: {err}"
            assert err.location.line is not None, f"error without a line: {err}"
