"""Defects a new technician found on the simulated lab (issue 17, part 3).

1. a run waiting at an operator prompt read ``crashed`` (no heartbeat while the prompt blocked);
2. a check without limits reported ``passed`` ("all checks passed" without any verdict);
3. ``bench plan`` gave no time for the chamber's waits (3:42:46 planned, 6:25:54 run);
4. prompts did not list the accepted answers and a typo (``maybe``) aborted the run;
5. ``bench inspect`` listed only poll traffic (``read 104``, ``PR1``) and no checks;
6. no ``--json`` on ``run`` and ``inspect``;
7. ``bench watch`` at 80 columns dropped units and cut values.
"""

from __future__ import annotations

import json
import os
import pty
import re
import sys
import threading
import time
from pathlib import Path

import pytest
from rich.console import Console

from bench.config import load_config
from bench.procedure import load_procedure
from bench.record import read_run_summary
from bench.runner import Runner
from bench.runner.operator import Operator
from bench.runner.session import start_run
from bench.watch import build, format_value, render, snapshot
from tests.conftest import ROOT, SIM_CONFIG, run_cli

CHAMBER_HEAD = "schema: bench-procedure/1\nname: {name}\ninstruments: [acs_board, tvac, thermocouples]\n"
STALE_S = 1.5
"""Heartbeat age (s) from which the tests' readers call a run crashed (the CLI uses 10 s)."""
FLUSH_S = 0.2
"""Flush interval (s of wall time) of the tests' in-process runs."""


class RecordingProgress:
    """A quiet progress sink that keeps every message."""

    def __init__(self) -> None:
        self.messages: list[str] = []

    def start(self, procedure, total_s: float) -> None: ...

    def step(self, n: int, total: int, step) -> None: ...

    def advance(self, run_time_s: float, readings: str = "") -> None: ...

    def message(self, text: str) -> None:
        self.messages.append(text)

    def stop(self, run_time_s: float) -> None: ...


def _runner(tmp_path: Path, text: str, operator: Operator | None) -> tuple[Runner, RecordingProgress, object]:
    """A run of procedure ``text`` on the simulated lab (virtual clock) as ``bench run`` starts it
    (instrument traffic recorded), flushing every FLUSH_S: (runner, progress, lab)."""
    proc_path = tmp_path / "proc.yaml"
    proc_path.write_text(text)
    cfg = load_config(SIM_CONFIG)
    cfg.flush_interval_s = FLUSH_S
    procedure = load_procedure(proc_path, kinds=cfg.kinds(), config_limits=cfg.limits())
    progress = RecordingProgress()
    session = start_run(procedure, cfg, procedure_path=proc_path, config_path=SIM_CONFIG, runs_dir=tmp_path / "runs", sim=True,
                        realtime=False, operator=operator or Operator(None, None), progress=progress)
    return session.runner, progress, session.lab


@pytest.fixture
def terminal(monkeypatch):
    """The operator's terminal: stdin is a pseudo-terminal; returns the write end (what the operator types)."""
    master, slave = pty.openpty()
    stdin = os.fdopen(slave, "r", buffering=1, closefd=True)
    monkeypatch.setattr(sys, "stdin", stdin)
    yield master
    stdin.close()
    os.close(master)


def _operator_events(path: Path) -> list[dict]:
    return [json.loads(e.message) for e in read_run_summary(path).events if e.kind == "operator"]


# ---- 1 and 4: prompts -------------------------------------------------------------------------------
PROMPT_PROCEDURE = CHAMBER_HEAD.format(name="door") + (
    "steps:\n"
    "  - wait: 30 s\n"
    "  - prompt: {text: \"Close the chamber door\", id: door}\n"
    "  - wait: 30 s\n"
)


