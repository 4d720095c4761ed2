"""The workers of a fleet: an embedded ``LocalCluster`` or an existing dask.distributed scheduler.

The embedded cluster runs ``workers`` worker **processes** with one thread each (HDF5 serialises
the threads of one process: h5py#591, #1806), its scheduler, nannies and workers listening on
127.0.0.1 only, and no dashboard unless asked for (then on 127.0.0.1, a free port). Starting it is
bounded by ``timeout_s``: each worker process must start within it (the nannies' death timeout)
and all must have joined within it. ``scheduler="tcp://HOST:PORT"`` connects to an existing
cluster instead: the connection and the first worker are awaited at most ``timeout_s`` each.
A malformed address, a scheduler that does not answer, or no worker within the timeout is bad
input (:class:`InputError` on ``--scheduler`` or ``--workers``): nothing has run.
"""

from __future__ import annotations

import logging
import os
import re
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Iterator

from bench.errors import InputError

if TYPE_CHECKING:
    from distributed import Client

DEFAULT_TIMEOUT_S = 60.0
"""Default bound on starting the embedded cluster or reaching a scheduler (s)."""

LOOPBACK_ANY_PORT = "127.0.0.1:0"
"""Where the embedded cluster's HTTP server listens: loopback, a free port."""

WORKER_CONFIG = {"distributed.worker.profile.enabled": False}
"""dask settings of the embedded cluster's workers: no statistical profiler (a thread that takes the
GIL a hundred times a second to sample the stack of the work, which is all Python and HDF5 here)."""

_ADDRESS = re.compile(r"tcp://(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(?P<port>[0-9]{1,5})")


@dataclass
class Workers:
    """A connected client and what it reaches: the scheduler's ``address``, the number of
    ``workers`` (at connection), the dashboard's link (embedded cluster with a dashboard), and
    whether the cluster is the embedded one."""

    client: "Client"
    address: str
    workers: int
    dashboard: str | None
    embedded: bool


def default_workers() -> int:
    """The embedded cluster's default size: the cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def check_scheduler(address: str) -> str:
    """``address`` if it is ``tcp://HOST:PORT`` with a port in 1..65535; else :class:`InputError`
    on ``--scheduler``."""
    m = _ADDRESS.fullmatch(address.strip())
    if m is None or not 1 <= int(m["port"]) <= 65535:
        raise InputError(f"expected a scheduler address tcp://HOST:PORT (port 1 to 65535), got {address!r}", None, "--scheduler")
    return address.strip()


def check_options(scheduler: str | None, workers: int | None, timeout_s: float) -> None:
    """:class:`InputError` for options :func:`connect` cannot use: a timeout <= 0 s, a malformed
    scheduler address, ``workers`` < 1 or given with a scheduler. Checked before anything starts."""
    if timeout_s <= 0:
        raise InputError(f"the timeout must be > 0 s, got {timeout_s:g} s", None, "--timeout")
    if scheduler is not None:
        check_scheduler(scheduler)
        if workers is not None:
            raise InputError("--workers sizes the embedded cluster; an existing one (--scheduler) has its own workers", None, "--workers")
    if workers is not None and workers < 1:
        raise InputError(f"expected at least 1 worker, got {workers}", None, "--workers")


@contextmanager
def connect(scheduler: str | None = None, *, workers: int | None = None, timeout_s: float = DEFAULT_TIMEOUT_S,
            dashboard: bool = False) -> Iterator[Workers]:
    """A client on the embedded cluster (``scheduler`` None; ``workers`` processes, default
    :func:`default_workers`) or on the scheduler at ``scheduler``; closed (and the embedded cluster
    stopped) when the block ends. Every wait is bounded by ``timeout_s`` (s)."""
    check_options(scheduler, workers, timeout_s)
    n = default_workers() if workers is None else workers
    import dask
    from distributed import Client, LocalCluster
    from distributed.exceptions import WorkerStartTimeoutError

    with ExitStack() as stack:
        if scheduler is None:
            try:
                # the scheduler's HTTP server (health, metrics; the dashboard when asked for) on
                # 127.0.0.1 and a free port, never dask's default of port 8787; the workers' config is
                # taken from this process's when the nannies are made
                with dask.config.set(WORKER_CONFIG):
                    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                                           dashboard_address=LOOPBACK_ANY_PORT if dashboard else None,
                                           scheduler_kwargs={"dashboard_address": LOOPBACK_ANY_PORT},
                                           silence_logs=logging.CRITICAL, death_timeout=timeout_s)
            except Exception as exc:  # noqa: BLE001 - any failure to start is reported as one line
                raise InputError(f"the embedded cluster of {n} worker(s) did not start (timeout {timeout_s:g} s): {exc}",
                                 None, "--workers") from None
            stack.callback(cluster.close, timeout=timeout_s)
            client = stack.enter_context(Client(cluster, timeout=timeout_s))
            try:
                client.wait_for_workers(n, timeout=timeout_s)
            except (WorkerStartTimeoutError, TimeoutError) as exc:
                raise InputError(f"the embedded cluster's workers did not start within {timeout_s:g} s: {exc}",
                                 None, "--workers") from None
            link = cluster.dashboard_link if dashboard else None
            yield Workers(client, cluster.scheduler_address, n, link, True)
            return
        address = check_scheduler(scheduler)
        try:
            client = stack.enter_context(Client(address, timeout=timeout_s))
        except (OSError, TimeoutError) as exc:
            raise InputError(f"no dask scheduler answered at {address} within {timeout_s:g} s ({exc})", None, "--scheduler") from None
        try:
            client.wait_for_workers(1, timeout=timeout_s)
        except (WorkerStartTimeoutError, TimeoutError):
            raise InputError(f"the scheduler at {address} has no worker (none joined within {timeout_s:g} s)", None,
                             "--scheduler") from None
        count = len(client.scheduler_info(n_workers=-1).get("workers", {}))
        yield Workers(client, address, count, None, False)
