"""The procedure language (parameters, blocks, limits, interlocks) and the runner's new steps."""

from __future__ import annotations

import os
import subprocess
import threading
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from bench.config import load_config
from bench.errors import InputError, InputErrors
from bench.lab import open_lab
from bench.procedure import load_procedure, parse_procedure
from bench.procedure.schema import STEP_TYPES
from bench.record import RunRecorder, read_run_summary
from bench.runner import Runner
from bench.runner.operator import Operator
from bench.runner.steps import HANDLERS
from tests.conftest import SIM_CONFIG, run_cli

HEAD = "schema: bench-procedure/1\nname: t\ninstruments: [acs_board, tvac, rate_table, thermocouples, stepper_bench]\n"


def errors_of(text: str, **kw) -> list[str]:
    with pytest.raises(InputErrors) as info:
        parse_procedure(text, "p.yaml", **kw)
    return [e.one_line() for e in info.value.errors]


class QuietProgress:
    def start(self, procedure, total_s): ...
    def step(self, n, total, step): ...
    def advance(self, run_time_s, readings=""): ...
    def message(self, text): self.last = text
    def stop(self, run_time_s): ...


def dry_run(tmp_path: Path, text: str, operator: Operator | None = None, config: Path = SIM_CONFIG):
    proc_path = tmp_path / "proc.yaml"
    proc_path.write_text(text)
    cfg = load_config(config)
    procedure = load_procedure(proc_path, kinds=cfg.kinds(), config_limits=cfg.limits())
    rec = RunRecorder.create(tmp_path / "runs", procedure_name=procedure.name, procedure_text=procedure.text,
                             procedure_path=str(proc_path), config_text=cfg.text, config_path=str(config), mode="sim",
                             software_version="test", flush_interval_s=1.0)
    lab = open_lab(cfg, procedure.instruments, sim=True, realtime=False)
    runner = Runner(procedure, lab, rec, QuietProgress(), operator)
    try:
        result = runner.run()
    finally:
        lab.close()
    return result, rec.path, lab, runner


# ---- loader ---------------------------------------------------------------------------------------
def test_every_action_type_has_a_handler():
    assert set(STEP_TYPES) == set(HANDLERS)


def test_parameters_substitute_and_override():
    text = HEAD + "parameters: {cold: -29 degC, dwell: 60 s, rates: [1 deg/s, 2 deg/s]}\nsteps:\n" \
        "  - set_temperature: {instrument: tvac, set_point: $cold}\n" \
        "  - record: {instrument: acs_board, duration: $dwell, window: \"w_${cold}\"}\n"
    p = parse_procedure(text)
    assert p.steps[0].params["set_point"] == -29.0
    assert p.steps[1].params["duration"] == 60.0 and p.steps[1].params["window"] == "w_-29 degC"
    q = parse_procedure(text, params={"cold": "-20degC", "dwell": "2 min"})
    assert q.steps[0].params["set_point"] == -20.0 and q.steps[1].params["duration"] == 120.0
    assert any("no parameter 'colt'" in e for e in errors_of(text, params={"colt": "1"}))
    assert any("unknown parameter or loop variable $nope" in e for e in errors_of(HEAD + "steps:\n  - wait: $nope\n"))


def test_blocks_expand_with_paths_contexts_and_locations(tmp_path: Path):
    sub = tmp_path / "sub.yaml"
    sub.write_text("schema: bench-procedure/1\nname: sub\ninstruments: [acs_board]\nparameters: {d: 1 s}\nsteps:\n"
                   "  - record: {instrument: acs_board, duration: $d, window: sub}\n")
    main = tmp_path / "main.yaml"
    main.write_text(HEAD + "steps:\n"
                    "  - for_each:\n      var: T\n      values: [10 degC, 20 degC]\n      steps:\n"
                    "        - set_temperature: {instrument: tvac, set_point: $T}\n"
                    "  - repeat: {count: 2, steps: [{wait: 1 s}]}\n"
                    "  - call: {procedure: sub.yaml, args: {d: 5 s}}\n")
    p = load_procedure(main)
    assert [s.path for s in p.steps] == ["1.1.1", "1.2.1", "2.1.1", "2.2.1", "3.1"]
    assert [s.params.get("set_point") for s in p.steps[:2]] == [10.0, 20.0]
    assert p.steps[1].context == "T=20 degC" and p.steps[3].context == "iteration=2"
    assert p.steps[4].params["duration"] == 5.0
    assert p.steps[4].location.file == str(sub) and p.steps[4].location.line == 6  # the called file's line
    assert str(sub.resolve()) in p.sources