def test_prompt_keeps_the_heartbeat_reads_waiting_and_asks_again_after_a_typo(tmp_path: Path, terminal: int) -> None:
    runner, progress, lab = _runner(tmp_path, PROMPT_PROCEDURE, Operator(None, Operator.terminal()))
    path = runner.rec.path
    seen: dict[str, object] = {}

    def operator_at_the_terminal() -> None:
        time.sleep(STALE_S + 1.0)  # longer than a stale heartbeat: the prompt must keep it fresh
        seen["summary"] = read_run_summary(path, stale_after_s=STALE_S)
        seen["watch"] = snapshot(path, stale_after_s=STALE_S)
        os.write(terminal, b"maybe\n")
        try:  # wait for the typo in the run file and the question asked again (a second prompt event)
            deadline = time.monotonic() + 30.0
            while time.monotonic() < deadline and "after_typo" not in seen:
                summary = read_run_summary(path, stale_after_s=STALE_S)
                typo = any(json.loads(e.message).get("answer") == "maybe" for e in summary.events if e.kind == "operator")
                if typo and sum(e.kind == "prompt" for e in summary.events) == 2:
                    seen["after_typo"] = summary
                time.sleep(0.05)
        finally:
            os.write(terminal, b"yes\n")

    person = threading.Thread(target=operator_at_the_terminal)
    person.start()
    try:
        result = runner.run()
    finally:
        person.join()
        lab.close()

    summary = seen["summary"]
    assert (summary.status, summary.live_status) == ("running", "waiting"), (summary.status, summary.status_detail)
    assert "waiting for operator: Close the chamber door" in summary.status_detail
    state = seen["watch"]
    assert state.status == "waiting" and "waiting for operator: Close the chamber door" in state.status_detail
    console = Console(record=True, width=100)
    console.print(build(state))
    assert "waiting for operator: Close the chamber door" in console.export_text()
    assert "after_typo" in seen, "no invalid answer and second question in the run file within 30 s"
    assert seen["after_typo"].live_status == "waiting"  # asked again, still waiting

    assert result.status == "completed", result.abort_reason
    assert any("Close the chamber door" in m and "[yes/no; no aborts the run]" in m for m in progress.messages), progress.messages
    assert any("'maybe' is not an accepted answer" in m and "yes, no" in m for m in progress.messages), progress.messages
    answers = _operator_events(path)
    assert [(a["answer"], a["valid"]) for a in answers] == [("maybe", False), ("yes", True)]
    final = read_run_summary(path)
    assert final.status == "completed" and sum(e.kind == "prompt" for e in final.events) == 2


def test_typos_never_abort_and_a_typed_no_is_confirmed_first(tmp_path: Path, terminal: int) -> None:
    """Issue 30 item 2: three typos aborted the run, and "no" aborted it without a word beforehand.
    Now typos are asked again (until the prompt's timeout), the question says that no aborts, and a
    typed "no" stops the run only once the person types 'abort'."""
    runner, progress, lab = _runner(tmp_path, PROMPT_PROCEDURE, Operator(None, Operator.terminal()))
    os.write(terminal, b"maybe\nperhaps\nsure?\nyse\nno\nkeep going\nno\nabort\n")
    try:
        result = runner.run()
    finally:
        lab.close()
    assert result.status == "aborted"
    assert "answered 'no' at prompt 'door'" in result.abort_reason, result.abort_reason
    events = _operator_events(runner.rec.path)
    assert [a.get("answer") for a in events if "answer" in a] == ["maybe", "perhaps", "sure?", "yse", "no", "no"]
    assert [(a["confirm_abort"], a["confirmed"]) for a in events if "confirm_abort" in a] == [("keep going", False), ("abort", True)]
    assert any("stops the run" in m and "'abort'" in m for m in progress.messages), progress.messages
    assert any("not stopped; asking 'door' again" in m for m in progress.messages), progress.messages


def test_prompt_times_out_with_the_reason(tmp_path: Path, terminal: int) -> None:
    text = PROMPT_PROCEDURE.replace("id: door}", "id: door, timeout: 1 s}")
    runner, _, lab = _runner(tmp_path, text, Operator(None, Operator.terminal()))
    t0 = time.monotonic()
    try:
        result = runner.run()
    finally:
        lab.close()
    assert 0.9 <= time.monotonic() - t0 < 10.0
    assert result.status == "aborted" and "no answer at prompt 'door' within 1 s" in result.abort_reason, result.abort_reason


