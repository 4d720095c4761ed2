"""Every value of a web request, typed strictly: one parser for JSON bodies and query strings.

A request is data from anyone who can reach the port. Before this parser, ``bool("no")`` and
``bool("false")`` were true, so ``"accept_overdue": "no"`` confirmed an overdue calibration and
``"dry_run": "false"`` started a dry-run; a NUL in a filter reached the database, and a query
``params=notjson`` was a server error. Here:

* a boolean is JSON ``true`` or ``false``, nothing else (not ``"false"``, ``0``, ``null``);
* a number is a JSON number (not a boolean), finite, within its field's bounds; an integer field
  takes integers only;
* a string is a JSON string (a query value is one), at most its field's length, without control
  characters (C0, DEL, C1: NUL, escape sequences, line breaks) nor lone surrogates;
* a body is one JSON object of at most :data:`MAX_BODY_BYTES`, UTF-8, whose fields are all known:
  an unknown field is refused (a misspelt ``accept_overdue`` must not silently mean "no");
* an operator name (the agreed ``operator`` field) is at most 64 characters, without control
  characters, and follows the one rule of every operator name (:func:`bench.operators.check_name`:
  printable, as ``bench run --operator`` and the lab config's ``operators:`` take it); a blank one
  is "not given" (whether a name is required, and whether it is one of the lab's, is
  :func:`bench.operators.resolve`'s to say).

Each refusal is an :class:`~bench.errors.InputError` naming the field: HTTP 400 with that line.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from typing import Any, Mapping

from bench.errors import InputError, finite_number

MAX_BODY_BYTES = 64 * 1024
"""Largest request body accepted (bytes); a larger one is refused before it is read (HTTP 413)."""
MAX_TEXT_CHARS = 200
"""Longest string of a field that does not say otherwise (characters)."""
MAX_PARAMS = 100
"""Most parameter overrides one request may carry."""
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\ud800-\udfff\u2028\u2029]")


class BodyTooLarge(Exception):
    """The request body is larger than :data:`MAX_BODY_BYTES` (HTTP 413)."""


@dataclass(frozen=True)
class Field:
    """One field of a body or query: ``kind`` ``bool``, ``number``, ``int``, ``text``, ``name``
    (an operator), ``params`` (a mapping of parameter names to value texts or numbers); ``default``
    when absent (``required`` otherwise); bounds ``lo``/``hi`` (numbers) and ``max_chars`` (texts)."""

    kind: str
    default: Any = None
    required: bool = False
    lo: float = -math.inf
    hi: float = math.inf
    max_chars: int = MAX_TEXT_CHARS
    nullable: bool = False


def text(value: Any, field: str, max_chars: int = MAX_TEXT_CHARS) -> str:
    """``value`` as a string of at most ``max_chars`` characters without control characters."""
    if not isinstance(value, str):
        raise InputError(f"expected a string, got {_shown(value)}", None, field)
    if len(value) > max_chars:
        raise InputError(f"expected at most {max_chars} characters, got {len(value)}", None, field)
    m = _CONTROL.search(value)
    if m:
        raise InputError(f"control character U+{ord(m.group()):04X} at position {m.start() + 1}: not allowed", None, field)
    return value


def boolean(value: Any, field: str) -> bool:
    """``value`` when it is JSON ``true`` or ``false``; anything else is refused."""
    if value is True or value is False:
        return value
    raise InputError(f"expected true or false, got {_shown(value)}", None, field)


def number(value: Any, field: str, lo: float = -math.inf, hi: float = math.inf, integer: bool = False) -> float | int:
    """``value`` when it is a finite JSON number (an integer for ``integer``) in ``lo`` .. ``hi``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"expected {'an integer' if integer else 'a number'}, got {_shown(value)}", None, field)
    if integer and not isinstance(value, int):
        raise InputError(f"expected an integer, got {_shown(value)}", None, field)
    if not math.isfinite(value):
        raise InputError(f"expected a finite number, got {_shown(value)}", None, field)
    if not lo <= value <= hi:
        raise InputError(f"expected {lo:g} .. {hi:g}, got {value:g}", None, field)
    return value


