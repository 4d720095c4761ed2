"""What every driver shares: its timeout, retries of idempotent reads, typed errors, safe state.

A driver subclasses :class:`Driver`, names its ``kind``, says whether it ``streams`` frames, and
implements ``identify()``, ``safe_state() -> str`` (what the instrument was told) and ``close()``:
the runner's ``bench.runner.instruments.Instrument`` protocol; a part of a composite instrument
(the F4 controller inside ``tvac``) leaves the first two to the composite. Reads go through
:meth:`Driver.read_retrying`: one attempt function, called again only when it raises
:class:`Transient` (a lost link, a "busy" answer, a reply that never came) and only as many
times as the driver's ``read_attempts`` allows. Writes and commands with side effects are
never retried: a timeout leaves their outcome unknown, so the caller decides.

Errors are the typed ones of :mod:`drivers.errors`; the application catches them by name.
"""

from __future__ import annotations

import math
import time
from typing import Any, Callable, ClassVar, TypeVar

from drivers.errors import InstrumentError

T = TypeVar("T")


class Transient(Exception):
    """One attempt of an idempotent read failed in a way that may not repeat.

    ``error`` is what the caller sees when no attempt is left; ``pause_s`` (s) is how long to
    wait before the next attempt (e.g. after a controller said it was busy)."""

    def __init__(self, error: InstrumentError, pause_s: float = 0.0):
        super().__init__(str(error))
        self.error = error
        self.pause_s = pause_s


def check_timeout(timeout_s: float) -> float:
    """A driver timeout (s): finite and positive, else ``ValueError``."""
    t = float(timeout_s)
    if not math.isfinite(t) or t <= 0:
        raise ValueError(f"timeout must be a positive number of seconds, got {timeout_s!r}")
    return t


class Driver:
    """Base class of the instrument drivers."""

    kind: ClassVar[str] = ""
    """The ``driver:`` name of a lab config (``acs_board``, ``tvac``…)."""
    streams: ClassVar[bool] = False
    """Whether the runner records a data stream of this instrument (else its commands and readings)."""
    read_attempts: int = 1
    """Attempts of one idempotent read (1 = never retried). Each attempt is bounded by ``timeout_s``
    unless the driver divides its timeout among them (documented where it does)."""

    timeout_s: float
    """Longest wait for one answer (s)."""
    name: str = ""
    """How errors name the instrument."""
    port: Any = None
    """The pyserial port of a driver on a serial link (or a port-like CAN byte stream); None otherwise."""

    def read_retrying(self, attempt: Callable[[int], T], *, attempts: int | None = None,
                      sleep: Callable[[float], None] = time.sleep) -> T:
        """Call ``attempt(i)`` (i = 0, 1, …) until it returns; each :class:`Transient` it raises
        costs one of ``attempts`` (default :attr:`read_attempts`), and the last one's ``error``
        is raised. Any other exception ends the read at once."""
        n = max(1, self.read_attempts if attempts is None else attempts)
        for i in range(n):
            try:
                return attempt(i)
            except Transient as exc:
                if i + 1 >= n:
                    raise exc.error from None
                if exc.pause_s > 0:
                    sleep(exc.pause_s)
        raise AssertionError("unreachable")  # pragma: no cover

    @property
    def baudrate(self) -> int | None:
        """Serial bit rate of the link (bit/s), None when the link is not a serial port."""
        rate = getattr(self.port, "baudrate", None)
        return int(rate) if rate else None

    def close(self) -> None:
        """Release the link."""