def test_an_answers_file_with_an_unaccepted_answer_is_bad_input(tmp_path: Path) -> None:
    proc = tmp_path / "door.yaml"
    proc.write_text(PROMPT_PROCEDURE)
    answers = tmp_path / "answers.yaml"
    answers.write_text("door: maybe\n")
    r = run_cli("run", str(proc), "--config", str(SIM_CONFIG), "--answers", str(answers), "--runs-dir", str(tmp_path / "runs"))
    assert r.returncode == 2, r.stdout + r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{answers}:1:7: door: ") and "'maybe'" in lines[0] and "yes, no" in lines[0]
    assert not (tmp_path / "runs").exists() or not list((tmp_path / "runs").glob("*.h5"))


# ---- 2, 5, 6, 7: checks, inspect, JSON, 80 columns -----------------------------------------------------
CHECKS_PROCEDURE = CHAMBER_HEAD.format(name="checks") + (
    "steps:\n"
    "  - power: {instrument: acs_board, on: true}\n"
    "  - set_temperature: {instrument: tvac, set_point: 25 degC}\n"
    "  - record: {instrument: acs_board, duration: 20 s, window: w}\n"
    "  - check: {name: mean_z, signal: acs_board.gyro.z, statistic: mean, window: w}\n"
    "  - check: {name: mount_min, signal: thermocouples.ch101, statistic: min, window: w}\n"
    "  - check: {name: air_slope, signal: tvac.air_temp, statistic: slope, window: w}\n"
)


@pytest.fixture(scope="module")
def checks_run(tmp_path_factory) -> Path:
    """The run file of a dry-run of CHECKS_PROCEDURE, whose three checks have no limits."""
    runner, _, lab = _runner(tmp_path_factory.mktemp("checks"), CHECKS_PROCEDURE, None)
    try:
        result = runner.run()
    finally:
        lab.close()
    assert result.status == "completed", result.abort_reason
    return runner.rec.path


def test_checks_without_limits_are_recorded_not_passed(tmp_path: Path) -> None:
    proc = tmp_path / "checks.yaml"
    proc.write_text(CHECKS_PROCEDURE)
    r = run_cli("run", str(proc), "--config", str(SIM_CONFIG), "--runs-dir", str(tmp_path / "runs"))
    assert r.returncode == 0, r.stdout + r.stderr
    text = " ".join(r.stdout.split())
    assert "3 checks recorded without limits; no verdict" in text, r.stdout
    assert "all checks passed" not in text and "passed" not in text
    summary = read_run_summary(next((tmp_path / "runs").glob("*.h5")))
    assert [s.outcome for s in summary.steps if s.type == "check"] == ["recorded"] * 3


def test_a_check_with_limits_still_passes_or_fails(tmp_path: Path) -> None:
    text = CHECKS_PROCEDURE.replace("window: w}\n  - check: {name: mount_min", "window: w, max: 1 deg/s}\n  - check: {name: mount_min") \
        .replace("statistic: slope, window: w}", "statistic: slope, window: w, min: 1}")
    runner, _, lab = _runner(tmp_path, text, None)
    try:
        result = runner.run()
    finally:
        lab.close()
    assert [(c["name"], c["outcome"]) for c in result.checks] == [("mean_z", "passed"), ("mount_min", "recorded"), ("air_slope", "failed")]
    assert not result.ok and result.status == "completed"