def test_recursive_call_is_refused(tmp_path: Path):
    me = tmp_path / "me.yaml"
    me.write_text("schema: bench-procedure/1\nname: me\ninstruments: [acs_board]\nsteps:\n  - call: {procedure: me.yaml}\n")
    with pytest.raises(InputErrors, match="recurse"):
        load_procedure(me)


def test_rate_schedule_expansion_follows_the_npsat1_pattern():
    text = HEAD + "steps:\n  - rate_steps: {instrument: rate_table, rates: [5 deg/s, 0.006 deg/s], alternate: true, settle: 10 s," \
        " dwell: 60 s, long_dwell: {below: 0.01 deg/s, dwell: 260 s}, record: acs_board, zero_reference: true, axis: y}\n"
    p = parse_procedure(text)
    records = [s for s in p.steps if s.type == "record"]
    assert [s.params["window"] for s in records] == ["rate_zero_before", "rate_+5", "rate_-5", "rate_+0.006", "rate_-0.006", "rate_zero_after"]
    assert [s.params["duration"] for s in records] == [60, 60, 60, 260, 260, 60]
    assert [s.meta["rate_dps"] for s in records] == [0.0, 5.0, -5.0, 0.006, -0.006, 0.0]
    assert all(s.meta["axis"] == "y" for s in records)
    assert [s.params["rate"] for s in p.steps if s.type == "table_rate"] == [5.0, -5.0, 0.006, -0.006]


def test_limits_in_three_layers_are_located(tmp_path: Path):
    text = HEAD + "limits: {tvac: {set_point: [-29 degC, 66 degC]}}\nsteps:\n" \
        "  - set_temperature: {instrument: tvac, set_point: 70 degC}\n" \
        "  - table_rate: {instrument: rate_table, rate: 90 deg/s}\n" \
        "  - bench_rate: {instrument: stepper_bench, rate: 4 deg/s}\n"
    errs = errors_of(text)
    assert any("p.yaml:6:5:" in e and "70 degC is outside the tvac set_point limits -29..66 degC (procedure)" in e for e in errs), errs
    assert any("p.yaml:7:5:" in e and "rate_table rate limits -60..60 deg/s" in e for e in errs), errs
    assert any("p.yaml:8:5:" in e and "stepper_bench rate limits -3.5..3.5" in e for e in errs), errs
    ok = HEAD + "steps:\n  - table_rate: {instrument: rate_table, rate: 20 deg/s}\n"
    parse_procedure(ok)
    errs = errors_of(ok, config_limits={"rate_table": {"rate": (-10.0, 10.0)}})
    assert any("(lab config)" in e for e in errs), errs


def test_step_needs_the_right_kind_of_instrument():
    errs = errors_of(HEAD + "steps:\n  - set_temperature: {instrument: rate_table, set_point: 20 degC}\n")
    assert any("is a rate_table; this step needs a tvac" in e for e in errs), errs


def test_signals_and_bands_are_checked():
    errs = errors_of(HEAD + "steps:\n  - wait_until_stable: {signal: tvac.humidity, band: 1 degC, hold: 1 min}\n"
                     "  - check: {signal: acs_board.gyro, statistic: mean, window: w}\n"
                     "  - wait_until_stable: {signal: tvac.air_temp, band: 1 Torr, hold: 1 min}\n")
    text = "\n".join(errs)
    assert "has no signal 'humidity'" in text and "is a vector: name an axis" in text and "Torr" in text


