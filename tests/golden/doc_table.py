"""The byte literals of a golden document's table (docs/golden/*.md), for the tests that check that
their own literals are the document's.

In those tables a row is ``| id | exchange | host → device | device → host | … |``; bytes on the wire
are written in backticks with control characters by their ASCII names (``<CR>``, ``<LF>``, ``<ACK>``;
ANSI X3.4-1986 / ECMA-6 table of control characters). A backtick segment is a byte literal when it is
one whole line (it ends with a control character) or one control character; other segments are prose
(a value quoted, a format such as ``SD.DDDDDDDDESDD,…<CR><LF>`` with its ``…``). A cell without a
literal that says ``as ID`` has the literals of row ID's cell.
"""

from __future__ import annotations

import re
from pathlib import Path

CONTROL_NAMES = ("NUL", "SOH", "STX", "ETX", "EOT", "ENQ", "ACK", "BEL", "BS", "HT", "LF", "VT", "FF", "CR", "SO", "SI",
                 "DLE", "DC1", "DC2", "DC3", "DC4", "NAK", "SYN", "ETB", "CAN", "EM", "SUB", "ESC", "FS", "GS", "RS", "US")
"""ASCII 0x00-0x1F by name, in code order."""
CONTROL = {name: bytes([code]) for code, name in enumerate(CONTROL_NAMES)}
_NAME = re.compile(r"<(" + "|".join(CONTROL_NAMES) + r")>")
_ENDS_WITH_NAME = re.compile(_NAME.pattern + "$")


def literal(segment: str) -> bytes | None:
    """The bytes of one backtick segment, or None where it is prose (see the module docstring)."""
    if "…" in segment or not _ENDS_WITH_NAME.search(segment):
        return None
    out = bytearray()
    pos = 0
    for m in _NAME.finditer(segment):
        out += segment[pos:m.start()].encode("ascii") + CONTROL[m.group(1)]
        pos = m.end()
    return bytes(out + segment[pos:].encode("ascii"))


def cell_literals(cell: str) -> list[bytes]:
    """The byte literals of a table cell in order, each once."""
    found = (literal(s) for s in re.findall(r"`([^`]+)`", cell))
    return list(dict.fromkeys(b for b in found if b is not None))


def exchange_rows(doc: Path, id_pattern: str) -> dict[str, tuple[list[bytes], list[bytes]]]:
    """``{row id: (host → device literals, device → host literals)}`` of the rows of ``doc`` whose id
    matches ``id_pattern`` (columns 3 and 4 of the table)."""
    cells = {}
    for line in doc.read_text(encoding="utf-8").splitlines():
        parts = [p.strip() for p in line.strip().strip("|").split("|")] if line.startswith("|") else []
        if len(parts) >= 4 and re.fullmatch(id_pattern, parts[0]):
            cells[parts[0]] = (parts[2], parts[3])
    rows = {}
    for rid, (host, device) in cells.items():
        rows[rid] = tuple(_resolved(cells, cell, side) for side, cell in enumerate((host, device)))
    return rows


def _resolved(cells: dict[str, tuple[str, str]], cell: str, side: int) -> list[bytes]:
    got = cell_literals(cell)
    ref = re.match(r"as (\S+)\b", cell)
    if not got and ref and ref.group(1) in cells:
        return cell_literals(cells[ref.group(1)][side])
    return got
