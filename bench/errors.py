"""Error types shared by every layer, and the exit codes they map to.

Exit codes of the ``bench`` command: 0 success, 1 run failed or aborted, 2 bad input.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from bench.terminal_text import printable
from drivers.errors import DeviceFault, InstrumentError, InstrumentTimeout, NotConfigured, ProtocolError

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_BAD_INPUT = 2


class BenchError(Exception):
    """Base class of every error bench raises on purpose."""


#: What bench raises on purpose: its own errors and the drivers' typed instrument errors
#: (``drivers.errors``, re-exported here; drivers import nothing from bench).
KNOWN_ERRORS: tuple[type[Exception], ...] = (BenchError, InstrumentError)

__all__ = ["EXIT_OK", "EXIT_FAILED", "EXIT_BAD_INPUT", "BenchError", "KNOWN_ERRORS", "Location", "InputError",
           "InputErrors", "DestinationError", "RecorderError", "InstrumentError", "InstrumentTimeout",
           "ProtocolError", "DeviceFault", "NotConfigured"]


@dataclass
class Location:
    """Where in an input file something is: 1-based line and column."""

    file: str | Path
    line: int | None = None
    column: int | None = None

    def __str__(self) -> str:
        out = str(self.file)
        if self.line is not None:
            out += f":{self.line}"
            if self.column is not None:
                out += f":{self.column}"
        return out


class InputError(BenchError):
    """Bad input (procedure, config, CSV, run file, command line): exit code 2.

    ``str()`` gives one line: ``file:line:column: field: message``, with control characters (a
    newline in a file name, an escape sequence in a run file's text) shown as escapes
    (:func:`bench.terminal_text.printable`), so a message is always exactly one line.
    """

    def __init__(self, message: str, location: Location | None = None, field: str | None = None):
        self.message = message
        self.location = location
        self.field = field
        super().__init__(self.one_line())

    def one_line(self) -> str:
        parts = []
        if self.location is not None:
            parts.append(str(self.location))
        if self.field:
            parts.append(self.field)
        parts.append(self.message)
        return printable(": ".join(parts))


def finite_number(value: object, where: Location | None, field: str | None) -> float:
    """``value`` (a text or a number from an input) as a finite float; :class:`InputError`
    ("expected a number" / "expected a finite number", located at ``where``, ``field``) otherwise."""
    try:
        v = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"expected a number, got {value!r}", where, field) from None
    if not math.isfinite(v):
        raise InputError(f"expected a finite number, got {value!r}", where, field)
    return v


class DestinationError(InputError):
    """The runs directory cannot take the run (unwritable, missing space). Refused before the run."""


class RecorderError(BenchError):
    """Writing the run file failed during the run. The runner aborts to the safe state."""


class InputErrors(InputError):
    """Several located input errors at once (a procedure or config with many problems).

    ``errors`` holds each one; ``str()`` is the first. The CLI prints one line per error.
    """

    def __init__(self, errors: list[InputError]):
        self.errors = list(errors)
        first = self.errors[0]
        super().__init__(first.message, first.location, first.field)