# ---- runner ---------------------------------------------------------------------------------------
def test_chamber_table_and_checks_run_on_the_simulated_lab(tmp_path: Path):
    text = HEAD + "steps:\n" \
        "  - power: {instrument: acs_board, on: true}\n" \
        "  - set_temperature: {instrument: tvac, set_point: 25 degC, wait: true, band: 0.5 degC, timeout: 2 h}\n" \
        "  - wait_until_stable: {signal: thermocouples.ch101, band: 0.5 degC, hold: 5 min, timeout: 3 h}\n" \
        "  - table_tilt: {instrument: rate_table, angle: -36.4 deg}\n" \
        "  - rate_steps: {instrument: rate_table, rates: [2 deg/s, 1 deg/s], alternate: true, settle: 2 s, dwell: 20 s, record: acs_board, axis: z}\n" \
        "  - check: {name: sf, signal: acs_board.gyro.z, statistic: scale_factor_error, window: \"rate_*\", min: -1 %, max: 1 %}\n" \
        "  - check: {name: air, signal: tvac.air_temp, statistic: mean, window: rate_+2, min: 24 degC, max: 26 degC}\n" \
        "  - check: {name: tight, signal: acs_board.gyro.z, statistic: std, window: rate_+2, max: 0.001 deg/s}\n"
    result, path, lab, runner = dry_run(tmp_path, text)
    assert result.status == "completed", result.abort_reason
    by_name = {c["name"]: c for c in result.checks}
    assert by_name["sf"]["outcome"] == "passed" and abs(by_name["sf"]["value"]) < 0.01
    assert by_name["air"]["outcome"] == "passed"
    assert by_name["tight"]["outcome"] == "failed"  # white noise 0.022 deg/s cannot be below 0.001
    assert not result.ok  # a failed check fails the run without aborting it
    w = runner.windows.all["rate_+2"]  # statistics only of what the checks name; the rest only seen
    assert set(w.stats) == {"acs_board.gyro.z", "tvac.air_temp"}
    assert {"acs_board.gyro.x", "acs_board.temp", "tvac.air_temp", "rate_table.tilt"} <= set(w.seen)
    with h5py.File(path, "r") as f:
        tvac_rows = f["streams/tvac/monitor/time"].shape[0]
        assert abs(tvac_rows - result.run_time_s) <= 3  # polled at 1 Hz through the whole run
        assert f["streams/rate_table/monitor/tilt"][-1] == pytest.approx(-36.4, abs=0.01)


def test_interlock_trip_aborts_to_the_safe_state_and_keeps_the_data(tmp_path: Path):
    text = HEAD + "interlocks:\n  - {signal: thermocouples.ch101, max: 30 degC, name: mount hot}\nsteps:\n" \
        "  - table_rate: {instrument: rate_table, rate: 3 deg/s}\n" \
        "  - set_temperature: {instrument: tvac, set_point: 60 degC}\n" \
        "  - wait: 3 h\n"
    result, path, lab, runner = dry_run(tmp_path, text)
    assert result.status == "aborted" and "interlock 'mount hot'" in result.abort_reason
    assert result.outcomes[-1].type == "wait" and result.outcomes[-1].outcome == "aborted"
    summary = read_run_summary(path)
    assert summary.status == "aborted" and "mount hot" in summary.abort_reason
    kinds = [e.kind for e in summary.events]
    assert "safe_state" in kinds
    with h5py.File(path, "r") as f:
        rate = f["streams/rate_table/monitor/rate"][:]
        assert rate.size > 100 and abs(rate.max() - 3.0) < 0.01  # data up to the abort is kept
    world = lab.world
    t = lab.clock.now()
    assert world.chamber.set_point_c == 20.0  # chamber went to its safe set point
    assert abs(float(world.table.rotation.commanded_rate_dps([t + 60])[0])) < 1e-9  # table stopped


def test_operator_answers_from_a_file_and_a_no_aborts(tmp_path: Path):
    text = HEAD + "steps:\n  - prompt: {text: \"Mount the unit\", id: mount}\n  - prompt: {text: \"Close the chamber\", id: close}\n"
    answers = tmp_path / "answers.yaml"
    answers.write_text("mount: yes\nclose: no\n")
    result, path, _, _ = dry_run(tmp_path, text, Operator.from_file(answers))
    assert result.status == "aborted" and "answered 'no' at prompt 'close'" in result.abort_reason
    ops = [e for e in read_run_summary(path).events if e.kind == "operator"]
    assert len(ops) == 2 and '"source": "file"' in ops[0].message
    with pytest.raises(InputError, match="needs an answer"):
        Operator().ask("x", "text", simulated=False)