def test_run_json_is_the_run_result(tmp_path: Path) -> None:
    proc = tmp_path / "checks.yaml"
    proc.write_text(CHECKS_PROCEDURE)
    r = run_cli("run", str(proc), "--config", str(SIM_CONFIG), "--runs-dir", str(tmp_path / "runs"), "--json")
    assert r.returncode == 0, r.stdout + r.stderr
    out = json.loads(r.stdout)  # stdout is exactly one JSON object; progress went to stderr
    path = Path(out["run_file"])
    assert out["status"] == "completed" and out["exit_code"] == 0 and path.exists()
    assert out["checks_summary"] == {"passed": 0, "failed": 0, "recorded": 3,
                                     "verdict": "3 checks recorded without limits; no verdict"}
    check = {c["name"]: c for c in out["checks"]}["mean_z"]
    assert check["outcome"] == "recorded" and check["units"] == "deg/s" and check["min"] is None
    assert [s["outcome"] for s in out["steps"]][:3] == ["done", "done", "done"]
    assert abs(out["streams"]["acs_board"]["rows"] - 2000) <= 2


def test_inspect_summarises_poll_traffic_and_lists_checks(checks_run) -> None:
    path = checks_run
    r = run_cli("inspect", str(path), env={**os.environ, "COLUMNS": "160"})
    assert r.returncode == 0, r.stderr
    text = r.stdout
    summary = read_run_summary(path)
    polls = next(s.rows for s in summary.streams if s.key == "tvac/monitor")
    commands = sum(1 for e in summary.events if e.kind == "command" and e.source == "tvac")
    replies = sum(1 for e in summary.events if e.kind == "reply" and e.source == "tvac")
    assert re.search(rf"tvac: {polls:,} polls, {commands:,} commands, {replies:,} replies, last at 0:00:20", text), text
    assert "read 104" not in text and "PR1" not in text  # poll traffic is summarised, not listed
    for kind in ("run_start", "step_start", "check", "step_end", "run_end"):
        assert kind in text
    checks = text[text.index("Checks"):]
    assert re.search(r"mean_z .* deg/s .* none .* recorded", checks), checks
    assert re.search(r"air_slope .* degC/s .* none .* recorded", checks), checks


