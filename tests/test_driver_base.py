"""drivers/base.py: one home for timeouts, retries of idempotent reads and the safe state."""

from __future__ import annotations

import inspect
import math

import pytest

from bench.kinds import registry
from drivers import acs_board, rate_table, tpg261, watlow_f4
from drivers.base import Driver, Transient, check_timeout
from drivers.errors import InstrumentError, InstrumentTimeout, ProtocolError

KINDS = list(registry.kinds().values())
"""Every installed kind (bench's own and a lab's, e.g. examples/bench-dc-supply): the checks below run
over each one's driver, so a new kind is checked against the base class without editing this file."""
PARTS = [tpg261.Tpg261, watlow_f4.WatlowF4]
"""Drivers of parts of a composite instrument (the chamber's gauge and controller)."""


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


def test_the_kinds_are_found_by_entry_point() -> None:
    """bench's own five are declared like any lab's kind; none failed to load."""
    reg = registry.registry()
    assert not reg.problems, reg.problems
    assert {k.name for k in KINDS if k.package == "bench"} >= {"acs_board", "tvac"}  # two of ours, found the same way
    assert all(k.package for k in KINDS)


@pytest.mark.parametrize("cls", [*PARTS], ids=lambda c: c.__name__)
def test_every_part_builds_on_the_base(cls) -> None:
    assert issubclass(cls, Driver)


@pytest.mark.parametrize("kind", KINDS, ids=lambda k: k.name)
def test_every_kind_s_driver_builds_on_the_base(kind) -> None:
    """Its driver derives from the base, names its kind, opens as the lab opens it, says what its
    safe state did and identifies itself."""
    cls = registry.load(kind.driver)
    assert issubclass(cls, Driver), f"{kind.driver} does not derive from drivers.base.Driver"
    assert cls.kind == kind.name
    assert cls.streams == kind.streams
    params = inspect.signature(cls.open).parameters
    assert {"baudrate", "timeout_s", "on_traffic"} <= set(params) or any(p.kind == p.VAR_KEYWORD for p in params.values())
    assert callable(getattr(cls, "safe_state", None)), f"{cls.__name__} has no safe_state of its own"
    assert inspect.signature(cls.safe_state).return_annotation in ("str", str)
    assert callable(getattr(cls, "identify", None)) and callable(getattr(cls, "close", None))


@pytest.mark.parametrize("kind", [k for k in KINDS if k.sim is not None], ids=lambda k: k.name)
def test_every_kind_opens_on_its_simulator_identifies_reads_and_goes_safe(kind, tmp_path) -> None:
    """The kind's own example instrument (``Kind.example``) in a lab config: its driver opens on its
    simulator, identifies, gives its ``instruments check`` reading, names only columns its kind
    declares (units declared once), and says what its safe state did."""
    from bench.config import load_config
    from bench.instruments_check import reading
    from bench.lab import open_lab
    from bench.procedure.signals import monitor_units

    assert kind.example, f"kind {kind.name} gives no example instrument section"
    body = "".join(f"    {line}\n" for line in kind.example.strip().splitlines())
    (tmp_path / "lab.yaml").write_text(f"schema: bench-config/1\nname: t\nmode: sim\ninstruments:\n  it:\n{body}")
    config = load_config(tmp_path / "lab.yaml")
    lab = open_lab(config, ["it"], sim=True, realtime=False)
    try:
        drv = lab.instruments["it"]
        ident = drv.identify()
        assert isinstance(ident, dict) and all(isinstance(v, str) for v in ident.values())
        assert isinstance(reading(config.instruments["it"], drv), str)
        if not kind.streams:
            columns = drv.monitor_columns()
            assert columns and all(monitor_units(c, kind.name) for c in columns), (columns, [s.name for s in kind.signals])
            values = drv.monitor()
            assert set(values) == set(columns)
        told = drv.safe_state()
        assert isinstance(told, str) and told
    finally:
        lab.close()


@pytest.mark.parametrize("kind", KINDS, ids=lambda k: k.name)
def test_every_dotted_path_of_every_kind_names_something(kind) -> None:
    """A kind's record names its code by dotted path: each one imports and is callable."""
    paths = [kind.driver, kind.settings, kind.reading, kind.replay]
    if kind.sim is not None:
        paths += [kind.sim.builder, kind.sim.settings, kind.sim.tcp_ports]
    paths += [p for d in kind.steps for p in (d.handler, d.estimate)]
    paths += [f.start for f in kind.faults]
    for path in filter(None, paths):
        assert callable(registry.load(path)), path


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