def test_pause_holds_timed_steps_but_keeps_watching(tmp_path: Path):
    text = HEAD + "steps:\n  - wait: 100 s\n"
    cfg = load_config(SIM_CONFIG)
    proc = parse_procedure(text, str(tmp_path / "p.yaml"))
    rec = RunRecorder.create(tmp_path / "runs", procedure_name="t", procedure_text=text, procedure_path="p.yaml",
                             config_text=cfg.text, config_path=str(SIM_CONFIG), mode="sim", software_version="test", flush_interval_s=1.0)
    lab = open_lab(cfg, proc.instruments, sim=True, realtime=False)
    runner = Runner(proc, lab, rec, QuietProgress())
    runner.toggle_pause()
    resume = threading.Timer(0.5, runner.toggle_pause)
    resume.start()
    try:
        t0 = time.monotonic()
        result = runner.run()
    finally:
        resume.join()
        lab.close()
    assert time.monotonic() - t0 >= 0.45
    assert result.status == "completed"
    # paused time is not counted: the wait still takes its 100 s; on a virtual clock the pause itself
    # takes no run time (issue 30: a paused dry-run stands still instead of racing on)
    assert result.outcomes[0].t_end_s - result.outcomes[0].t_start_s == pytest.approx(100.0, abs=5.0)
    kinds = [e.kind for e in read_run_summary(rec.path).events]
    assert "pause" in kinds and "resume" in kinds


# ---- CLI ------------------------------------------------------------------------------------------
def test_validate_and_plan_cli(tmp_path: Path):
    good = tmp_path / "good.yaml"
    good.write_text(HEAD + "parameters: {sp: 30 degC}\nsteps:\n  - set_temperature: {instrument: tvac, set_point: $sp}\n"
                    "  - rate_steps: {instrument: rate_table, rates: [1 deg/s], dwell: 10 s, record: acs_board}\n")
    r = run_cli("validate", str(good), "--config", str(SIM_CONFIG))
    assert r.returncode == 0 and "valid (4 steps" in r.stdout, r.stdout + r.stderr
    r = run_cli("validate", str(good), "-p", "sp=150degC")
    assert r.returncode == 2 and "good.yaml:6:5:" in r.stderr and "150 degC is outside" in r.stderr and "Traceback" not in r.stderr
    r = run_cli("plan", str(good), env={**os.environ, "COLUMNS": "200"})
    assert r.returncode == 0 and "record at +1 deg/s" in r.stdout and "0:00:10" in r.stdout
    r = run_cli("validate", str(good), "-p", "nonsense")
    assert r.returncode == 2 and "expected NAME=VALUE" in r.stderr


def test_run_refuses_an_unanswerable_prompt_on_hardware(tmp_path: Path):
    proc = tmp_path / "p.yaml"
    proc.write_text("schema: bench-procedure/1\nname: p\ninstruments: [acs_board]\nsteps:\n  - prompt: {text: \"Mount it\", id: mount}\n")
    hw = tmp_path / "hw.yaml"
    hw.write_text(SIM_CONFIG.read_text().replace("mode: sim", "mode: hardware").replace("sensor_model: sensors/", f"sensor_model: {SIM_CONFIG.parent}/sensors/"))
    r = run_cli("run", str(proc), "--config", str(hw), "--runs-dir", str(tmp_path / "runs"), stdin=subprocess.DEVNULL)
    assert r.returncode == 2 and "p.yaml:5:5:" in r.stderr and "needs an operator" in r.stderr
    assert not (tmp_path / "runs").exists() or not list((tmp_path / "runs").glob("*.h5"))  # nothing started


def test_windows_fold_only_the_watched_signals_with_the_same_statistics():
    from bench.runner.windows import Windows

    every, watched = Windows(), Windows({"a.x"})
    rng = np.random.default_rng(3)
    for ws in (every, watched):
        ws.start("w", 0.0)
    for k in range(5):
        t = k + np.arange(10) / 10.0
        y = rng.normal(size=10)
        for ws in (every, watched):
            ws.feed("a.x", t, y)
            ws.feed("b.y", t, 2 * y)
            ws.feed_one("c.z", float(k), float(y[0]))
    for stat in ("mean", "std", "min", "max", "slope", "count"):
        assert watched.statistic("a.x", stat, "w") == every.statistic("a.x", stat, "w")
    assert every.statistic("b.y", "mean", "w")[0] == pytest.approx(2 * every.statistic("a.x", "mean", "w")[0])
    with pytest.raises(ValueError, match=r"window 'w' has no b.y data \(signals: a.x, b.y, c.z\)"):
        watched.statistic("b.y", "mean", "w")
