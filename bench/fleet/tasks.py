"""What a worker does with one run file: the library function the serial command calls, its output
written inside the output directory, and a small picklable :class:`FileResult`.

=========  ===============================================  =====================================
command    calls (as the serial command does)                output
=========  ===============================================  =====================================
replay     :func:`bench.replay.run.replay`                   the replay's run file, ``OUT/<sub>/``
calibrate  :func:`bench.analysis.per_file.calibrate_file`    ``OUT/<sub>/<stem>.<method>.json``
diagnose   :func:`bench.analysis.per_file.diagnose_file`     ``OUT/<sub>/<stem>.diagnose.json``
report     :func:`bench.report.run_report.write_report`      ``OUT/<sub>/<stem>.html``
=========  ===============================================  =====================================

A calibration's or diagnosis's JSON file is byte for byte what ``bench calibrate METHOD FILE
--json`` (``bench diagnose FILE --json``) prints, and :attr:`FileResult.payload` is that JSON
parsed. The exit class of a file is the serial command's: 0 done (a replay that matches), 1 failed
(a replay that diverged, an instrument or internal error), 2 the file cannot be used (not a run
file, damaged, no data the method needs); the error text is the serial command's one line.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

from bench.errors import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_OK, InputError, InputErrors
from bench.fleet.files import destination, write_new


@dataclass(frozen=True)
class Job:
    """What to do with every file of a fleet (picklable: it travels to the workers).

    ``out_dir``: the output directory (as the workers see it); ``method``, ``options`` (``degree``,
    ``sensor``): ``bench calibrate``'s; ``mapping``: ``--map`` values; ``model``: ``bench
    diagnose --model``; ``force``: replace outputs that exist."""

    command: str
    out_dir: str
    method: str | None = None
    options: tuple[tuple[str, Any], ...] = ()
    mapping: tuple[str, ...] | None = None
    model: str | None = None
    force: bool = False


@dataclass(frozen=True)
class FileResult:
    """One file's outcome, small enough to send back from a worker.

    ``exit_code``: the serial command's exit class (0, 1, 2); ``verdict``: MATCH, DIVERGED (replay),
    calibrated, the diagnosis (``nothing missing``, ``missing EFFECT, ...``, ``UNEXPLAINED``),
    written (report) or ERROR; ``summary``: one line; ``output``: the file written (replay: its run
    file); ``error``: the one-line reason of an ERROR; ``wall_s``: wall time of the file on its
    worker (s); ``worker``: ``host:pid``; ``notes``: how a mapped file was read, replay notes;
    ``payload``: the serial command's ``--json`` (calibrate, diagnose) or the replay's figures."""

    path: str
    rel: str
    exit_code: int
    verdict: str
    summary: str = ""
    output: str | None = None
    error: str | None = None
    wall_s: float = 0.0
    worker: str = ""
    notes: tuple[str, ...] = ()
    payload: Any = None

    @property
    def ok(self) -> bool:
        """The file was done, and a replay matched."""
        return self.exit_code == EXIT_OK

    def as_json(self) -> dict[str, Any]:
        """The result as plain JSON values (``--json``)."""
        out = asdict(self)
        out["notes"] = list(self.notes)
        return out


@dataclass
class _Done:
    verdict: str
    exit_code: int = EXIT_OK
    summary: str = ""
    output: str | None = None
    payload: Any = None
    notes: list[str] = field(default_factory=list)


def run_file(job: Job, path: str, rel: str) -> FileResult:
    """Do ``job`` with the file at ``path`` (named ``rel`` under the fleet's root): never raises for
    what the file holds; the error becomes the result's ``error`` with the serial exit class."""
    t0 = time.perf_counter()
    worker = f"{socket.gethostname()}:{os.getpid()}"
    _quiet_instrument_logs()
    try:
        done = _COMMANDS[job.command](job, Path(path), destination(Path(job.out_dir), rel, job.command, job.method))
    except InputErrors as exc:
        return FileResult(path, rel, EXIT_BAD_INPUT, "ERROR", error="; ".join(e.one_line() for e in exc.errors),
                          wall_s=time.perf_counter() - t0, worker=worker)
    except InputError as exc:
        return FileResult(path, rel, EXIT_BAD_INPUT, "ERROR", error=exc.one_line(), wall_s=time.perf_counter() - t0, worker=worker)
    except Exception as exc:  # noqa: BLE001 - one file's failure is its result; the fleet goes on
        return FileResult(path, rel, EXIT_FAILED, "ERROR", error=f"{type(exc).__name__}: {exc}",
                          wall_s=time.perf_counter() - t0, worker=worker)
    return FileResult(path, rel, done.exit_code, done.verdict, done.summary, done.output, None, time.perf_counter() - t0,
                      worker, tuple(done.notes), done.payload)


def _quiet_instrument_logs() -> None:
    """As ``bench`` without ``--debug``: the drivers' libraries do not log what the drivers report
    as typed errors (a worker has no terminal to show them on)."""
    for name in ("pymodbus", "can", "canopen"):
        logging.getLogger(name).setLevel(logging.CRITICAL)


def _replay(job: Job, path: Path, runs_dir: Path) -> _Done:
    from bench.record import check_destination
    from bench.replay.run import replay

    # as `bench replay`: a directory that cannot take the replay's file is refused before the replay
    check_destination(runs_dir, path.stat().st_size if path.is_file() else 0)
    r = replay(path, None, runs_dir)
    first = r.divergences[0].render() if r.divergences else None
    payload = {"match": r.ok, "divergences": len(r.divergences), "first_divergence": first, "commands": r.commands,
               "run_time_s": r.run_time_s, "status": r.status, "abort_reason": r.abort_reason,
               "replay_file": str(r.replay_file), "notes": list(r.notes)}
    summary = f"{r.commands} commands, run time {r.run_time_s:.1f} s" + (f"; first divergence: {first}" if first else "")
    return _Done("MATCH" if r.ok else "DIVERGED", EXIT_OK if r.ok else EXIT_FAILED, summary, str(r.replay_file), payload,
                 list(r.notes))


def _calibrate(job: Job, path: Path, out: Path) -> _Done:
    from bench.analysis.per_file import calibrate_file, json_text

    notes: list[str] = []
    result = calibrate_file(job.method or "", path, job.mapping, dict(job.options), on_note=notes.append)
    text = json_text(result.json)
    _write_text(out, text, job.force)
    return _Done("calibrated", summary="; ".join(result.notes), output=str(out), payload=json.loads(text), notes=notes)


def _diagnose(job: Job, path: Path, out: Path) -> _Done:
    from bench.analysis.per_file import diagnose_file, json_text, rows_line

    notes: list[str] = []
    result, _ds = diagnose_file(path, job.mapping, Path(job.model) if job.model else None, on_note=notes.append)
    text = json_text(result.json)
    _write_text(out, text, job.force)
    effects = sorted({f.effect for f in result.findings})
    verdict = f"missing {', '.join(effects)}" if effects else ("UNEXPLAINED" if result.unexplained else "nothing missing")
    return _Done(verdict, summary=rows_line(result) or "", output=str(out), payload=json.loads(text), notes=notes)


def _report(job: Job, path: Path, out: Path) -> _Done:
    from bench.report.run_report import write_report

    write_new(out, lambda tmp: write_report(path, tmp), force=job.force)
    return _Done("written", output=str(out))


def _write_text(out: Path, text: str, force: bool) -> None:
    """The ``--json`` text as the serial command prints it (with its final newline)."""
    write_new(out, lambda tmp: tmp.write_text(text + "\n", encoding="utf-8"), force=force)


_COMMANDS: dict[str, Callable[[Job, Path, Path], _Done]] = {
    "replay": _replay, "calibrate": _calibrate, "diagnose": _diagnose, "report": _report}
