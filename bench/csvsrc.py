"""Read measured-data CSV files with located errors (``file:line: column: problem``).

Lines starting with ``#`` are comments; a comment of the form ``# key: value`` before the header
is metadata (e.g. ``# sample_rate_hz: 100``). The first other line is the header. Every value of a
requested column must be a finite number.

Two readers: :func:`read_csv_table` keeps every cell as text (small tables: rate-transfer steps);
:func:`read_numeric_table` reads the numeric columns of a measured-data file straight into float
arrays, a block of lines (1 MiB) at a time (no Python object per cell: 1,000,000 rows of 8 columns take
the file's bytes plus 8 bytes per value), falling back to the per-cell reader from the first block
that is not plain numbers (quotes, comments, blank lines, a bad cell), which gives the same located
messages.
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
    index = _column_index(table.path, table.header, table.header_line, columns)
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


@dataclass
class NumericTable:
    """The requested columns of a CSV file as float arrays, with the header, metadata and the 1-based
    file line of every row (:func:`read_numeric_table`)."""

    path: Path
    header: list[str]
    header_line: int
    columns: dict[str, np.ndarray]
    lines: np.ndarray
    meta: dict[str, str]
    meta_lines: dict[str, int] = field(default_factory=dict)

    @property
    def rows(self) -> int:
        return int(self.lines.shape[0])


BLOCK_BYTES = 1 << 20
"""Bytes of data lines parsed at a time by :func:`read_numeric_table`."""
_PLAIN_BYTES = b"0123456789eE+-.,\n\r \t"
"""The bytes of plain numbers, commas and line ends: a block with any other byte (quotes, comments,
letters) goes to the per-cell reader (``bytes.translate`` deleting these: one C pass, ~50x faster
than a regular-expression search over the block)."""


def read_numeric_table(path: str | Path, wanted) -> NumericTable:
    """The header, metadata and the columns named by ``wanted(header) -> list[str]`` of ``path`` as
    float arrays (every cell a finite number), parsed block by block; :class:`InputError` located at
    file:line and column for the first problem, as :func:`numeric_columns` says it."""
    p = Path(path)
    data = read_input_bytes(p, limit_bytes=CSV_LIMIT_BYTES, what="CSV file")
    view = memoryview(data)
    pos, line_no = 0, 0
    meta: dict[str, str] = {}
    meta_lines: dict[str, int] = {}
    if data.startswith(b"\xef\xbb\xbf"):
        pos = 3
    header_line = None
    while pos < len(data):  # metadata, comments and blank lines, then the header
        end = data.find(b"\n", pos)
        end = len(data) if end < 0 else end
        raw = bytes(view[pos:end])
        line_no += 1
        pos = end + 1
        if b"\r" in raw.rstrip(b"\r"):  # old-Mac line ends: the per-cell reader numbers those lines
            return _numeric_via_table(p, wanted)
        try:
            text = raw.decode("utf-8").rstrip("\r")
        except UnicodeDecodeError:
            return _numeric_via_table(p, wanted)
        stripped = text.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            m = _META.match(stripped)
            if m:
                meta[m.group(1)] = m.group(2)
                meta_lines[m.group(1)] = line_no
            continue
        if '"' in text:
            return _numeric_via_table(p, wanted)
        header_line = line_no
        header = [h.strip() for h in next(csv.reader([text]))]
        break
    if header_line is None:
        raise InputError("no header line", Location(p, 1))
    names = wanted(header)
    index = _column_index(p, header, header_line, names)
    width = len(header)
    if not names:
        return NumericTable(p, header, header_line, {}, np.empty(0, dtype=np.int64), meta, meta_lines)
    out_cols: list[list[np.ndarray]] = [[] for _ in names]
    out_lines: list[np.ndarray] = []
    usecols = [index[n] for n in names]
    while pos < len(data):
        stop = min(pos + BLOCK_BYTES, len(data))
        if stop < len(data):
            nl = data.rfind(b"\n", pos, stop)
            stop = len(data) if nl < 0 else nl + 1
        block = view[pos:stop]
        parsed = _plain_block(bytes(block), width, usecols)
        if parsed is None:  # not plain numbers: the per-cell reader from this line on
            rest = _numeric_via_table(p, wanted, first_line=line_no + 1)
            for k, n in enumerate(names):
                out_cols[k].append(rest.columns[n])
            out_lines.append(rest.lines)
            break
        values, count = parsed
        for k in range(len(names)):
            out_cols[k].append(values[:, k])
        out_lines.append(np.arange(line_no + 1, line_no + 1 + count, dtype=np.int64))
        line_no += count
        pos = stop
    cols = {n: (np.concatenate(out_cols[k]) if out_cols[k] else np.empty(0)) for k, n in enumerate(names)}
    lines = np.concatenate(out_lines) if out_lines else np.empty(0, dtype=np.int64)
    return NumericTable(p, header, header_line, cols, lines, meta, meta_lines)


def _plain_block(block: bytes, width: int, usecols: list[int]) -> tuple[np.ndarray, int] | None:
    """(values (rows, len(usecols)), rows) of a block of whole lines that are plain numbers with
    ``width`` cells each, every value finite; None for anything else (the per-cell reader decides)."""
    if not block or block.translate(None, _PLAIN_BYTES):
        return None
    b = np.frombuffer(block, dtype=np.uint8)
    ends = np.flatnonzero(b == 10)
    if ends.size == 0 or ends[-1] != b.size - 1:
        ends = np.append(ends, b.size)
    starts = np.concatenate([[0], ends[:-1] + 1])
    if np.any(ends - starts < 1):  # a blank line
        return None
    commas = np.flatnonzero(b == 44)
    per_line = np.diff(np.searchsorted(commas, np.concatenate([[0], ends])))
    if np.any(per_line != width - 1):
        return None
    import io

    try:
        v = np.loadtxt(io.BytesIO(block), delimiter=",", usecols=usecols, ndmin=2, dtype=float)
    except ValueError:
        return None
    if v.shape[0] != ends.size or not np.all(np.isfinite(v)):
        return None
    return v, int(ends.size)


def _column_index(p: Path, header: list[str], header_line: int, columns: list[str]) -> dict[str, int]:
    index: dict[str, int] = {}
    for name in columns:
        if name not in header:
            raise InputError(f"missing column (header has: {', '.join(header) or 'nothing'})",
                             Location(p, header_line), name)
        if header.count(name) > 1:
            raise InputError("column named twice in the header", Location(p, header_line), name)
        index[name] = header.index(name)
    return index


def _numeric_via_table(p: Path, wanted, first_line: int = 0) -> NumericTable:
    """:func:`read_numeric_table` by the per-cell reader (rows from file line ``first_line`` on)."""
    table = read_csv_table(p)
    names = wanted(table.header)
    keep = [i for i, ln in enumerate(table.lines) if ln >= first_line]
    if len(keep) != len(table.lines):
        table.rows = [table.rows[i] for i in keep]
        table.lines = [table.lines[i] for i in keep]
    cols = numeric_columns(table, names)
    return NumericTable(table.path, table.header, table.header_line, cols, np.array(table.lines, dtype=np.int64),
                        table.meta, table.meta_lines)


def read_numeric_csv(path: str | Path, columns: list[str]) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The requested ``columns`` as float arrays, plus the 1-based file line of every row.

    Raises :class:`InputError` naming the file, line and column of the first problem.
    """
    table = read_csv_table(path)
    return numeric_columns(table, columns), np.array(table.lines, dtype=np.int64)
