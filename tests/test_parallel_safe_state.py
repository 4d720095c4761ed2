"""Safe state in parallel (issue 21): on an abort every instrument is told at once, the moving axes
first, each within its own deadline; one instrument's reconnection or hang delays no other; what
each was told and when it confirmed (or that its deadline passed) is recorded."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest

from bench.clock import VirtualClock, WallClock
from bench.config import load_config
from bench.kinds import registry


def SAFE(kind: str) -> float:
    """The kind's default safe-state deadline (s)."""
    return registry.get(kind).safe_state_timeout_s
from bench.errors import InputError, InputErrors
from bench.faults import parse_fault_spec
from bench.lab import Lab, open_lab
from bench.procedure import parse_procedure
from bench.record import RunRecorder, read_run_summary
from bench.runner import Runner
from bench.runner.operator import Operator
from bench.runner.session import start_run
from tests.conftest import SIM_CONFIG


class Quiet:
    """A progress sink that keeps the messages; ``abort_at``: (run time s, runner) to stop the run."""

    def __init__(self, abort_at: float | None = None):
        self.messages: list[str] = []
        self.abort_at = abort_at
        self.runner: Runner | None = None

    def start(self, procedure, total_s): ...
    def step(self, n, total, step): ...
    def stop(self, run_time_s): ...

    def advance(self, run_time_s, readings=""):
        if self.abort_at is not None and run_time_s >= self.abort_at and self.runner is not None:
            self.runner.request_abort("test stop")

    def message(self, text):
        self.messages.append(text)


def outcome_events(summary, name: str):
    """The events that end ``name``'s safe state (``safe_state`` or ``error`` with the timing data)."""
    return [e for e in summary.events if e.source == name and e.kind in ("safe_state", "error") and e.data.startswith(b"{")]


def the_abort(summary):
    (abort,) = [e for e in summary.events if e.kind == "abort"]
    return abort


# ---- the measured case: the chamber unreachable while the table spins ------------------------------------
SPIN = """schema: bench-procedure/1
name: spin_while_the_chamber_link_drops
instruments: [tvac, rate_table]
steps:
  - table_rate: {instrument: rate_table, rate: 20 deg/s}
  - wait: 1 s
  - set_temperature: {instrument: tvac, set_point: 30 degC}
  - wait: 60 s
"""


def test_the_table_stops_within_its_deadline_while_the_chamber_is_unreachable(tmp_path: Path):
    cfg = load_config(SIM_CONFIG)
    proc = parse_procedure(SPIN, str(tmp_path / "p.yaml"), kinds=cfg.kinds(), config_limits=cfg.limits())
    progress = Quiet()
    session = start_run(proc, cfg, procedure_path=tmp_path / "p.yaml", config_path=SIM_CONFIG, runs_dir=tmp_path / "runs",
                        sim=True, realtime=False, operator=Operator(None, None), progress=progress,
                        fault_spec=parse_fault_spec("modbus_disconnect@3s/25s"))
    try:
        result = session.runner.run()
    finally:
        session.lab.close()
    assert result.status == "aborted" and "tvac" in result.abort_reason
    summary = read_run_summary(session.recorder.path)
    assert summary.status == "aborted"
    abort = the_abort(summary)
    # the table: told at the abort, its stop confirmed within its own deadline (run time and wall time)
    (table,) = [e for e in summary.events if e.kind == "safe_state" and e.source == "rate_table"]
    assert "quick stop" in table.message
    assert 0 < table.t_s - abort.t_s <= SAFE("rate_table")
    assert table.wall_unix - abort.wall_unix <= SAFE("rate_table")
    data = json.loads(table.data)
    assert data["outcome"] == "confirmed" and data["deadline_s"] == SAFE("rate_table")
    assert data["t_told_s"] == pytest.approx(abort.t_s) and data["t_end_s"] == pytest.approx(table.t_s)
    # the chamber: its safe state was attempted through a reconnection, and how it ended is recorded
    (chamber,) = outcome_events(summary, "tvac")
    cdata = json.loads(chamber.data)
    assert cdata["outcome"] in ("confirmed", "failed", "missed") and cdata["deadline_s"] == SAFE("tvac")
    assert chamber.t_s - abort.t_s <= cdata["deadline_s"]
    assert any(e.kind == "fault" and e.source == "tvac" and "safe state" in e.message for e in summary.events)
    assert table.t_s < chamber.t_s  # the table did not wait for the chamber's reconnection
    # shown as it happened
    assert any(m.startswith("rate_table: ") and "confirmed" in m for m in progress.messages)
    assert any(m.startswith("tvac: ") and "deadline" in m for m in progress.messages)


