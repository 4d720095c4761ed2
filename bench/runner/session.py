"""Start a run: run file, lab, fault injection and runner wired together (``bench run``, ``bench soak``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench import __version__
from bench.config import LabConfig
from bench.errors import InputError
from bench.lab import Lab, open_lab
from bench.procedure import Procedure
from bench.record import RunRecorder
from bench.runner.engine import Runner
from bench.runner.operator import Operator


@dataclass
class RunSession:
    """A run ready to go: ``runner.run()``, then ``lab.close()`` (always)."""

    recorder: RunRecorder
    lab: Lab
    runner: Runner
    faults: list[Any]
    """The faults scheduled by ``fault_spec`` (:class:`bench.faults.ScheduledFault`)."""


def start_run(procedure: Procedure, config: LabConfig, *, procedure_path: Path, config_path: Path, runs_dir: Path,
              sim: bool, realtime: bool, operator: Operator, progress: Any, operator_name: str | None = None,
              fault_spec: Any = None) -> RunSession:
    """Create the run file, open the lab (recording every byte from the first one: replay answers
    it), and build the runner; with ``fault_spec`` (a parsed ``--inject-faults``) the progress sink is
    wrapped by a :class:`bench.faults.FaultInjector`. On failure everything opened so far
    is closed and the run file is finalised as aborted with the reason."""
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
    )
    try:
        lab = open_lab(config, procedure.instruments, sim=sim, realtime=realtime, on_traffic=traffic)
    except BaseException as exc:
        recorder.close("aborted", f"instruments could not be opened: {exc}")
        raise
    recorder.event("lab_open", "runner", "instruments open", t_s=lab.clock.now())
    faults: list[Any] = []
    if fault_spec is not None:
        from bench.faults import FaultInjector, plan_faults

        try:
            faults = plan_faults(fault_spec, lab.kinds, procedure.estimated_duration_s())
        except InputError:
            lab.close()
            recorder.close("aborted", "bad --inject-faults spec")
            raise
        progress = FaultInjector(progress, faults, lab, recorder)
    runner = Runner(procedure, lab, recorder, progress, operator)
    return RunSession(recorder, lab, runner, faults)
