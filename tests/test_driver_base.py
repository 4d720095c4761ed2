"""drivers/base.py: one home for timeouts, retries of idempotent reads and the safe state."""

from __future__ import annotations

import inspect
import math

import pytest

from drivers import acs_board, rate_table, stepper_bench, thermocouple_reader, tpg261, tvac, watlow_f4
from drivers.base import Driver, Transient, check_timeout
from drivers.errors import InstrumentError, InstrumentTimeout, ProtocolError

DRIVER_CLASSES = [acs_board.AcsBoard, rate_table.RateTable, stepper_bench.StepperBench,
                  thermocouple_reader.ThermocoupleReader, tpg261.Tpg261, tvac.TvacChamber, watlow_f4.WatlowF4]


class _Reader(Driver):
    read_attempts = 3


def test_a_transient_failure_is_retried_up_to_the_attempts_and_the_last_error_raised() -> None:
    calls, pauses = [], []

    def attempt(i: int) -> str:
        calls.append(i)
        raise Transient(InstrumentTimeout(f"no answer (attempt {i})"), pause_s=0.05)

    with pytest.raises(InstrumentTimeout, match=r"attempt 2"):
        _Reader().read_retrying(attempt, sleep=pauses.append)
    assert calls == [0, 1, 2]
    assert pauses == [0.05, 0.05]  # no pause after the last attempt


def test_a_read_that_succeeds_on_a_later_attempt_returns_its_value() -> None:
    def attempt(i: int) -> int:
        if i < 1:
            raise Transient(InstrumentError("link lost"))
        return 42

    assert _Reader().read_retrying(attempt, sleep=lambda s: None) == 42


def test_other_errors_are_never_retried() -> None:
    calls = []

    def attempt(i: int) -> None:
        calls.append(i)
        raise ProtocolError("NAK")

    with pytest.raises(ProtocolError):
        _Reader().read_retrying(attempt)
    assert calls == [0]


def test_writes_get_one_attempt() -> None:
    calls = []

    def attempt(i: int) -> None:
        calls.append(i)
        raise Transient(InstrumentTimeout("no answer"))

    with pytest.raises(InstrumentTimeout):
        _Reader().read_retrying(attempt, attempts=1)
    assert calls == [0]


@pytest.mark.parametrize("bad", [0, -1, math.inf, math.nan])
def test_a_timeout_must_be_a_positive_finite_number_of_seconds(bad: float) -> None:
    with pytest.raises(ValueError, match="timeout"):
        check_timeout(bad)


@pytest.mark.parametrize("cls", DRIVER_CLASSES, ids=lambda c: c.__name__)
def test_every_driver_builds_on_the_base(cls) -> None:
    assert issubclass(cls, Driver)


@pytest.mark.parametrize("cls", [c for c in DRIVER_CLASSES if c is not watlow_f4.WatlowF4], ids=lambda c: c.__name__)
def test_every_instrument_reports_what_its_safe_state_did(cls) -> None:
    """(The F4 controller is a part of ``tvac``, whose safe state sets it.)"""
    assert callable(getattr(cls, "safe_state", None)), f"{cls.__name__} has no safe_state of its own"
    assert inspect.signature(cls.safe_state).return_annotation in ("str", str)


def test_retries_live_in_one_place() -> None:
    """No driver loops over attempts itself: each hands an attempt function to read_retrying."""
    for mod in (acs_board, rate_table, watlow_f4):
        src = inspect.getsource(mod)
        assert "read_retrying(" in src, mod.__name__
        assert "for _ in range(attempts)" not in src and "while True:\n            try:\n                rr" not in src


def test_the_run_file_says_what_each_instrument_was_told_on_abort(tmp_path) -> None:
    """An interlock trip: the safe_state events carry the drivers' accounts, not "safe state reached"."""
    from bench.record import read_run_summary
    from tests.conftest import ROOT, SIM_CONFIG, run_cli

    runs = tmp_path / "runs"
    r = run_cli("run", str(ROOT / "tests" / "sessions" / "chamber_interlock_abort.yaml"), "--config", str(SIM_CONFIG),
                "--sim", "--runs-dir", str(runs))
    assert r.returncode == 1, r.stdout + r.stderr
    (path,) = runs.glob("*.h5")
    told = {e.source: e.message for e in read_run_summary(path).events if e.kind == "safe_state"}
    assert set(told) == {"tvac", "thermocouples"}
    assert told["tvac"].startswith("ramp off, set point 20 degC")
    assert "nothing to make safe" in told["thermocouples"]
