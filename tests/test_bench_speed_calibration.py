"""Stepper bench speed calibration (ESTCube-2 section 3.2): fit, uncertainties, CSV input, CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.analysis.bench_speed_fit import fit_bench_speed, fit_timings_file
from bench.csvsrc import read_numeric_csv
from bench.errors import InputError
from drivers.stepper_speed import BenchSpeedCalibration
from tests.conftest import ROOT, run_cli

TABLE_3_1 = ROOT / "tests" / "data" / "estcube2_table_3_1.csv"


def test_table_3_1_reproduces_the_thesis():
    r = run_cli("calibrate-bench", str(TABLE_3_1), "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert round(out["k"], 4) == 19.5154  # Eq. 3.1
    assert round(out["b_s_per_rad"], 4) == 0.4088  # Eq. 3.1
    assert round(out["u_a_s"], 3) == 0.153  # Eq. 3.2
    assert round(out["u_c_s"], 3) == 0.153  # Eq. 3.4
    assert round(out["u_speed_dps"], 3) == 0.006  # Eq. 3.5
    assert round(out["coverage_factor"], 3) == 2.869  # Eq. 3.6
    assert round(out["u_n"], 2) == 0.48  # Eq. 3.7
    assert round(out["u_n_extended"], 1) == 1.4  # Eq. 3.9
    assert out["u_k"] > 0 and out["u_b"] > 0


def test_table_output_names_the_result():
    r = run_cli("calibrate-bench", str(TABLE_3_1))
    assert r.returncode == 0 and "k = 19.5154" in r.stdout and "b = 0.4088" in r.stdout


@settings(max_examples=50, deadline=None)
@given(st.floats(5, 50), st.floats(0.05, 1.0), st.integers(0, 2**31))
def test_fit_recovers_known_bench(k, b, seed):
    rng = np.random.default_rng(seed)
    cal = BenchSpeedCalibration(k, b)
    n = np.repeat([200.0, 500.0, 900.0, 1400.0], 6)
    t = np.array([cal.rotation_time_s(x) for x in n]) + rng.normal(0, 0.15, n.size)
    fit = fit_bench_speed(n, t)
    assert abs(fit.k - k) < 6 * fit.u_k + 1e-9
    assert abs(fit.b_s_per_rad - b) < 6 * fit.u_b + 1e-9


@given(st.floats(0.05, 20), st.floats(5, 50), st.floats(0.05, 1.0))
def test_speed_and_n_are_inverse(speed, k, b):
    cal = BenchSpeedCalibration(k, b)
    n = cal.n_for_speed(speed)
    if n / k + b > 0:
        assert cal.speed_for_n(n) == pytest.approx(speed, rel=1e-9)
        assert cal.rotation_time_s(n) == pytest.approx(360.0 / speed, rel=1e-9)


def test_estcube_defaults_convert_table_speeds():
    cal = BenchSpeedCalibration()
    assert cal.n_for_speed(360.0 / 99.224) == pytest.approx(300, abs=1.5)  # within u_n-extended 1.4
    with pytest.raises(ValueError):
        cal.n_for_speed(0.0)


@pytest.mark.parametrize(
    "text, needle, line",
    [
        ("n,rotation_time_s\n300,99\n300,abc\n", "expected a number", 3),
        ("n,time\n300,99\n", "missing column", 1),
        ("n,rotation_time_s\n300,99\n300,-1\n900,292\n", "> 0 s", 3),
        ("# comment\nn,rotation_time_s\n300,99\n300,99.2\n", "two or more values of n", None),
        ("n,rotation_time_s\n300,99,5\n", "expected 2 values", 2),
        ("", "no header", 1),
    ],
)
def test_bad_timings_are_located(tmp_path, text, needle, line):
    f = tmp_path / "t.csv"
    f.write_text(text)
    with pytest.raises(InputError) as info:
        fit_timings_file(f)
    assert needle in str(info.value)
    if line is not None:
        assert info.value.location.line == line
    r = run_cli("calibrate-bench", str(f))
    assert r.returncode == 2 and "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1


@settings(max_examples=300, deadline=None)
@given(st.text(alphabet="n,rotation_time_s0123456789.-e#\n \"inf", max_size=200))
def test_csv_reader_never_raises_anything_else(tmp_path_factory, text):
    f = tmp_path_factory.mktemp("csv") / "x.csv"
    f.write_text(text)
    try:
        values, lines = read_numeric_csv(f, ["n", "rotation_time_s"])
    except InputError:
        return
    assert all(np.all(np.isfinite(v)) for v in values.values())
    assert len(lines) == len(values["n"])


# ---- stock GRBL: steps per degree from timed rotations ---------------------------------------------
@settings(max_examples=50, deadline=None)
@given(st.floats(500.0, 1500.0), st.floats(0.97, 1.03), st.integers(0, 2**31))
def test_grbl_fit_recovers_the_true_steps_per_degree(set_steps, error, seed):
    """Timings of a table whose true steps per degree differ from GRBL's $100 by ``error``:
    t = 360·true/($100·v) plus a stopwatch operator's 0.15 s scatter."""
    from bench.analysis.bench_speed_fit import fit_grbl_steps

    rng = np.random.default_rng(seed)
    true = set_steps * error
    v = np.repeat([0.5, 1.0, 2.0, 3.5], 5)
    t = 360.0 * true / (set_steps * v) + rng.normal(0, 0.15, v.size)
    fit = fit_grbl_steps(v, t, set_steps)
    assert abs(fit.steps_per_deg - true) < 5 * fit.u_steps_per_deg
    assert fit.u_steps_per_deg < 1e-3 * true  # 0.15 s on rotations of 100-700 s
    assert fit.command == f"$100={fit.steps_per_deg:.3f}" and fit.rate_error == pytest.approx(set_steps / true - 1, abs=1e-3)


