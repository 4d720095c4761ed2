"""Link faults during a run: reconnect with backoff and a recorded gap, or abort when it lasts."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from bench.config import load_config
from bench.lab import open_lab
from bench.procedure import parse_procedure
from bench.record import RunRecorder, read_run_summary
from bench.runner import Runner
from tests.conftest import SIM_CONFIG


class FaultAt:
    """A progress sink that injects faults at given run times (the runner reports run time to it
    at every drain period): ``[(t_s, callable)]``."""

    def __init__(self, schedule):
        self.schedule = sorted(schedule, key=lambda x: x[0])
        self.messages: list[str] = []

    def start(self, procedure, total_s): ...
    def step(self, n, total, step): ...
    def stop(self, run_time_s): ...

    def message(self, text):
        self.messages.append(text)

    def advance(self, run_time_s, readings=""):
        while self.schedule and run_time_s >= self.schedule[0][0]:
            self.schedule.pop(0)[1]()


def run(tmp_path: Path, steps: str, instruments: str, schedule_for, config_text: str | None = None):
    text = f"schema: bench-procedure/1\nname: faults\ninstruments: {instruments}\nsteps:\n{steps}"
    cfg_path = SIM_CONFIG
    if config_text is not None:
        cfg_path = tmp_path / "cfg.yaml"
        cfg_path.write_text(config_text.replace("sensor_model: sensors/", f"sensor_model: {SIM_CONFIG.parent}/sensors/"))
    cfg = load_config(cfg_path)
    proc = parse_procedure(text, str(tmp_path / "p.yaml"))
    rec = RunRecorder.create(tmp_path / "runs", procedure_name="faults", procedure_text=text, procedure_path="p.yaml",
                             config_text=cfg.text, config_path=str(cfg_path), mode="sim", software_version="test", flush_interval_s=1.0)
    lab = open_lab(cfg, proc.instruments, sim=True, realtime=False)
    progress = FaultAt(schedule_for(lab))
    try:
        result = Runner(proc, lab, rec, progress).run()
    finally:
        lab.close()
    return result, rec.path, progress


def events(path: Path, kind: str):
    return [e for e in read_run_summary(path).events if e.kind == kind]


def test_thermocouple_unplugged_for_a_while_is_a_recorded_gap(tmp_path: Path):
    def schedule(lab):
        link = lab.sims["thermocouples"].serial[""]
        return [(20.0, lambda: link.inject("disconnect", duration_s=6.0))]

    result, path, progress = run(tmp_path, "  - wait: 60 s\n", "[thermocouples]", schedule)
    assert result.status == "completed", result.abort_reason
    (fault,), (gap,) = events(path, "fault"), events(path, "gap")
    assert fault.source == "thermocouples" and "disconnected" in fault.message
    assert 5.0 <= gap.t_s - fault.t_s <= 6.0 + 8.0
    with h5py.File(path, "r") as f:
        t = f["streams/thermocouples/monitor/time"][:]
    assert not np.any((t > fault.t_s + 0.01) & (t < gap.t_s - 0.01))  # no rows inside the gap
    assert t[-1] >= 59.0  # logging resumed
    assert any("link restored" in m for m in progress.messages)


def test_board_link_glitch_during_a_recording_keeps_the_stream(tmp_path: Path):
    def schedule(lab):
        link = lab.sims["acs_board"].serial[""]
        return [(30.0, lambda: link.inject("disconnect", duration_s=12.0))]  # longer than a drain period (5 s)

    steps = "  - power: {instrument: acs_board, on: true}\n  - record: {instrument: acs_board, duration: 60 s, window: w}\n"
    result, path, _ = run(tmp_path, steps, "[acs_board]", schedule)
    assert result.status == "completed", result.abort_reason
    (gap,) = events(path, "gap")
    with h5py.File(path, "r") as f:
        t = f["streams/acs_board/time"][:]
        counter = f["streams/acs_board/counter"][:].astype(int)
    missing = np.diff(counter) % 65536 - 1
    assert missing.sum() > 100  # frames sent while unplugged are lost, and counted by their counters
    assert t[-1] >= 59.9 and np.sum(t > gap.t_s) > 1500  # streaming went on after the reconnection


def test_chamber_controller_dropping_connections_is_reconnected(tmp_path: Path):
    def schedule(lab):
        server = lab.sims["tvac"].device
        return [(15.0, lambda: server.inject("disconnect")), (25.0, server.clear_faults)]

    result, path, _ = run(tmp_path, "  - wait: 60 s\n", "[tvac]", schedule)
    assert result.status == "completed", result.abort_reason
    assert events(path, "fault") and events(path, "gap")


def test_a_link_that_does_not_come_back_aborts_to_the_safe_state(tmp_path: Path):
    def schedule(lab):
        link = lab.sims["stepper_bench"].serial[""]
        return [(10.0, lambda: link.inject("disconnect"))]

    config = SIM_CONFIG.read_text().replace("    max_rate: 3.5 deg/s", "    reconnect_timeout: 10 s\n    max_rate: 3.5 deg/s", 1)
    assert "reconnect_timeout: 10 s" in config
    result, path, _ = run(tmp_path, "  - wait: 120 s\n", "[stepper_bench]", schedule, config)
    assert result.status == "aborted" and "not restored within 10 s" in result.abort_reason
    assert read_run_summary(path).status == "aborted"
    assert result.run_time_s < 40


def test_a_fault_the_instrument_reports_is_not_retried(tmp_path: Path):
    def schedule(lab):
        server = lab.sims["tvac"].device
        return [(10.0, lambda: server.inject("open_sensor"))]

    result, path, _ = run(tmp_path, "  - wait: 60 s\n", "[tvac]", schedule)
    assert result.status == "aborted" and "input error" in result.abort_reason
    assert not events(path, "gap")
