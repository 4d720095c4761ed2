"""What every ``bench`` command shares on the command line.

* :class:`Parser`: usage errors as one line and exit code 2; ``--debug`` accepted after any
  subcommand as well as before it; help texts keep their line breaks (examples, exit codes).
* :func:`epilog`: the "exit codes" and "examples" block at the end of each command's ``--help``.
* :func:`add_force`, :func:`check_output`, :func:`output_file`: output files are never
  overwritten unless ``--force`` is given, and never replaced by a half-written file.

Light on purpose (argparse and :mod:`bench.errors` only): ``bench --help`` and ``bench --version``
import nothing else.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import textwrap
from pathlib import Path
from typing import Iterable

from bench.errors import EXIT_BAD_INPUT, InputError
from bench.outputs import exists_error as _exists
from bench.outputs import refuse_special

DEBUG_HELP = "show the traceback of an error instead of one line (accepted before or after the command)"

BAD_INPUT = "bad input: one located line per problem (file:line:column: field: message), nothing run or written"
"""Exit code 2 as every command means it (``bench.errors.EXIT_BAD_INPUT``)."""

INTERNAL = "an unexpected error (one line; --debug shows the traceback)"
"""Exit code 1 of commands that have no failure of their own."""


class HelpFormatter(argparse.HelpFormatter):
    """Descriptions are filled to the terminal width; text with line breaks (the epilog of
    :func:`epilog`: exit codes, examples) is kept as written, so examples stay copyable."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if "\n" in text:
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)


class Parser(argparse.ArgumentParser):
    """argparse that reports usage errors as one line and exit code 2.

    Every subparser (``top_level=False``, what ``add_subparsers(parser_class=Parser)`` creates)
    also takes ``--debug``; its default is ``SUPPRESS`` so that a subcommand without it leaves the
    top-level value alone (``bench --debug run ...`` and ``bench run ... --debug`` are the same).
    """

    def __init__(self, *args, top_level: bool = False, **kwargs) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)
        if top_level:
            self.add_argument("--debug", action="store_true", help=DEBUG_HELP)
        else:
            self.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=DEBUG_HELP)

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


LAB_CONFIG = "configs/lab.yaml"
"""The lab config the examples name: each lab makes its own (it is not in the repository)."""
LAB_CONFIG_NOTE = (f"{LAB_CONFIG} is your lab's config: make it with 'bench lab init -o {LAB_CONFIG}' (an example of a real "
                   "lab: configs/lab.example.yaml); configs/sim.yaml is the simulated lab every dry-run (--sim) can use.")
"""Said under every ``--help`` whose examples name :data:`LAB_CONFIG`."""


def epilog(*examples: str, ok: str, failed: str = INTERNAL, bad: str = BAD_INPUT, notes: str = "") -> str:
    """The end of a command's ``--help``: optional notes, its exit codes, one example per line.

    ``ok``, ``failed`` and ``bad`` say what exit codes 0, 1 and 2 mean for this command. Notes and
    exit codes are wrapped to the terminal; examples never are. Examples that name
    :data:`LAB_CONFIG` (which each lab makes) get :data:`LAB_CONFIG_NOTE` under them.
    """
    width = max(60, min(shutil.get_terminal_size().columns, 120) - 2)
    if any(LAB_CONFIG in e for e in examples) and "bench lab init" not in notes:
        notes = f"{notes} {LAB_CONFIG_NOTE}".strip()
    lines = textwrap.wrap(notes, width) + [""] if notes else []
    lines.append("exit codes:")
    for code, text in (("0", ok), ("1", failed), ("2", bad)):
        lines += textwrap.wrap(text, width, initial_indent=f"  {code}  ", subsequent_indent="     ")
    lines += ["", "examples:", *(f"  {e}" for e in examples)]
    return "\n".join(lines)


def quantity(value: str, units: str, option: str) -> float:
    """A command-line quantity ("2h", "90 min", "0.1/min") as a float in ``units``; a bare number
    ("2") is already in ``units``. :class:`InputError` naming ``option`` (exit 2) for anything
    else: not a quantity, wrong dimension, not finite."""
    try:
        number = float(value)
    except ValueError:
        from bench.units import to_units  # pint: only when a unit is written

        return to_units(value, units, None, option)
    if not math.isfinite(number):
        raise InputError(f"{value!r} is not a finite quantity", None, option)
    return number


def add_force(p: argparse.ArgumentParser) -> None:
    """``--force``: overwrite existing output files (default: refuse them with exit code 2)."""
    p.add_argument("--force", action="store_true",
                   help="overwrite output files that exist (default: refuse them, exit 2, nothing written)")


def check_output(path: Path | None, option: str, *, force: bool = False, inputs: Iterable[Path | None] = ()) -> None:
    """Refuse an output ``path`` (given by ``option``, e.g. ``-o``) that exists unless ``force``,
    and always one that is also an input of the command: :class:`InputError` (exit 2), before any
    work is done. ``None`` (option not given) passes."""
    if path is None:
        return
    for src in inputs:
        if src is not None and _same_file(path, src):
            raise InputError(f"{path} is also the input; write the output to another file", None, option)
    refuse_special(path, option)
    if os.path.lexists(path) and not force:
        raise _exists(path, option)
    parent = Path(path).parent
    if not parent.is_dir():
        raise InputError(f"directory {parent} does not exist; create it or write elsewhere", None, option)


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False
