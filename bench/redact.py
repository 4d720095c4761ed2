"""Credentials kept out of everything bench stores or shows: the one redaction rule.

A lab config may name its catalogue as ``postgresql://bench:PASSWORD@labdb/bench``; that text is kept
in every run file (``/config/text``), a run file is copied, attached to reports and downloaded from
the web station. :func:`redact` replaces each credential in a text by ``***`` and keeps the rest,
so the text still says which server and which user:

* the password of a URL (``scheme://user:PASSWORD@host``), also one holding an unencoded ``@`` or
  ``:`` (everything up to the URL's last ``@`` is the user part);
* the value of a key that names a secret (``password``, ``passwd``, ``secret``, ``token``, ``api_key``,
  ``access_key``, ``private_key``, and names ending in them such as ``sslpassword`` or
  ``BENCH_WEB_TOKEN``) written ``key: value``, ``key=value`` (a URL query, a libpq connection
  string) or ``"key": "value"`` (JSON);
* a bearer token (``Bearer VALUE``).

The recorder applies it to every text it stores (root attributes, the procedure and config texts,
instrument identities, event messages and sources, the JSON data of events other than instrument
traffic, the abort reason); the catalogue applies it to every message that quotes a URL; the web
station refuses to serve a run file in which :func:`find_secrets` still finds one (a file written
before this rule). Instrument traffic (``command``/``reply`` data) is stored byte for byte: it is
what a replay answers, and bench's drivers send no credentials. Imports nothing of bench.
"""

from __future__ import annotations

import json
import re
from typing import Any

MASK = "***"
"""What a credential is replaced by."""

_HINTS = ("://", "pass", "secret", "token", "key", "bearer")
"""A text without any of these (in lower case) holds no credential: most texts, such as the messages
of instrument traffic, leave :func:`redact` after this test (0.3 µs; a case-blind regex took 6 µs)."""


def _may_hold(text: str) -> bool:
    low = text.lower()
    return any(h in low for h in _HINTS)

_URL_PASSWORD = re.compile(
    r"(?P<head>[A-Za-z][A-Za-z0-9+.\-]*://[^\s:/@'\"<>]*:)"  # scheme://user:
    r"(?P<secret>[^\s'\"<>]*)"  # the password, up to the URL's last '@' (it may hold '@', ':', '/')
    r"(?=@[^\s@'\"<>]*(?:[\s'\"<>]|$))"  # '@' then the host and the rest, without another '@'
)
_SECRET_KEY = r"[A-Za-z0-9_.\-]*(?:password|passwd|secret|token|api[_\-]?key|access[_\-]?key|private[_\-]?key)"
_KEY_VALUE = re.compile(
    rf"(?P<head>(?<![A-Za-z0-9_.\-]){_SECRET_KEY}[\"']?[ \t]*[:=][ \t]*)"
    r"(?P<secret>\"(?:[^\"\\\n]|\\.)*\"|'[^'\n]*'|[^\s,;&'\"}\]]+)",
    re.IGNORECASE,
)
_BEARER = re.compile(r"(?P<head>\bBearer[ \t]+)(?P<secret>[A-Za-z0-9\-._~+/]+=*)", re.IGNORECASE)
_SECRET_NAME = re.compile(rf"{_SECRET_KEY}", re.IGNORECASE)
_KINDS = ((_URL_PASSWORD, "a URL password"), (_KEY_VALUE, "a secret value"), (_BEARER, "a bearer token"))


def _mask(m: re.Match[str]) -> str:
    secret = m.group("secret")
    if secret == MASK or secret in ('""', "''", f'"{MASK}"', f"'{MASK}'"):
        return m.group(0)
    quote = secret[0] if secret[:1] in ("'", '"') and len(secret) > 1 and secret[-1] == secret[0] else ""
    return f"{m.group('head')}{quote}{MASK}{quote}"


_SEEN: dict[str, str] = {}
"""Short texts already redacted -> the result: the recorder stores tens of thousands of instrument
messages a second of virtual time, nearly all repeats (bounded by :data:`SEEN_MAX`)."""
SEEN_MAX = 4096
SEEN_CHARS = 256


def redact(text: str) -> str:
    """``text`` with every credential (see the module docstring) replaced by ``***``; a text without
    one is returned unchanged (the same object)."""
    if not text:
        return text
    short = len(text) <= SEEN_CHARS
    if short:
        hit = _SEEN.get(text)
        if hit is not None:
            return hit
    out = text
    if _may_hold(text):
        for pattern, _what in _KINDS:
            out = pattern.sub(_mask, out)
    if short:
        if len(_SEEN) >= SEEN_MAX:
            _SEEN.clear()
        _SEEN[text] = out
    return out


def find_secrets(text: str) -> list[str]:
    """Where ``text`` holds a credential, without quoting it: ``["a URL password on line 7", …]``
    (empty when :func:`redact` would change nothing)."""
    if not text or not _may_hold(text):
        return []
    found = []
    for pattern, what in _KINDS:
        for m in pattern.finditer(text):
            if _mask(m) != m.group(0):
                found.append(f"{what} on line {text.count(chr(10), 0, m.start()) + 1}")
    return found


def redact_data(obj: Any) -> Any:
    """``obj`` (parsed JSON: dicts, lists, strings, numbers) with :func:`redact` applied to every
    string, and the value of every key that names a secret replaced by ``***``."""
    if isinstance(obj, str):
        return redact(obj)
    if isinstance(obj, dict):
        return {k: (MASK if isinstance(k, str) and _SECRET_NAME.fullmatch(k) and v not in (None, "") else redact_data(v))
                for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [redact_data(v) for v in obj]
    return obj


def redact_bytes(data: bytes) -> bytes:
    """Bytes of a stored text or JSON document with their credentials redacted: JSON is parsed and
    written again only when something was redacted (so it stays valid JSON); other UTF-8 text goes
    through :func:`redact`; anything else (binary) is returned unchanged."""
    if not data or not _may_hold(data.decode("latin-1")):
        return data
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        return data
    try:
        doc = json.loads(text)
    except ValueError:
        out = redact(text)
        return data if out is text else out.encode("utf-8")
    clean = redact_data(doc)
    return data if clean == doc else json.dumps(clean).encode("utf-8")
