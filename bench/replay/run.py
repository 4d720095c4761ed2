"""Re-execute a recorded run against replay backends and compare (``bench replay``)."""

from __future__ import annotations

import gc
import json
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Iterator
from pathlib import Path

from bench import __version__
from bench.config import load_config
from bench.errors import InputError, InputErrors
from bench.procedure import load_procedure
from bench.record import RunRecorder, layout, read_run_summary
from bench.record.reader import read_traffic
from bench.replay.compare import Divergence, compare, compare_streams
from bench.replay.recording import Recording, check_plain_name, config_file, load_recording, param_overrides, procedure_file
from bench.replay.resim import board_streams, resimulate, why_not
from bench.replay.workspace import Workspace, shown
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


def replay(run_file: Path | Recording, procedure_path: Path | None = None, runs_dir: Path = Path("runs"), *,
           check_board: bool = True) -> ReplayResult:
    """Replay ``run_file`` (or its :class:`Recording`, already read); raises :class:`InputError` for a
    file that cannot be replayed.
    ``check_board``: check a dry-run's recorded board samples against a re-simulation
    (:mod:`bench.replay.resim`; about doubles the time of a replay of a dry-run with the board).

    The texts in the run file (procedure, sub-procedures, vibration profiles, config) and the paths
    they were recorded at are data: they are written into a private temporary directory and read
    from there (:mod:`bench.replay.workspace`); nothing outside it and ``runs_dir`` is written, and
    nothing outside it, ``procedure_path`` and the project's ``procedures/``/``configs/`` is read."""
    rec = None
    try:
        with long_lived():
            rec = run_file if isinstance(run_file, Recording) else load_recording(Path(run_file))
        with Workspace(rec.path) as ws:
            return _replay(rec, ws, procedure_path, runs_dir, check_board)
    finally:
        rec = None  # what the replay built is dropped before the collector sees it again
        gc.unfreeze()


