"""Re-execute a recorded run against replay backends and compare (``bench replay``)."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

from bench import __version__
from bench.config import load_config
from bench.procedure import load_procedure
from bench.procedure.loader import parse_procedure
from bench.record import RunRecorder, layout, read_run_summary
from bench.replay.compare import Divergence, compare, compare_streams
from bench.replay.recording import load_recording, materialise_config, new_workdir, param_overrides
from bench.runner import Runner
from bench.runner.operator import Operator


class ReplayOperator(Operator):
    """Gives the recorded answers, with their recorded source, in the order they were asked."""

    def __init__(self, answers: list[tuple[str, str, str]]):
        super().__init__({k: a for k, a, _s in answers})
        self._queue = list(answers)

    def can_answer(self, key: str, simulated: bool) -> bool:
        return True

    def ask(self, key: str, text: str, simulated: bool, **_waiting: object) -> tuple[str, str]:
        """The next recorded answer to ``key`` (``_waiting``: the live prompt's keepalive and
        deadline, unused: recorded answers come at once)."""
        for i, (k, answer, source) in enumerate(self._queue):
            if k == key:
                del self._queue[i]
                return answer, source
        return "no", "replay (no recorded answer)"


class QuietProgress:
    def start(self, procedure, total_s: float) -> None: ...

    def step(self, n: int, total: int, step) -> None: ...

    def advance(self, run_time_s: float, readings: str = "") -> None: ...

    def message(self, text: str) -> None: ...

    def stop(self, run_time_s: float) -> None: ...


@dataclass
class ReplayResult:
    source: Path
    replay_file: Path
    divergences: list[Divergence]
    run_time_s: float
    wall_time_s: float
    status: str
    abort_reason: str
    commands: int
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.divergences

    def report(self) -> str:
        lines = [f"replay of {self.source}: {self.commands} commands, run time {self.run_time_s:.1f} s in {self.wall_time_s:.2f} s wall "
                 f"({self.run_time_s / max(self.wall_time_s, 1e-9):.0f}x); replay recorded in {self.replay_file}"]
        lines += self.notes
        if self.ok:
            lines.append("MATCH: same commands, step outcomes, checks, streams and end of run")
        else:
            lines.append("DIVERGED: " + self.divergences[0].render())
            lines.append(f"  and {len(self.divergences) - 1} more divergence(s)")
        return "\n".join(lines)


def replay(run_file: Path, procedure_path: Path | None = None, runs_dir: Path = Path("runs")) -> ReplayResult:
    """Replay ``run_file``; raises :class:`InputError` for a file that cannot be replayed."""
    rec = load_recording(Path(run_file))
    src = rec.summary
    with new_workdir() as wd:
        config = load_config(materialise_config(rec, Path(wd)))
    kinds, limits = config.kinds(), config.limits()
    stored_path = str(src.attrs.get(layout.ATTR_PROCEDURE_PATH, "procedure.yaml"))
    defaults = parse_procedure(src.procedure_text, stored_path, {}, kinds, limits).parameters
    if procedure_path is None:
        procedure = parse_procedure(src.procedure_text, stored_path, param_overrides(rec, defaults), kinds, limits)
        text, ppath = src.procedure_text, stored_path
    else:
        own = load_procedure(procedure_path, {}, kinds, limits).parameters
        overrides = {k: v for k, v in param_overrides(rec, defaults).items() if k in own}
        procedure = load_procedure(procedure_path, overrides, kinds, limits)
        text, ppath = procedure.text, str(procedure_path)
    notes = []
    for p, t in rec.sources.items():
        if procedure.sources.get(p, t) != t:
            notes.append(f"note: called procedure {p} differs from the text recorded in the run file")
    drivers = {n: config.instruments[n].driver for n in procedure.instruments if n in config.instruments}
    mode = rec.mode if rec.mode in (layout.MODE_SIM, layout.MODE_HARDWARE) else layout.MODE_SIM

    from bench.replay.lab import open_replay_lab

    recorder = RunRecorder.create(runs_dir, procedure_name=procedure.name, procedure_text=text, procedure_path=ppath,
                                  config_text=config.text, config_path=str(src.attrs.get(layout.ATTR_CONFIG_PATH, "")), mode=layout.MODE_REPLAY,
                                  software_version=__version__, flush_interval_s=config.flush_interval_s)
    recorder.event("replay", "replay", f"replay of {rec.path}", t_s=0.0, data=json.dumps({
        "source": str(rec.path.resolve()), "sha256": rec.sha256, "source_started_utc": src.attrs.get(layout.ATTR_STARTED_UTC, ""),
        "source_mode": rec.mode, "source_status": rec.status, "procedure": ppath}).encode())
    runner: Runner | None = None
    lab_box: list = []
    pending_abort: list[str] = []
    record_traffic = [rec.prelude_recorded]

    def traffic(name: str, direction: str, what: str, raw: bytes) -> None:
        if record_traffic[0]:
            recorder.event(direction, name, what, t_s=lab_box[0].lab.clock.now() if lab_box else 0.0,
                           step=runner.current_step if runner is not None else -1, data=raw)

    def exhausted(reason: str) -> None:
        if runner is not None:
            runner.request_abort(reason)
        else:
            pending_abort.append(reason)

    wall0 = time.monotonic()
    try:
        rl = open_replay_lab(config, procedure.instruments, rec, mode, traffic, exhausted)
    except BaseException as exc:
        recorder.close(layout.STATUS_ABORTED, f"instruments could not be opened: {exc}")
        raise
    lab_box.append(rl)
    if rec.prelude_recorded:
        recorder.event("lab_open", "runner", "instruments open", t_s=rl.lab.clock.now())
    record_traffic[0] = True
    try:
        runner = Runner(procedure, rl.lab, recorder, QuietProgress(), ReplayOperator(rec.answers))
        for reason in pending_abort:
            runner.request_abort(reason)
        try:
            result = runner.run()
            run_time, status, reason = result.run_time_s, result.status, result.abort_reason
        except Exception as exc:  # noqa: BLE001 - a replay reports how the re-executed run broke, it does not crash
            run_time, status = rl.lab.clock.now(), layout.STATUS_FAILED
            reason = f"the replayed run crashed: {type(exc).__name__}: {exc}"
            notes.append(f"note: {reason}")
            if not recorder.closed:
                try:
                    recorder.event("run_end", "runner", f"failed: {reason}", t_s=run_time)
                    recorder.close(layout.STATUS_FAILED, reason)
                except Exception:  # noqa: BLE001
                    pass
    finally:
        rl.close()
    wall = time.monotonic() - wall0
    rep = read_run_summary(recorder.path)
    crashed = rec.status in (layout.STATUS_CRASHED, layout.STATUS_RUNNING)
    if crashed:
        notes.append(f"note: the source has no end (status {rec.status}); compared up to its last event at {rec.end_t_s:.1f} s")
    divs = compare(src, rep, drivers, timed=rec.clock == "virtual", prefix_only=crashed, skip_prelude=False)
    divs += compare_streams(rec.path, recorder.path, src, rep, crashed, timed=rec.clock == "virtual")
    divs.sort(key=lambda d: (d.t_s, 0 if d.what == "command" else 1))
    commands = sum(1 for e in rep.events if e.kind == "command")
    return ReplayResult(rec.path, recorder.path, divs, run_time, wall, status, reason, commands, notes)
