"""Run-file events as a person reads them.

Some events carry JSON for programs (``bench inspect --json``, replay): an answer to a prompt, a
control action from the web station, the confirmation of an overdue calibration. ``bench inspect``,
``bench watch``, the web station's run page and the report show them as sentences instead:
``yes from alice (web 127.0.0.1) to mount_axis_z``, ``stop by alice (web 127.0.0.1)``. Any other
message is shown as it was recorded. Every text returned is :func:`bench.terminal_text.printable`:
a name or answer decoded from the JSON (``\u001b`` there is a real ESC once decoded) shows its
control characters as visible escapes and never acts on a terminal.

Light on purpose (json and :mod:`bench.terminal_text` only): every layer may use it.
"""

from __future__ import annotations

import json
from typing import Any

from bench.terminal_text import printable

OPERATOR = "operator"
CONTROL = "control"


def _json(message: str) -> dict[str, Any] | None:
    if not message.startswith("{"):
        return None
    try:
        d = json.loads(message)
    except (ValueError, RecursionError):
        return None
    return d if isinstance(d, dict) else None


SOURCE_WORDS = {"operator": "terminal", "file": "answers file", "dry-run": "dry-run: answered yes"}
"""How an answer's recorded ``source`` reads (``operator`` is a person at the terminal)."""


def _who(d: dict[str, Any]) -> str:
    person, where = str(d.get("operator") or ""), str(d.get("source") or d.get("origin") or "")
    where = SOURCE_WORDS.get(where, where)
    if person and where:
        return f"{person} ({where})"
    return person or where or "unknown"


def event_text(kind: str, source: str, message: str) -> str:
    """The event's message for people: answers, confirmations and control actions as sentences;
    everything else as recorded; control characters shown, never acted on (:func:`printable`)."""
    return printable(_sentence(kind, message))


def _sentence(kind: str, message: str) -> str:
    d = _json(message) if kind in (OPERATOR, CONTROL) else None
    if d is None:
        return message
    if kind == CONTROL:
        action = str(d.get("action", "action"))
        note = str(d.get("message") or "")
        return f"{action} by {_who(d)}" + (f": {note}" if note and note != f"{action} requested from the web station" else "")
    if "confirm_abort" in d:
        verdict = "run stopped" if d.get("confirmed") else "not stopped, asked again"
        return f"{d.get('confirm_abort')!r} from {_who(d)} after 'no' at {d.get('id', '?')}: {verdict}"
    if "answer" in d:
        answer = str(d.get("answer", ""))
        valid = d.get("valid", True)
        text = f"{answer!r} from {_who(d)} to {d.get('id', '?')}"
        if not valid:
            text += ": not an accepted answer, asked again"
        elif d.get("instrument"):
            text += f" (instrument {d['instrument']})"
        return text
    return message