# ---- an instrument that hangs past its deadline ----------------------------------------------------------
class Hanging:
    """An instrument whose safe state hangs (a driver stuck on a dead link) until released."""

    kind = "hanging"
    streams = False
    baudrate = None

    def __init__(self, hang_s: float = 30.0):
        self.release = threading.Event()
        self.hang_s = hang_s

    def identify(self) -> dict[str, str]:
        return {"model": "hanging"}

    def safe_state(self) -> str:
        self.release.wait(self.hang_s)
        return "released"

    def close(self) -> None:
        self.release.set()


class Quick(Hanging):
    kind = "quick"

    def safe_state(self) -> str:
        return "off"


def run_with_hanging(tmp_path: Path, lab: Lab, instruments: str, steps: str, abort_at: float):
    text = f"schema: bench-procedure/1\nname: hang\ninstruments: {instruments}\nsteps:\n{steps}"
    proc = parse_procedure(text, str(tmp_path / "p.yaml"))
    rec = RunRecorder.create(tmp_path / "runs", procedure_name="hang", procedure_text=text, procedure_path="p.yaml",
                             config_text="", config_path="cfg.yaml", mode="sim", software_version="test", flush_interval_s=1.0)
    progress = Quiet(abort_at)
    runner = Runner(proc, lab, rec, progress)
    progress.runner = runner
    wall0 = time.monotonic()
    try:
        result = runner.run()
    finally:
        lab.close()
    return result, read_run_summary(rec.path), time.monotonic() - wall0


def add_hanging(lab: Lab, hanging: Hanging, deadline_s: float) -> None:
    """Put ``hanging`` first in the lab (the old sequential abort path would have waited for it first)."""
    lab.instruments = {"hanging": hanging, **lab.instruments}
    lab.ports["hanging"] = "test://hanging"
    lab.kinds["hanging"] = hanging.kind
    lab.safe_state_timeouts["hanging"] = deadline_s


def test_a_safe_state_hanging_past_its_deadline_delays_no_other_in_virtual_time(tmp_path: Path):
    cfg = load_config(SIM_CONFIG)
    lab = open_lab(cfg, ["rate_table"], sim=True, realtime=False)
    hanging = Hanging()
    add_hanging(lab, hanging, 0.5)
    steps = "  - table_rate: {instrument: rate_table, rate: 20 deg/s}\n  - wait: 60 s\n"
    result, summary, wall_s = run_with_hanging(tmp_path, lab, "[rate_table]", steps, abort_at=10.0)
    assert result.status == "aborted" and result.abort_reason == "test stop"
    assert summary.status == "aborted"  # the run file closed, finalised
    assert wall_s < 15  # the hang (30 s) was not waited for
    abort = the_abort(summary)
    (table,) = outcome_events(summary, "rate_table")
    assert table.kind == "safe_state" and json.loads(table.data)["outcome"] == "confirmed"
    assert table.t_s - abort.t_s <= SAFE("rate_table") and table.wall_unix - abort.wall_unix < 5
    (hung,) = outcome_events(summary, "hanging")
    data = json.loads(hung.data)
    assert hung.kind == "error" and data["outcome"] == "missed" and "not confirmed within its deadline 0.5 s" in hung.message
    assert 0.5 <= data["wall_s"] < 5


