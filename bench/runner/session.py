"""Start a run: run file, lab, fault injection and runner wired together (``bench run``, ``bench soak``)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from bench import __version__
from bench.config import LabConfig
from bench.errors import InputError
from bench.identity import RunIdentity
from bench.catalog.hooks import RunCatalogHook
from bench.lab import InstrumentOpenError, Lab, open_lab
from bench.procedure import Procedure
from bench.record import RunRecorder, layout
from bench.record.skeleton import login_name
from bench.runner.engine import Runner
from bench.runner.operator import Operator
from bench.runner.unit_identity import OverdueCalibration, confirm_overdue, declared_identity, root_attrs
from bench.startup_signals import StartupSignals, StoppedDuringStartup, stop_within


@dataclass
class RunSession:
    """A run ready to go: ``runner.run()``, then ``lab.close()`` (always)."""

    recorder: RunRecorder
    lab: Lab
    runner: Runner
    faults: list[Any]
    """The faults scheduled by ``fault_spec`` (:class:`bench.faults.ScheduledFault`)."""
    catalog: RunCatalogHook | None = None
    """The run's row in the catalogue of runs: ``catalog.run_ended()`` once the run is over (never raises)."""


def start_run(procedure: Procedure, config: LabConfig, *, procedure_path: Path, config_path: Path, runs_dir: Path,
              sim: bool, realtime: bool, operator: Operator, progress: Any, operator_name: str | None = None,
              fault_spec: Any = None, identity: RunIdentity | None = None,
              overdue: Sequence[OverdueCalibration] = (), accept_overdue: bool = False,
              catalog: str | None = None, startup: StartupSignals | None = None, operator_origin: str = "") -> RunSession:
    """Create the run file, open the lab (recording every byte from the first one: replay answers
    it), and build the runner; with ``fault_spec`` (a parsed ``--inject-faults``) the progress sink is
    wrapped by a :class:`bench.faults.FaultInjector`. On failure, or on any ``BaseException``
    (Ctrl-C …), everything opened so far is closed and the run file is finalised as aborted with the
    reason; the exception propagates.

    ``identity``: the unit under test and station, recorded as root attributes; ``operator_origin``
    where ``operator_name`` came from (:mod:`bench.operators`), recorded beside it. ``overdue``: the
    run's instruments past their calibration due date, confirmed (``accept_overdue``, else through
    ``operator``) and recorded before any instrument is opened; a "no" finalises the file as
    aborted and raises :class:`bench.runner.unit_identity.CalibrationDeclined`.

    ``startup``: the installed start-up signal handler (``bench run``): the file is created and
    finalised with signals held, a stop signal raises :class:`StoppedDuringStartup` (its
    ``run_file`` set, the file aborted "stopped during start-up by SIGTERM (while …)"), and once the
    run is built the handler is handed over: the caller forwards a signal noted since
    (``startup.signum``) to the runner."""
    guard = startup if startup is not None else StartupSignals()
    lab: Lab | None = None
    runner: Runner | None = None
    recorder: RunRecorder | None = None

    def traffic(name: str, direction: str, what: str, raw: bytes) -> None:
        if recorder is not None:
            recorder.event(direction, name, what, t_s=lab.clock.now() if lab else 0.0,
                           step=runner.current_step if runner is not None else -1, data=raw)

    with guard.held():
        recorder = RunRecorder.create(
            runs_dir,
            procedure_name=procedure.name,
            procedure_text=procedure.text,
            procedure_path=str(procedure_path),
            config_text=config.text,
            config_path=str(config_path),
            mode="sim" if sim else "hardware",
            software_version=__version__,
            flush_interval_s=config.flush_interval_s,
            **({"operator": operator_name} if operator_name else {}),
            identity={**(root_attrs(identity) if identity is not None else {}),
                      **({layout.ATTR_OPERATOR_ORIGIN: operator_origin} if operator_origin else {})} or None,
        )
    hook: RunCatalogHook | None = None
    doing = "cataloguing the run"
    try:
        guard.raise_pending()
        doing = "recording the config's files"
        recorder.event(layout.EVENT_CONFIG_SOURCES, "runner", config.name, t_s=0.0, data=config_sources_json(config))
        doing = "confirming overdue calibrations"
        confirm_overdue(overdue, operator, accept_overdue, recorder, operator_name or login_name())
        doing = "opening the instruments"
        lab = open_lab(config, procedure.instruments, sim=sim, realtime=realtime, on_traffic=traffic)
        doing = "cataloguing the run"
        # the run's row, `running` (``catalog``: URL or file, default runs_dir/catalog.sqlite); never raises
        hook = RunCatalogHook.run_started(recorder.path, runs_dir=runs_dir, catalog=catalog)
        doing = "preparing the run"
        recorder.event("lab_open", "runner", "instruments open", t_s=lab.clock.now())
        faults: list[Any] = []
        if fault_spec is not None:
            from bench.faults import FaultInjector, plan_faults

            doing = "planning the injected faults"
            faults = plan_faults(fault_spec, lab.kinds, procedure.estimated_duration_s())
            progress = FaultInjector(progress, faults, lab, recorder)
        runner = Runner(procedure, lab, recorder, progress, operator, declared=declared_identity(config, procedure.instruments))
        runner.operator_name = operator_name or login_name()
        guard.hand_over()
    except BaseException as raised:
        # a library may have turned the stop signal into its own error (stop_within): it is the stop
        exc = stop_within(raised) or raised
        with guard.held():  # the run ends before its first step: the file is finalised as aborted, its row updated
            if lab is not None:
                try:
                    lab.close()
                except Exception:  # noqa: BLE001 - the file must still be finalised; the first failure is reported
                    pass
            never_started = isinstance(exc, InstrumentOpenError)
            try:
                recorder.close("aborted", _startup_abort_reason(exc, doing))
            finally:
                if never_started:
                    # the run never started (nothing but identification was sent): no run file is
                    # kept and it was never catalogued; the error names the instrument and what to do
                    _discard(recorder.path)
            if not never_started:  # an aborted start-up (declined calibration, a stop signal…) is on record
                (hook or RunCatalogHook(recorder.path, runs_dir, catalog)).run_ended()
        if isinstance(exc, StoppedDuringStartup):
            exc.run_file = recorder.path
        if exc is not raised:
            raise exc from raised
        raise
    return RunSession(recorder, lab, runner, faults, hook)


