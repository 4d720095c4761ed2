"""Read measured-data CSV files with located errors (``file:line: column: problem``).

Lines starting with ``#`` are comments (they may carry metadata). The first other line is the
header. Every value of a requested column must be a finite number.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from bench.errors import InputError, Location


def read_numeric_csv(path: str | Path, columns: list[str]) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The requested ``columns`` as float arrays, plus the 1-based file line of every row.

    Raises :class:`InputError` naming the file, line and column of the first problem.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise InputError("CSV file not found", Location(p)) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read CSV file: {exc}", Location(p)) from None
    lines = [(i + 1, line) for i, line in enumerate(text.splitlines()) if line.strip() and not line.lstrip().startswith("#")]
    if not lines:
        raise InputError(f"no header line; expected columns {', '.join(columns)}", Location(p, 1))
    try:
        rows = list(csv.reader([line for _, line in lines]))
    except csv.Error as exc:
        raise InputError(f"not valid CSV: {exc}", Location(p)) from None
    header_line, header = lines[0][0], [h.strip() for h in rows[0]]
    index: dict[str, int] = {}
    for name in columns:
        if name not in header:
            raise InputError(f"missing column (header has: {', '.join(header) or 'nothing'})", Location(p, header_line), name)
        index[name] = header.index(name)
    values = {name: np.empty(len(rows) - 1) for name in columns}
    line_numbers = np.array([ln for ln, _ in lines[1:]], dtype=np.int64)
    for r, (row, (ln, _)) in enumerate(zip(rows[1:], lines[1:])):
        if len(row) != len(header):
            raise InputError(f"expected {len(header)} values like the header, got {len(row)}", Location(p, ln))
        for name, j in index.items():
            cell = row[j].strip()
            try:
                v = float(cell)
            except ValueError:
                raise InputError(f"expected a number, got {cell!r}", Location(p, ln), name) from None
            if not math.isfinite(v):
                raise InputError(f"expected a finite number, got {cell!r}", Location(p, ln), name)
            values[name][r] = v
    return values, line_numbers
