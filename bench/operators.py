"""Who runs a run, and from where: the operator is a declared name, never the login of whoever
started the server.

* ``bench run --operator NAME``; without it, the login name (the person at the terminal).
* The web station's start form has an operator field: it is required (the server's login, often
  ``root``, says nothing about the person at the browser).
* A lab config may list its operators (``operators: [alice, bob]``): a name must then be one of
  them (exit 2 / HTTP 400 otherwise, located at the config's list); the start page offers them.

The run file records the name (root attribute ``operator``) and where it came from (``operator_origin``:
``cli alice@pts/3`` for a terminal, ``web 127.0.0.1`` for a browser: the socket's peer address).
Control actions from the web (answers, pause, resume, stop) carry the acting person's name, recorded
in that event beside its origin; they never replace the run's operator.

Bottom layer (imports only :mod:`bench.errors` and :mod:`bench.identity`).
"""

from __future__ import annotations

import getpass
import os
import sys
from dataclasses import dataclass
from typing import Sequence

from bench.errors import InputError, Location
from bench.identity import check_identity_text

CLI = "cli"
WEB = "web"


@dataclass(frozen=True)
class OperatorId:
    """The operator of a run (``name``) and where the name came from (``origin``)."""

    name: str
    origin: str


def login_name() -> str:
    """The login name, ``unknown`` when it cannot be determined."""
    try:
        return getpass.getuser()
    except (OSError, KeyError):
        return "unknown"


def terminal_name() -> str:
    """The controlling terminal of stdin without ``/dev/`` (``pts/3``), ``no tty`` when none."""
    try:
        return os.ttyname(sys.stdin.fileno()).removeprefix("/dev/") if sys.stdin and sys.stdin.isatty() else "no tty"
    except (OSError, ValueError, AttributeError):
        return "no tty"


def cli_origin() -> str:
    """``cli LOGIN@TTY``: where a name given on the command line came from."""
    return f"{CLI} {login_name()}@{terminal_name()}"


def web_origin(peer: str) -> str:
    """``web ADDRESS``: where a name typed in a browser came from (``peer``: the socket's peer)."""
    return f"{WEB} {peer or 'unknown'}"


def check_name(value: object, field: str, location: Location | None = None) -> str:
    """An operator name as given (printable, at most 64 characters, no surrounding spaces: the
    rules of every identity text, :func:`bench.identity.check_identity_text`), else a located
    :class:`InputError` naming ``field``."""
    return check_identity_text(value, location, field)


def resolve(name: str | None, allowed: Sequence[str] = (), *, origin: str, field: str = "--operator",
            allowed_at: Location | None = None, required: bool = False) -> OperatorId:
    """The operator of a run: ``name`` (stripped), else the login name unless ``required``. With a
    lab's list of operators (``allowed``, declared at ``allowed_at``) the name must be one of them
    (compared without regard to case; the list's spelling is recorded). :class:`InputError` naming
    ``field`` otherwise."""
    text = (name or "").strip()
    if not text:
        if required:
            raise InputError("who runs this? enter the operator's name" + (f" (one of {', '.join(allowed)})" if allowed else ""),
                             None, field)
        text = login_name()
        if allowed and text.lower() not in {a.lower() for a in allowed}:
            raise InputError(f"the login name {text!r} is not one of the lab's operators ({', '.join(allowed)}); "
                             f"name yourself with {field} NAME", allowed_at, field)
    check_name(text, field)
    if allowed:
        match = next((a for a in allowed if a.lower() == text.lower()), None)
        if match is None:
            where = f" ({allowed_at})" if allowed_at is not None else ""
            raise InputError(f"{text!r} is not one of the lab's operators{where}: {', '.join(allowed)}", None, field)
        text = match
    return OperatorId(text, origin)


def describe(operator: str, origin: str) -> str:
    """``alice (cli root@pts/3)``, or the name alone when the origin is unknown (older run files)."""
    return f"{operator} ({origin})" if origin else operator