@contextmanager
def long_lived() -> Iterator[None]:
    """Build objects that live as long as the replay (an 8-h recording: its traffic, an exchange per
    command, a million objects) without the cyclic garbage collector, then freeze them
    (``gc.freeze``): each full collection rescanned all of them, 0.7 s of an 8-h replay.
    :func:`replay` unfreezes at its end. Reference counting still frees what is dropped."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if was:
            gc.enable()


CONFIG_NOT_FOUND_HINT = ("; a replay reads the config and the sensor models and calibration files it read from the run "
                         f"file ('{layout.EVENT_CONFIG_SOURCES}' event)")
OLD_CONFIG_NOT_FOUND_HINT = ("; run file recorded before bench kept the files a config names: a replay reads them from the "
                             "project's configs/ only, under the name the config gives (copy the file there, or record the run again)")


def _load(ws: Workspace, what: str, load, config_hint: str = CONFIG_NOT_FOUND_HINT):
    """``load()`` of a mirrored text; its errors located in the run file, with a hint for a file
    the run file does not hold (``config_hint`` for the config's files)."""
    try:
        return load()
    except InputError as exc:
        err = ws.relocate(exc)
        if "not found" in err.one_line():
            hint = ("; a replay reads the procedure, its sub-procedures and vibration profiles from the run file (give "
                    "--procedure FILE to replay a procedure from files)" if what == "procedure" else config_hint)
            errs = err.errors if isinstance(err, InputErrors) else [err]
            errs = [InputError(e.message + hint, e.location, e.field) if "not found" in e.message else e for e in errs]
            err = InputErrors(errs) if isinstance(err, InputErrors) else errs[0]
        raise err from None


def _replay(rec, ws: Workspace, procedure_path: Path | None, runs_dir: Path, check_board: bool) -> ReplayResult:
    src = rec.summary
    config = _load(ws, "config", lambda: load_config(config_file(rec, ws), recorded=True),
                   CONFIG_NOT_FOUND_HINT if rec.config_sources is not None else OLD_CONFIG_NOT_FOUND_HINT)
    for name in config.instruments:
        check_plain_name(name, rec.path, f"{layout.absolute(layout.CONFIG_TEXT)}: instruments:")
    kinds, limits, signals = config.kinds(), config.limits(), config.signals()
    stored_file = procedure_file(rec, ws)
    notes = []
    try:
        defaults = _load(ws, "procedure", lambda: load_procedure(stored_file, {}, kinds, limits, signals)).parameters
        overrides = param_overrides(rec, defaults)
        stored = _load(ws, "procedure", lambda: load_procedure(stored_file, overrides, kinds, limits, signals))
    except InputError as exc:
        if procedure_path is None:
            raise
        # the stored procedure does not load from the run file alone (a file it names is not stored):
        # --procedure is replayed with every recorded parameter it has
        notes.append(f"note: the stored procedure does not load from the run file ({exc.one_line()}); "
                     "--procedure gets every recorded parameter it has")
        stored, overrides = None, param_overrides(rec, {})
    if procedure_path is None:
        procedure = stored
        text, ppath = src.procedure_text, rec.procedure_path
    else:
        own = load_procedure(procedure_path, {}, kinds, limits, signals).parameters
        procedure = load_procedure(procedure_path, {k: v for k, v in overrides.items() if k in own}, kinds, limits, signals)
        text, ppath = procedure.text, str(procedure_path)
    used = {ws.recorded(p): t for p, t in procedure.sources.items()}
    for p, t in rec.sources.items():
        if used.get(p, t) != t:
            notes.append(f"note: called file {shown(p)} differs from the text recorded in the run file")
    drivers = {n: config.instruments[n].driver for n in procedure.instruments if n in config.instruments}
    mode = rec.mode if rec.mode in (layout.MODE_SIM, layout.MODE_HARDWARE) else layout.MODE_SIM
    _check_board_streams(rec, config)

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
        with long_lived():
            rl = open_replay_lab(config, procedure.instruments, rec, mode, traffic, exhausted)
    except BaseException as exc:
        recorder.close(layout.STATUS_ABORTED, f"instruments could not be opened: {exc}")
        if isinstance(exc, (ValueError, TypeError, KeyError, IndexError)):  # recorded data the backends cannot take
            raise InputError(f"{rec.path}: cannot be replayed: the recording does not make instrument answers "
                             f"({type(exc).__name__}: {' '.join(str(exc).split())[:200]})") from None
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
        lab_box.clear()  # the lab's traffic hooks hold this closure, which held the lab and the runner:
        runner = None  # without these cycles the exchanges are freed now, not by a later full collection
    wall = time.monotonic() - wall0
    rep = read_run_summary(recorder.path, traffic=False)
    rep_commands = read_traffic(recorder.path, kinds=("command",))
    crashed = rec.status in (layout.STATUS_CRASHED, layout.STATUS_RUNNING)
    if crashed:
        notes.append(f"note: the source has no end (status {rec.status}); compared up to its last event at {rec.end_t_s:.1f} s")
    divs = compare(src, rep, rec.traffic, rep_commands, drivers, timed=rec.clock == "virtual", prefix_only=crashed,
                   src_keys=rec.link_keys(drivers))
    divs += compare_streams(rec.path, recorder.path, src, rep, crashed, timed=rec.clock == "virtual")
    if check_board:  # a fresh copy of the stored procedure: the replay's runner has been through the other
        fresh = (lambda: _load(ws, "procedure", lambda: load_procedure(stored_file, overrides, kinds, limits, signals))) if stored is not None else None
        divs += _board_check(rec, fresh, config, ws, crashed, notes)
    divs.sort(key=lambda d: (d.t_s, 0 if d.what == "command" else 1))
    commands = len(rep_commands)
    return ReplayResult(rec.path, recorder.path, divs, run_time, wall, status, reason, commands, notes)


def _check_board_streams(rec: Recording, config) -> None:
    """The recorded board streams the replay re-encodes into frames have the board's columns, each
    of its row shape (the columns of the board's frame description in the recorded config);
    :class:`InputError` otherwise."""
    streams = {s.key: s for s in rec.summary.streams}
    for key in board_streams(rec, config):
        have = streams[key].shapes
        columns = getattr(config.instruments[key].settings, "stream_columns", None)
        for c in columns() if columns is not None else []:
            if have.get(c.name) != tuple(c.shape or ()):
                got = "missing" if c.name not in have else f"of row shape {have[c.name]}"
                raise InputError(f"{rec.path}: cannot be replayed: column {c.name} of board stream {layout.absolute(layout.stream_path(key))} "
                                 f"is {got}, expected row shape {tuple(c.shape or ())}")


def _board_check(rec, stored, config, ws: Workspace, crashed: bool, notes: list[str]) -> list[Divergence]:
    """The recorded board streams against a re-simulation of the dry-run (:mod:`bench.replay.resim`):
    the replay feeds the board from those rows, so only an independent run tells a changed value.
    ``stored``: makes the stored procedure (None when it does not load from the run file)."""
    keys = board_streams(rec, config)
    reason = why_not(rec, keys) or ("" if stored is not None else "the stored procedure does not load from the run file")
    if not keys:
        return []
    if reason:
        notes.append(f"note: the board's samples ({', '.join(keys)}) are what the replay sends, not checked against a reference: {reason}")
        return []
    wall0 = time.monotonic()
    try:
        path = _load(ws, "config", lambda: resimulate(stored(), config, rec, ws.root / "resim"))
    except Exception as exc:  # noqa: BLE001 - the replay itself is done: a re-simulation that cannot run is reported, not raised
        what = exc.one_line() if isinstance(exc, InputError) else f"{type(exc).__name__}: {exc}"
        notes.append(f"note: the board's samples ({', '.join(keys)}) were not re-simulated: {what}")
        return []
    divs = compare_streams(rec.path, path, rec.summary, read_run_summary(path, traffic=False), crashed, keys=keys, got="re-simulated dry-run")
    notes.append(f"board samples ({', '.join(keys)}) checked against a re-simulation of the dry-run "
                 f"({time.monotonic() - wall0:.2f} s wall): {'differ' if divs else 'the same'}")
    return divs