def config_sources_json(config: LabConfig) -> bytes:
    """The data of the ``config_sources`` event: the config's absolute path (its directory
    resolved, as the loader resolved the names in it) and the texts of the files it read, so a
    replay loads the config with them and nothing from disk (docs/run-file.md)."""
    path = Path(config.path)
    return json.dumps({"path": str(path.parent.resolve() / path.name), "sources": config.sources}).encode()


def _startup_abort_reason(exc: BaseException, doing: str) -> str:
    """The abort reason of a run that ended in start-up, while ``doing``."""
    if isinstance(exc, StoppedDuringStartup):
        return f"stopped during start-up by {exc.signal_name} (while {doing})"
    if not isinstance(exc, Exception):  # KeyboardInterrupt without the start-up handler, SystemExit
        return f"stopped during start-up by {type(exc).__name__} (while {doing})"
    if doing == "confirming overdue calibrations":
        return f"overdue calibration not confirmed: {exc}"
    if doing == "opening the instruments":
        return f"instruments could not be opened: {exc}"
    if doing == "planning the injected faults" and isinstance(exc, InputError):
        return "bad --inject-faults spec"
    return f"start-up failed while {doing}: {exc or type(exc).__name__}"


def _discard(path: Path) -> None:
    """Remove the run file of a run that never started (an instrument could not be opened): its
    name (the placeholder, or the finalised file moved over it) and the hidden file it was being
    set up in (:func:`bench.record.destination.partial_path`), should closing have failed before
    moving it."""
    from bench.record.destination import partial_path

    for p in (Path(path), partial_path(Path(path))):
        try:
            p.unlink()
        except OSError:
            pass