def _cli(capsys, *args: str) -> tuple[int, str, str]:
    """``bench ARGS`` in this process (a subprocess costs seconds): exit code, stdout, stderr."""
    from bench.cli import main

    code = main(list(args))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_grbl_fit_from_rotations_timed_on_the_simulated_bench(tmp_path, capsys):
    """The simulated bench with mechanics of 890 steps/deg, GRBL told 894.33: rotations timed
    from the stage's true angle (a mark passing a fixed point) at three rates, repeated; the fit
    gives 890 back and the $100 line. (Our simulator and our fit agree; the linearity itself is
    the firmware's: tests/golden/test_grbl_transcripts.py::test_grbl_steps_at_the_rate_of_the_feed.)"""
    from bench.clock import VirtualClock
    from bench.sim import registry
    from bench.sim.stage import RotatingStage
    from bench.sim.stepper_bench import StepperBenchSim, bench_eeprom
    from drivers.stepper_bench import BenchSetup, StepperBench

    clock = VirtualClock()
    stage = RotatingStage()
    sim = StepperBenchSim(clock, stage, bench_eeprom(894.33, 210.0, 10.0, build_info="STEPPER_BENCH:T"), true_steps_per_deg=890.0)
    url = registry.register(f"cal{id(clock)}", sim)
    rows = ["rate_dps,rotation_time_s"]
    try:
        bench = StepperBench.open(url, setup=BenchSetup("X", 894.33, 3.5))
        for rate in (1.0, 2.0, 3.5):
            bench.set_rate(rate)
            bench.run()
            clock.sleep(2.0)
            marks: list[float] = []
            while len(marks) < 4:  # a mark on the table passes 0 deg: the stopwatch starts, stops
                t0 = clock.now()
                clock.sleep(1.0)
                bench.status()  # as the runner polls
                a0, a1 = stage.angle_deg(np.array([t0, clock.now()]))
                if np.floor(a0 / 360) != np.floor(a1 / 360):  # cruising: the angle is linear in time
                    marks.append(t0 + (np.floor(a1 / 360) * 360 - a0) / (a1 - a0))
            rows += [f"{rate},{round(b - a, 2)}" for a, b in zip(marks, marks[1:])]
            bench.stop()
    finally:
        registry.unregister(f"cal{id(clock)}")
    f = tmp_path / "grbl_timings.csv"
    f.write_text("\n".join(rows) + "\n")
    code, out, err = _cli(capsys, "calibrate-bench", str(f), "--steps-per-deg", "894.33", "--json")
    assert code == 0, err
    fit = json.loads(out)
    assert fit["steps_per_deg"] == pytest.approx(890.0, abs=max(0.05, 3 * fit["u_steps_per_deg"]))
    assert fit["command"] == f"$100={fit['steps_per_deg']:.3f}" and fit["rate_error"] == pytest.approx(894.33 / 890 - 1, abs=2e-4)
    code, out, err = _cli(capsys, "calibrate-bench", str(f), "--steps-per-deg", "894.33")
    assert "send $100=" in out and "steps_per_deg:" in out


def test_grbl_timings_need_the_steps_per_degree_grbl_ran_with(tmp_path, capsys):
    f = tmp_path / "g.csv"
    f.write_text("rate_dps,rotation_time_s\n1,360.5\n2,180.2\n")
    code, out, err = _cli(capsys, "calibrate-bench", str(f))
    assert code == 2 and "--steps-per-deg" in err and len(err.strip().splitlines()) == 1
    f.write_text("rate_dps,rotation_time_s\n1,360.5\n0,180.2\n")
    code, out, err = _cli(capsys, "calibrate-bench", str(f), "--steps-per-deg", "894.33")
    assert code == 2 and f"{f}:3:" in err and "rate_dps" in err
