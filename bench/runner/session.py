"""Start a run: run file, lab, fault injection and runner wired together (``bench run``, ``bench soak``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from bench import __version__
from bench.config import LabConfig
from bench.errors import InputError
from bench.identity import RunIdentity
from bench.catalog.hooks import RunCatalogHook
from bench.lab import Lab, open_lab
from bench.procedure import Procedure
from bench.record import RunRecorder
from bench.record.skeleton import login_name
from bench.runner.engine import Runner
from bench.runner.operator import Operator
from bench.runner.unit_identity import OverdueCalibration, confirm_overdue, declared_identity, root_attrs


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
              catalog: str | None = None) -> RunSession:
    """Create the run file, open the lab (recording every byte from the first one: replay answers
    it), and build the runner; with ``fault_spec`` (a parsed ``--inject-faults``) the progress sink is
    wrapped by a :class:`bench.faults.FaultInjector`. On failure everything opened so far
    is closed and the run file is finalised as aborted with the reason.

    ``identity``: the unit under test and station, recorded as root attributes. ``overdue``: the
    run's instruments past their calibration due date, confirmed (``accept_overdue``, else through
    ``operator``) and recorded before any instrument is opened; a "no" finalises the file as
    aborted and raises :class:`bench.runner.unit_identity.CalibrationDeclined`."""
    lab: Lab | None = None
    runner: Runner | None = None
    recorder: RunRecorder | None = None

    def traffic(name: str, direction: str, what: str, raw: bytes) -> None:
        if recorder is not None:
            recorder.event(direction, name, what, t_s=lab.clock.now() if lab else 0.0,
                           step=runner.current_step if runner is not None else -1, data=raw)

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
        identity=root_attrs(identity) if identity is not None else None,
    )
    # the run's row, `running` (``catalog``: URL or file, default runs_dir/catalog.sqlite); never raises
    hook = RunCatalogHook.run_started(recorder.path, runs_dir=runs_dir, catalog=catalog)

    def abort_before_start(reason: str) -> None:
        """The run ends before its first step: file finalised as aborted, its row updated."""
        recorder.close("aborted", reason)
        hook.run_ended()

    try:
        confirm_overdue(overdue, operator, accept_overdue, recorder, operator_name or login_name())
    except BaseException as exc:
        abort_before_start(f"overdue calibration not confirmed: {exc}")
        raise
    try:
        lab = open_lab(config, procedure.instruments, sim=sim, realtime=realtime, on_traffic=traffic)
    except BaseException as exc:
        abort_before_start(f"instruments could not be opened: {exc}")
        raise
    recorder.event("lab_open", "runner", "instruments open", t_s=lab.clock.now())
    faults: list[Any] = []
    if fault_spec is not None:
        from bench.faults import FaultInjector, plan_faults

        try:
            faults = plan_faults(fault_spec, lab.kinds, procedure.estimated_duration_s())
        except InputError:
            lab.close()
            abort_before_start("bad --inject-faults spec")
            raise
        progress = FaultInjector(progress, faults, lab, recorder)
    runner = Runner(procedure, lab, recorder, progress, operator, declared=declared_identity(config, procedure.instruments))
    return RunSession(recorder, lab, runner, faults, hook)
