"""Text from files and requests made safe to print on a terminal: the one home of that rule.

A run file, a file name or a catalogue row is data another person (or a damaged disk) wrote. Printed
raw, its control characters act on the terminal: ``ESC [ 2 J`` clears the screen, ``ESC ] 52``
writes the clipboard, a carriage return or newline forges a line of bench's own output (``bench:
all verified``), a right-to-left override reverses what follows. :func:`printable` shows each such
character as a visible escape (``\\x1b``, ``\\n``, ``\\u202e``) instead, so the text is still all
there and can be read, and nothing in it reaches the terminal as an instruction.

Used by every one-line message (:meth:`bench.errors.InputError.one_line`, the CLI's error lines),
``bench inspect``, ``bench runs``, ``bench catalog rebuild`` and the replay's divergence report.
Imports nothing of bench: every layer may use it.
"""

from __future__ import annotations

import dataclasses
import re
from typing import Any

_UNSAFE = re.compile(
    "[\x00-\x1f\x7f-\x9f"  # C0 controls (ESC, BEL, CR, LF, TAB, BS …), DEL, C1 controls (CSI 0x9b, OSC 0x9d …)
    "\u061c\u200e\u200f\u202a-\u202e\u2066-\u2069"  # bidirectional marks, embeddings, overrides and isolates
    "\u2028\u2029"  # line and paragraph separators (a line break to some terminals and viewers)
    "\ud800-\udfff]"  # lone surrogates: bytes of a name that is not UTF-8 (surrogateescape)
)
_NAMED = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}


def _escape(m: re.Match[str]) -> str:
    c = m.group()
    if c in _NAMED:
        return _NAMED[c]
    n = ord(c)
    if 0xDC80 <= n <= 0xDCFF:  # a byte os.fsdecode could not decode: show the byte
        return f"\\x{n - 0xDC00:02x}"
    return f"\\x{n:02x}" if n < 0x100 else f"\\u{n:04x}"


def printable(text: object) -> str:
    """``str(text)`` with every control, bidirectional-override, line-separator and undecodable
    character replaced by a visible escape (``\\x1b``, ``\\n``, ``\\u202e``); one line, nothing a
    terminal acts on. Printable text (any script, emoji) is unchanged."""
    s = text if isinstance(text, str) else str(text)
    return _UNSAFE.sub(_escape, s)


def printable_data(obj: Any) -> Any:
    """``obj`` with :func:`printable` applied to every string in it: mappings (keys too), lists,
    tuples, sets and dataclass instances are rebuilt, everything else (numbers, arrays, dates) kept
    as it is. For a summary or rows read from files, before a terminal shows them."""
    if isinstance(obj, str):
        return printable(obj)
    if isinstance(obj, dict):
        return {printable_data(k): printable_data(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set, frozenset)):
        items = [printable_data(v) for v in obj]
        if isinstance(obj, tuple) and hasattr(obj, "_fields"):  # a named tuple
            return type(obj)(*items)
        return type(obj)(items)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        changes = {f.name: printable_data(getattr(obj, f.name)) for f in dataclasses.fields(obj) if f.init}
        return dataclasses.replace(obj, **changes)
    return obj
