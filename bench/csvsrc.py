"""Read measured-data CSV files with located errors (``file:line: column: problem``).

Lines starting with ``#`` are comments; a comment of the form ``# key: value`` before the header
is metadata (e.g. ``# sample_rate_hz: 100``). The first other line is the header. Every value of a
requested column must be a finite number.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.errors import InputError, Location, finite_number
from bench.inputs import CSV_LIMIT_BYTES, read_input_bytes

_META = re.compile(r"^\s*#\s*([A-Za-z_][A-Za-z0-9_]*)\s*:\s*(.*?)\s*$")


@dataclass
class CsvTable:
    """A parsed CSV file: ``header`` names, data ``rows`` (lists of str) with their 1-based file
    ``lines``, the header's line number and the ``# key: value`` metadata (values as str)."""

    path: Path
    header: list[str]
    header_line: int
    rows: list[list[str]]
    lines: list[int]
    meta: dict[str, str]
    meta_lines: dict[str, int] = field(default_factory=dict)
    """1-based file line of each metadata key, for located messages."""


def read_csv_table(path: str | Path) -> CsvTable:
    """Parse ``path`` into a :class:`CsvTable`; :class:`InputError` when it cannot be read."""
    p = Path(path)
    data = read_input_bytes(p, limit_bytes=CSV_LIMIT_BYTES, what="CSV file")  # regular files of at most 256 MiB
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise InputError(f"cannot read CSV file: byte 0x{data[exc.start]:02x} is not UTF-8 text", Location(p, line)) from None
    # lines end at \n, \r\n or \r only (str.splitlines would also split at form feeds and other
    # characters inside a cell, and the line numbers would no longer be those an editor shows)
    meta: dict[str, str] = {}
    meta_lines: dict[str, int] = {}
    numbered: list[tuple[int, str]] = []
    for i, line in enumerate(text.replace("\r\n", "\n").replace("\r", "\n").split("\n")):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            m = _META.match(stripped)
            if m and not numbered:
                meta[m.group(1)] = m.group(2)
                meta_lines[m.group(1)] = i + 1
            continue
        numbered.append((i + 1, line))
    if not numbered:
        raise InputError("no header line", Location(p, 1))
    # one reader over all lines: a quoted cell may span lines; each row keeps the line it starts on
    reader = csv.reader([line + "\n" for _, line in numbered], strict=True)
    rows: list[list[str]] = []
    lines: list[int] = []
    start = 0
    try:
        for row in reader:
            rows.append(row)
            lines.append(numbered[start][0])
            start = reader.line_num
    except csv.Error as exc:  # an unterminated quote, a field beyond the csv module's size limit
        raise InputError(f"not valid CSV: {exc}", Location(p, numbered[min(start, len(numbered) - 1)][0])) from None
    return CsvTable(p, [h.strip() for h in rows[0]], lines[0], rows[1:], lines[1:], meta, meta_lines)


def numeric_columns(table: CsvTable, columns: list[str]) -> dict[str, np.ndarray]:
    """The named columns of ``table`` as float arrays; every cell must be a finite number."""
    index: dict[str, int] = {}
    for name in columns:
        if name not in table.header:
            raise InputError(f"missing column (header has: {', '.join(table.header) or 'nothing'})",
                             Location(table.path, table.header_line), name)
        if table.header.count(name) > 1:
            raise InputError("column named twice in the header", Location(table.path, table.header_line), name)
        index[name] = table.header.index(name)
    values = {name: np.empty(len(table.rows)) for name in columns}
    for r, (row, ln) in enumerate(zip(table.rows, table.lines)):
        if len(row) != len(table.header):
            raise InputError(f"expected {len(table.header)} values like the header, got {len(row)}", Location(table.path, ln))
        for name, j in index.items():
            cell = row[j].strip()
            if "_" in cell:  # float() reads "1_000" as 1000: not a number in a data file
                raise InputError(f"expected a number, got {cell!r}", Location(table.path, ln), name)
            values[name][r] = finite_number(cell, Location(table.path, ln), name)
    return values


def read_numeric_csv(path: str | Path, columns: list[str]) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The requested ``columns`` as float arrays, plus the 1-based file line of every row.

    Raises :class:`InputError` naming the file, line and column of the first problem.
    """
    table = read_csv_table(path)
    return numeric_columns(table, columns), np.array(table.lines, dtype=np.int64)