def operator_name(value: Any, field: str = "operator") -> str:
    """An operator's name, stripped (:func:`bench.operators.check_name`), ``""`` when blank."""
    from bench.identity import MAX_IDENTITY_CHARS
    from bench.operators import check_name

    name = text(value, field, MAX_IDENTITY_CHARS).strip()
    return check_name(name, field) if name else ""


def params(value: Any, field: str = "params") -> dict[str, str]:
    """Parameter overrides: a mapping of names (as ``-p NAME=VALUE``) to value texts or numbers;
    the values as texts (a blank one dropped)."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise InputError("expected a mapping of parameter names to values", None, field)
    if len(value) > MAX_PARAMS:
        raise InputError(f"expected at most {MAX_PARAMS} parameters, got {len(value)}", None, field)
    out: dict[str, str] = {}
    for k, v in value.items():
        name = text(k, f"{field} name", 64).strip()
        if not name:
            raise InputError("a parameter name is empty", None, field)
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            v = str(number(v, f"{field}.{name}"))
        v = text(v, f"{field}.{name}").strip()
        if v:
            out[name] = v
    return out


def _value(value: Any, spec: Field, name: str) -> Any:
    if value is None and spec.nullable:
        return spec.default
    if spec.kind == "bool":
        return boolean(value, name)
    if spec.kind in ("number", "int"):
        return number(value, name, spec.lo, spec.hi, integer=spec.kind == "int")
    if spec.kind == "text":
        return text(value, name, spec.max_chars)
    if spec.kind == "name":
        return operator_name(value, name)
    if spec.kind == "params":
        return params(value, name)
    raise ValueError(f"unknown field kind {spec.kind!r}")


def parse_body(raw: bytes, fields: Mapping[str, Field]) -> dict[str, Any]:
    """The JSON object in ``raw`` with every field typed by ``fields`` (absent ones at their
    default); :class:`InputError` for anything else. An empty body is an empty object."""
    if len(raw) > MAX_BODY_BYTES:
        raise BodyTooLarge()
    try:
        body = json.loads(raw.decode("utf-8") or "{}", parse_constant=_no_constant)
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        why = str(exc) if isinstance(exc, ValueError) and str(exc).endswith("is not JSON") else "not UTF-8 JSON"
        raise InputError(f"expected a JSON object: {why}") from None
    if not isinstance(body, dict):
        raise InputError("expected a JSON object")
    unknown = sorted(set(body) - set(fields))
    if unknown:
        raise InputError(f"unknown field(s) {', '.join(map(repr, unknown))[:200]}; expected {', '.join(fields)}")
    out = {}
    for name, spec in fields.items():
        if name not in body:
            if spec.required:
                raise InputError("required", None, name)
            out[name] = spec.default
        else:
            out[name] = _value(body[name], spec, name)
    return out


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not JSON")


def query(params_: Mapping[str, str], fields: Mapping[str, Field]) -> dict[str, Any]:
    """The query parameters named in ``fields``, typed (a value is text; ``number``/``int`` fields
    parse it; an empty value or ``null`` is the default). Other parameters are ignored (a browser
    adds its own)."""
    out = {}
    for name, spec in fields.items():
        raw = params_.get(name)
        if raw is None or raw in ("", "null", "undefined"):
            if spec.required:
                raise InputError("required", None, name)
            out[name] = spec.default
            continue
        value = text(raw, name, spec.max_chars if spec.kind in ("text", "json") else 64)
        if spec.kind == "int":
            try:
                parsed: Any = int(value)
            except ValueError:
                raise InputError(f"expected an integer, got {value!r}", None, name) from None
            out[name] = number(parsed, name, spec.lo, spec.hi, integer=True)
        elif spec.kind == "number":
            out[name] = number(finite_number(value, None, name), name, spec.lo, spec.hi)
        elif spec.kind == "json":
            try:
                out[name] = json.loads(value, parse_constant=_no_constant)
            except (ValueError, RecursionError):
                raise InputError(f"expected JSON, got {value[:40]!r}", None, name) from None
        else:
            out[name] = value
    return out


def _shown(value: Any) -> str:
    """A value as a message quotes it: JSON, cut to 40 characters."""
    try:
        s = json.dumps(value)
    except (TypeError, ValueError):
        s = type(value).__name__
    return s if len(s) <= 40 else s[:37] + "..."
