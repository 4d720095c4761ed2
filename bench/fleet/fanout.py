"""The files of a fleet submitted to the workers, one task each, and the results collected as they
finish (:func:`run_fleet`).

Each task is :func:`bench.fleet.tasks.run_file` on one file; its result comes back as soon as it is
done (``on_result``: progress), and the results are returned in the files' order. A task whose
worker died (a file that crashes the HDF5 library kills its process; dask retries it on other
workers, then gives up) or that was cancelled (the scheduler went away) is a failed file with the
reason, and the others finish. Every wait is bounded: when no file has finished for
``file_timeout_s`` the files still out are cancelled and reported as timed out.
"""

from __future__ import annotations

import functools
import time
import uuid
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, Sequence

from bench.errors import EXIT_FAILED
from bench.fleet.files import RunFileRef
from bench.fleet.tasks import FileResult, Job, run_file

if TYPE_CHECKING:
    from distributed import Client, Future

POLL_S = 0.02
"""How often finished tasks are looked for (s of wall time)."""
DEFAULT_FILE_TIMEOUT_S = 3600.0
"""Default longest wait for the next file to finish (s): 1 h."""


@dataclass
class FleetRun:
    """What a fleet did: one result per file (in the files' order) and the wall time (s) from the
    first submission to the last result."""

    results: list[FileResult] = field(default_factory=list)
    wall_s: float = 0.0

    @property
    def failed(self) -> list[FileResult]:
        """The files that were not done, or whose replay diverged."""
        return [r for r in self.results if not r.ok]


def run_fleet(client: "Client", job: Job, files: Sequence[RunFileRef], *,
              on_result: Callable[[FileResult], None] | None = None,
              file_timeout_s: float = DEFAULT_FILE_TIMEOUT_S) -> FleetRun:
    """Run ``job`` on every file of ``files`` on ``client``'s workers; ``on_result`` hears each
    result as it arrives. Never raises for a file: its failure is its result."""
    t0 = time.perf_counter()
    tag = uuid.uuid4().hex[:8]
    futures = client.map(functools.partial(run_file, job), [str(f.path) for f in files], [f.rel for f in files],
                         key=[f"fleet-{job.command}-{tag}-{i}" for i in range(len(files))], pure=False, retries=0)
    index = {fut.key: i for i, fut in enumerate(futures)}
    results: list[FileResult | None] = [None] * len(files)
    pending = set(futures)
    last = time.monotonic()
    try:
        while pending:
            done = [f for f in pending if f.done()]
            if not done:
                if time.monotonic() - last > file_timeout_s:
                    for fut in pending:
                        fut.cancel()
                        i = index[fut.key]
                        results[i] = _failed(files[i], f"no file finished within {file_timeout_s:g} s (--file-timeout); cancelled")
                        if on_result is not None:
                            on_result(results[i])
                    break
                time.sleep(POLL_S)
                continue
            last = time.monotonic()
            for fut in done:
                pending.discard(fut)
                i = index[fut.key]
                results[i] = _collect(fut, files[i], file_timeout_s)
                fut.release()
                if on_result is not None:
                    on_result(results[i])
    finally:
        for fut in pending:  # an interrupt: nothing left running on the workers
            fut.cancel()
    return FleetRun([r for r in results if r is not None], time.perf_counter() - t0)


def _collect(fut: "Future", ref: RunFileRef, timeout_s: float) -> FileResult:
    """The result of a finished task, or a failed file saying why there is none."""
    if fut.status == "finished":
        try:
            return fut.result(timeout=timeout_s)
        except Exception as exc:  # noqa: BLE001 - the result was lost on the way back
            return _failed(ref, f"the result could not be fetched: {type(exc).__name__}: {exc}")
    if fut.status == "error":
        exc = fut.exception(timeout=timeout_s)
        return _failed(ref, f"the worker failed on this file: {type(exc).__name__}: {exc}")
    return _failed(ref, f"the task was {fut.status} (the scheduler or its workers went away?)")


def _failed(ref: RunFileRef, why: str) -> FileResult:
    return FileResult(str(ref.path), ref.rel, EXIT_FAILED, "ERROR", error=why)