def test_a_safe_state_hanging_past_its_deadline_delays_no_other_on_the_wall_clock(tmp_path: Path):
    clock = WallClock()
    hanging, quick = Hanging(), Quick()
    lab = Lab(clock, "sim", {"quick": quick}, {"quick": "test://quick"}, kinds={"quick": "quick"})
    add_hanging(lab, hanging, 0.3)
    result, summary, wall_s = run_with_hanging(tmp_path, lab, "[quick]", "  - wait: 5 s\n", abort_at=0.2)
    assert result.status == "aborted" and summary.status == "aborted"
    assert wall_s < 3
    abort = the_abort(summary)
    (q,) = outcome_events(summary, "quick")
    assert q.kind == "safe_state" and q.message.startswith("off; confirmed") and q.wall_unix - abort.wall_unix < 0.3
    (hung,) = outcome_events(summary, "hanging")
    assert json.loads(hung.data)["outcome"] == "missed" and 0.3 <= hung.wall_unix - abort.wall_unix < 2


def test_moving_axes_are_told_first(tmp_path: Path):
    from bench.runner.safe_state import safe_state_order

    kinds = {"tvac": "tvac", "board": "acs_board", "table": "rate_table", "bench": "stepper_bench"}
    assert safe_state_order(list(kinds), kinds) == ["table", "bench", "tvac", "board"]


# ---- the virtual clock in lockstep -----------------------------------------------------------------------
def test_a_long_wait_in_lockstep_does_not_jump_time_under_a_short_one():
    """A reconnection's 8-s backoff and a table's 50-ms polls in two threads: every poll sees run
    time move by exactly its own wait (unshared, the backoff would jump run time under it)."""
    clock = VirtualClock(100.0)
    seen: list[float] = []

    def table():
        for _ in range(40):
            before = clock.now()
            clock.sleep(0.05)
            seen.append(clock.now() - before)

    def chamber():
        clock.sleep(0.5)
        clock.sleep(8.0)

    threads = [threading.Thread(target=table, daemon=True), threading.Thread(target=chamber, daemon=True)]
    for th in threads:
        clock.enrol(th)
    for th in threads:
        th.start()
    deadline = time.monotonic() + 10
    while any(th.is_alive() for th in threads) and time.monotonic() < deadline:
        clock.advance_lockstep(0.002)
        clock.release()
        for th in threads:
            if not th.is_alive():
                clock.leave(th)
    assert not any(th.is_alive() for th in threads)
    assert len(seen) == 40 and max(seen) == pytest.approx(0.05, abs=0.02)  # busy time may add a little, never the 8 s
    assert 108.5 <= clock.now() < 108.6  # both waits whole: the backoff was not cut short either


# ---- the config key ---------------------------------------------------------------------------------------
CONFIG = """\
schema: bench-config/1
name: deadlines
mode: sim
instruments:
  table:
    driver: rate_table
    port: can://virtual/x?node=1
{extra}  tvac:
    driver: tvac
    port: modbus-tcp://127.0.0.1:5020
    gauge_port: /dev/null
"""


def test_safe_state_timeout_is_read_per_instrument_with_a_default_per_kind(tmp_path: Path):
    path = tmp_path / "lab.yaml"
    path.write_text(CONFIG.format(extra="    safe_state_timeout: 2.5 s\n"))
    cfg = load_config(path)
    assert cfg.instruments["table"].safe_state_timeout_s == 2.5
    assert cfg.instruments["tvac"].safe_state_timeout_s == SAFE("tvac")


@pytest.mark.parametrize("bad, says", [("0 s", "between 0.1 s and 300 s"), ("1 h", "between 0.1 s and 300 s"),
                                       ("fast", "safe_state_timeout")])
def test_a_bad_safe_state_timeout_is_refused_at_its_key(tmp_path: Path, bad: str, says: str):
    path = tmp_path / "lab.yaml"
    path.write_text(CONFIG.format(extra=f"    safe_state_timeout: {bad}\n"))
    with pytest.raises((InputError, InputErrors)) as exc:
        load_config(path)
    text = str(exc.value)
    assert text.startswith(f"{path}:8:") and says in text, text
