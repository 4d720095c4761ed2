"""Rich tables that stay readable in an 80-column terminal: every value in full (never cut to "…"),
units in the headers, prose wrapped at spaces.

:func:`fit_tables` measures the columns and, when they do not fit side by side, splits them over
several tables that repeat the key columns (e.g. ``axis``), instead of letting rich shrink and cut
them. :func:`pack` joins short items ("set_point 66 degC") into lines of a given width, breaking only
between items, so a value is never separated from its unit.

Used by the tables of ``bench plan``, ``bench calibrate``, ``bench inspect`` and the summary of
``bench run``; ``bench watch`` lays out its own screen. Imports only rich, so every layer may use it.
Widths are in terminal cells.
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence

from rich.cells import cell_len
from rich.table import Table
from rich.text import Text

PROSE_MIN = 16
"""Narrowest a prose column (wrapped at spaces) is made, cells, unless its longest word is longer."""


def table_overhead(columns: int) -> int:
    """Cells a rich table with the default box and padding (0, 1) adds to its columns' widths: a
    border between and around the columns and one space each side of every cell."""
    return 3 * columns + 1


def longest_line(text: str) -> int:
    """Width (cells) of the longest line of ``text``."""
    return max((cell_len(line) for line in text.split("\n")), default=0)


def longest_word(text: str) -> int:
    """Width (cells) of the longest run of non-space characters of ``text`` (where a wrap cannot break)."""
    return max((cell_len(w) for w in text.split()), default=0)


def is_number(text: str) -> bool:
    """Whether ``text`` reads as a number (or is a ``-`` placeholder): such columns are right-aligned."""
    if text.strip() in ("", "-"):
        return True
    try:
        float(text.replace("−", "-"))
    except ValueError:
        return False
    return True


def pack(parts: Sequence[str], width: int, sep: str = ", ") -> str:
    """``parts`` joined by ``sep`` into lines of at most ``width`` cells, breaking only between parts
    (a part longer than ``width`` gets a line of its own, which the table then wraps at its spaces)."""
    lines: list[str] = []
    line = ""
    tail = sep.rstrip()  # what ends a line that continues on the next
    for k, p in enumerate(parts):
        candidate = f"{line}{sep}{p}" if line else p
        more = tail if k + 1 < len(parts) else ""
        if line and cell_len(candidate + more) > width:
            lines.append(line + tail)
            line = p
        else:
            line = candidate
    if line:
        lines.append(line)
    return "\n".join(lines)


def fit_tables(headers: Sequence[str], rows: Sequence[Sequence[str | Text]], width: int, *, title: str = "", key: int = 1,
               prose: Sequence[int] = ()) -> list[Table]:
    """Rich tables showing ``rows`` under ``headers`` within ``width`` cells. Cells are shown as they
    read (a ``str`` is never taken for rich markup: ``[axis=z]`` stays); a :class:`rich.text.Text`
    cell keeps its style.

    Every column is as wide as its widest value (no wrapping, never cut), except the ``prose``
    columns (indices), which wrap at spaces and are at least :data:`PROSE_MIN` cells (or their
    longest word) wide; so is a column too wide to stand beside the key columns. Headers wrap at
    spaces to their column. Numeric columns are right-aligned.
    When the columns do not fit side by side, they are spread evenly over as few tables as fit, each
    repeating the first ``key`` columns, titled ``TITLE (1/n)``, ``(continued, 2/n)``, ..."""
    n = len(headers)
    styled = [[c if isinstance(c, Text) else Text("" if c is None else str(c)) for c in r] + [Text("")] * (n - len(r)) for r in rows]
    cells = [[c.plain for c in r] for r in styled]
    naturals = [max(max((longest_line(r[j]) for r in cells), default=0), longest_word(headers[j]), 1) for j in range(n)]
    room = width - table_overhead(key + 1) - sum(naturals[:key])
    prose = {j for j in range(n) if j in prose or (j >= key and naturals[j] > room)}  # too wide to stand unwrapped
    mins = []
    for j in range(n):
        natural = naturals[j]
        if j in prose:
            natural = min(natural, max(PROSE_MIN, max((longest_word(r[j]) for r in cells), default=0), longest_word(headers[j])))
        mins.append(natural)
    groups = _groups(mins, width, key)
    tables = []
    for g, cols in enumerate(groups):
        name = title
        if len(groups) > 1:
            name = f"{title} ({g + 1}/{len(groups)})" if g == 0 else f"(continued, {g + 1}/{len(groups)})"
        t = Table(title=name or None)
        for j in cols:
            numeric = all(is_number(r[j]) for r in cells) and j not in prose
            t.add_column("\n".join(textwrap.wrap(headers[j], mins[j], break_long_words=False)) or headers[j],
                         justify="right" if numeric else "left", no_wrap=j not in prose, overflow="fold", min_width=mins[j])
        for r in styled:
            t.add_row(*(r[j] for j in cols))
        tables.append(t)
    return tables


def _groups(mins: list[int], width: int, key: int) -> list[list[int]]:
    """Column indices per table: the first ``key`` columns in each, the others in order, spread as
    evenly as fits over as few tables as ``width`` allows (a lone column where one does not fit)."""
    keys = list(range(min(key, len(mins))))
    rest = list(range(len(keys), len(mins)))
    fits = lambda cols: sum(mins[i] for i in keys + cols) + table_overhead(len(keys) + len(cols)) <= width  # noqa: E731
    for count in range(1, len(rest) + 1):
        size, extra = divmod(len(rest), count)
        chunks, at = [], 0
        for g in range(count):
            n = size + (1 if g < extra else 0)
            chunks.append(rest[at:at + n])
            at += n
        if all(fits(c) for c in chunks):
            return [keys + c for c in chunks]
    return [keys + [j] for j in rest] or [keys]