def test_inspect_json(checks_run) -> None:
    path = checks_run
    r = run_cli("inspect", str(path), "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["status"] == "completed" and out["waiting_for"] is None and out["procedure"]["name"] == "checks"
    assert {"unit_serial", "station"} <= set(out["identity"])
    streams = {s["key"]: s for s in out["streams"]}
    assert streams["tvac/monitor"]["columns"]["pressure"]["units"] == "Torr" and abs(streams["acs_board"]["rows"] - 2000) <= 2
    assert [s["type"] for s in out["steps"]] == ["power", "set_temperature", "record", "check", "check", "check"]
    assert [c["outcome"] for c in out["checks"]] == ["recorded"] * 3 and out["checks"][0]["units"] == "deg/s"
    assert out["checks_summary"]["recorded"] == 3
    ev = out["events"]
    assert ev["traffic"]["tvac"]["commands"] > 0 and ev["traffic"]["tvac"]["polls"] == streams["tvac/monitor"]["rows"]
    assert ev["by_kind"]["command"] == sum(t["commands"] for t in ev["traffic"].values())
    assert all(e["kind"] not in ("command", "reply") for e in ev["recent"])


def test_watch_at_80_columns_keeps_units_and_whole_values(checks_run) -> None:
    path = checks_run
    state = snapshot(path)
    console = Console(record=True, width=80)
    render(state, console)
    text = console.export_text()
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= 80
    assert "…" not in text[: text.index("events (instrument traffic summarised below)")]  # nothing cut in the readings
    for stream in state.streams:
        assert f"{stream.rows:,} rows" in text
        for sig in stream.signals:
            value = re.escape(format_value(sig.value, sig.integer, sig.column))
            units = re.escape(sig.units) if sig.units not in ("", "1") else ""
            assert re.search(rf"\s{value}\s+{units}\s", text), (sig.label, sig.units, text)
    assert "poll" in text  # the traffic summary, not the traffic


# ---- 3: plan estimates ---------------------------------------------------------------------------------
PLAN_PROCEDURE = "schema: bench-procedure/1\nname: plan_check\ninstruments: [tvac, thermocouples]\n" + (
    "steps:\n"
    "  - set_temperature: {instrument: tvac, set_point: 45 degC, wait: true}\n"
    "  - wait_until_stable: {signal: thermocouples.ch101, band: 0.5 degC, hold: 5 min, timeout: 2 h}\n"
    "  - set_temperature: {instrument: tvac, set_point: 5 degC, ramp: 0.4 degC/min}\n"
    "  - wait: 30 min\n"
    "  - wait_until_stable: {signal: thermocouples.ch101, band: 0.5 degC, hold: 5 min, timeout: 4 h}\n"
    "  - pump_down: {instrument: tvac, pressure: 1e-3 Torr}\n"
    "  - set_temperature: {instrument: tvac, set_point: 20 degC, wait: true}\n"
    "  - vent: {instrument: tvac}\n"
)


def _plan_total(stdout: str) -> tuple[str, float]:
    m = re.search(r"estimated procedure time (≥ )?(\d+):(\d\d):(\d\d)", " ".join(stdout.split()))
    assert m, stdout
    return m.group(1) or "", int(m.group(2)) * 3600 + int(m.group(3)) * 60 + int(m.group(4))


def test_plan_estimates_chamber_waits_within_15_percent_of_a_dry_run(tmp_path: Path) -> None:
    proc = tmp_path / "plan_check.yaml"
    proc.write_text(PLAN_PROCEDURE)
    plan = run_cli("plan", str(proc), "--config", str(SIM_CONFIG), env={**os.environ, "COLUMNS": "200"})
    assert plan.returncode == 0, plan.stderr
    bound, estimate = _plan_total(plan.stdout)
    assert bound == ""  # every wait has a model: an estimate, not a lower bound
    runner, _, lab = _runner(tmp_path, PLAN_PROCEDURE, None)
    try:
        result = runner.run()
    finally:
        lab.close()
    assert result.status == "completed", result.abort_reason
    assert estimate == pytest.approx(result.run_time_s, rel=0.15), (estimate, result.run_time_s)


def test_plan_of_the_technicians_procedure_counts_the_chamber() -> None:
    """thermal_ramp_ambient ran 6:25:54 (23154 s) on the simulated lab; the plan said 3:42:46."""
    plan = run_cli("plan", str(ROOT / "procedures" / "thermal_ramp_ambient.yaml"), "--config", str(SIM_CONFIG))
    assert plan.returncode == 0, plan.stderr
    bound, estimate = _plan_total(plan.stdout)
    assert bound == "" and estimate == pytest.approx(23154, rel=0.15)


def test_plan_marks_a_wait_without_a_model_as_a_lower_bound(tmp_path: Path) -> None:
    proc = tmp_path / "table.yaml"
    proc.write_text("schema: bench-procedure/1\nname: table\ninstruments: [rate_table]\nsteps:\n"
                    "  - table_rate: {instrument: rate_table, rate: 5 deg/s, accel: 1 deg/s**2, settle: 10 s}\n"
                    "  - wait_until_stable: {signal: rate_table.rate, band: 0.01 deg/s, hold: 1 min}\n")
    plan = run_cli("plan", str(proc), "--config", str(SIM_CONFIG), env={**os.environ, "COLUMNS": "200"})
    assert plan.returncode == 0, plan.stderr
    bound, estimate = _plan_total(plan.stdout)
    assert bound == "≥ " and estimate == 5 + 10 + 60  # acceleration 5 s, settle, hold
    assert "lower bound" in plan.stdout


def test_the_planners_table_defaults_are_the_drives_eds_defaults() -> None:
    """bench/model/rate_table.py repeats the EDS's profile velocity and acceleration (counts at 0.001 deg/count)."""
    import configparser

    from bench.model.rate_table import TableParams

    eds = configparser.ConfigParser(strict=False)
    eds.read(ROOT / "drivers" / "rate_table.eds")
    counts_per_deg = 1000.0
    assert int(eds["6081"]["DefaultValue"], 0) / counts_per_deg == TableParams().profile_velocity_dps
    assert int(eds["6083"]["DefaultValue"], 0) / counts_per_deg == TableParams().profile_accel_dps2
