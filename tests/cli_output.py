"""What a failing ``bench`` command wrote on stderr, read the way a person reads it.

The analysis commands (``calibrate``, ``diagnose``, ``report``) print progress lines on stderr once
they have run for 2 s, also when stderr is not a terminal (docs/analysis.md, "Progress on stderr"): on a
loaded machine even a bad input that is refused a moment later may show one. A test that means
"one located error line" therefore ignores lines of exactly that documented format, written before
the error, and nothing else: any other extra line, or a progress line after the error, still fails.
"""

from __future__ import annotations

import re

PROGRESS_LINE = re.compile(r"(?:calibrate [a-z][a-z0-9-]*|diagnose|report): \S.* \(\d+ s\)")
"""One progress line as docs/analysis.md gives it: ``<command>: <what it is doing> (<elapsed> s)``."""


def is_progress(line: str) -> bool:
    """True for a line of the documented progress format (and nothing else)."""
    return PROGRESS_LINE.fullmatch(line) is not None


def one_error_line(res, code: int = 2) -> str:
    """The one message line of a ``bench`` run that must exit ``code`` (bad input: 2) with no
    traceback or numpy warning; progress lines before it are allowed, nothing else is."""
    assert res.returncode == code, (res.returncode, res.stdout[-2000:], res.stderr[-2000:])
    assert "Traceback" not in res.stderr and "RuntimeWarning" not in res.stderr, res.stderr
    lines = res.stderr.strip().splitlines()
    messages = [i for i, line in enumerate(lines) if not is_progress(line)]
    assert messages == [len(lines) - 1], res.stderr  # exactly one, and it is the last line
    return lines[-1]
