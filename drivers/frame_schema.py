"""Validation of a frame description from plain data (a loaded YAML document), every problem
with its key path; and the descriptions that ship with bench (``drivers/frames/``).

:func:`description_from_mapping` builds a :class:`drivers.board_frames.FrameDescription`;
``bench/board_frames.py`` turns the key paths of :class:`FrameDescriptionError` into file:line.
The format: docs/frame-descriptions.md.
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from drivers.board_frames import (CHECKS, HEADER_ITEMS, INTEGER_ONLY, NAK_REASONS, NAME_RE, OPS, QUANTITIES, RATIO_RE,
                                  REQUIRED_OPS, REQUIREMENTS, SCHEMA, STANDARD_FIELDS, STATUS_BITS, TYPES, Command, Field,
                                  FrameDescription, FrameDescriptionError, Nak, PayloadItem, Reply, path_text)

BUILTIN_DIR = Path(__file__).with_name("frames")
"""Where the descriptions that ship with bench live (``acs_board.yaml``: ours)."""


# ---- building from plain data ---------------------------------------------------------------------
class _Problems:
    def __init__(self) -> None:
        self.items: list[tuple[tuple, str]] = []

    def add(self, path: tuple, message: str) -> None:
        self.items.append((path, message))


def _get(m: dict, key: str, path: tuple, probs: _Problems, kinds, *, required: bool = False, default: Any = None) -> Any:
    if key not in m:
        if required:
            probs.add(path + (key,), "missing")
        return default
    v = m[key]
    if not isinstance(v, kinds) or isinstance(v, bool) and bool not in (kinds if isinstance(kinds, tuple) else (kinds,)):
        want = " or ".join(k.__name__ for k in (kinds if isinstance(kinds, tuple) else (kinds,)))
        probs.add(path + (key,), f"expected {want}, got {v!r}"[:160])
        return default
    return v


def _unknown(m: dict, known: Iterable[str], path: tuple, probs: _Problems) -> None:
    known = set(known)
    for k in m:
        if k not in known:
            probs.add(path + (k,), f"unknown key (known: {', '.join(sorted(known))})")


def _byte(v: Any, path: tuple, probs: _Problems, what: str = "a byte 0..255") -> int | None:
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 255:
        probs.add(path, f"expected {what}, got {v!r}")
        return None
    return v


def _number(v: Any, path: tuple, probs: _Problems, *, nonzero: bool = False) -> float | None:
    """A finite number, or a ratio ``a/b`` of two numbers (never evaluated as code)."""
    if isinstance(v, str):
        m = RATIO_RE.fullmatch(v)
        if not m or float(m.group(2)) == 0:
            probs.add(path, f"expected a number or a ratio such as 250/32768, got {v!r}")
            return None
        v = float(m.group(1)) / float(m.group(2))
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or (nonzero and v == 0):
        probs.add(path, f"expected a finite{' non-zero' if nonzero else ''} number, got {v!r}")
        return None
    return float(v)


def _order(v: Any, path: tuple, probs: _Problems) -> str | None:
    if v in ("little", "big"):
        return "<" if v == "little" else ">"
    probs.add(path, f"expected little or big, got {v!r}")
    return None


def description_from_mapping(data: Any, source: str = "", text: str = "") -> FrameDescription:
    """A :class:`FrameDescription` from plain data (a loaded YAML document); raises
    :class:`FrameDescriptionError` listing every problem with its key path."""
    probs = _Problems()
    if not isinstance(data, dict):
        raise FrameDescriptionError([((), "expected a mapping (a frame description document)")], source)
    _unknown(data, ("schema", "name", "doc", "byte_order", "sync", "header", "version", "check", "max_payload", "data",
                    "commands", "nak", "status_bits", "power_up", "max_odr_hz"), (), probs)
    if data.get("schema") != SCHEMA:
        probs.add(("schema",), f"expected {SCHEMA!r}, got {data.get('schema')!r}")
    name = _get(data, "name", (), probs, str, required=True, default="") or ""
    doc = _get(data, "doc", (), probs, str, default="") or ""
    order = _order(data.get("byte_order", "little"), ("byte_order",), probs) or "<"
    sync_v = _get(data, "sync", (), probs, list, required=True, default=[])
    sync = [_byte(b, ("sync", i), probs) for i, b in enumerate(sync_v)]
    if sync_v is not None and not 1 <= len(sync_v) <= 4:
        probs.add(("sync",), f"expected 1 to 4 sync bytes, got {len(sync_v)}")
    header_v = _get(data, "header", (), probs, list, required=True, default=[])
    header = []
    for i, h in enumerate(header_v):
        if h not in HEADER_ITEMS:
            probs.add(("header", i), f"expected one of {', '.join(HEADER_ITEMS)}, got {h!r}")
        elif h in header or (h.startswith("length") and any(x.startswith("length") for x in header)):
            probs.add(("header", i), f"{h!r} given twice")
        else:
            header.append(h)
    if header_v and "type" not in header:
        probs.add(("header",), "the header needs the frame type (item 'type')")
    if header_v and not any(h.startswith("length") for h in header):
        probs.add(("header",), "the header needs the payload length (item 'length' or 'length16')")
    version = None
    if "version" in header:
        version = _byte(data.get("version"), ("version",), probs, "the version byte every frame carries (0..255)")
    elif "version" in data:
        probs.add(("version",), "a version byte needs 'version' in the header")
    header_len = len(sync_v or []) + sum(HEADER_ITEMS[h] for h in header)

    check_m = _get(data, "check", (), probs, dict, required=True, default={}) or {}
    _unknown(check_m, ("algorithm", "from", "byte_order"), ("check",), probs)
    algo = check_m.get("algorithm")
    if algo not in CHECKS:
        probs.add(("check", "algorithm"), f"expected one of {', '.join(CHECKS)}, got {algo!r}")
        algo = "none"
    check_from = check_m.get("from", len(sync_v or []))
    if isinstance(check_from, bool) or not isinstance(check_from, int) or not 0 <= check_from <= header_len:
        probs.add(("check", "from"), f"expected the byte offset where the check starts, 0..{header_len} (the header's end), got {check_from!r}")
        check_from = 0
    check_order = _order(check_m.get("byte_order", "big"), ("check", "byte_order"), probs) or ">"
    length_limit = 0xFFFF if "length16" in header else 0xFF
    max_payload = _get(data, "max_payload", (), probs, int, default=min(128, length_limit))
    if max_payload is not None and not 0 <= max_payload <= length_limit:
        probs.add(("max_payload",), f"expected 0..{length_limit} bytes")
        max_payload = length_limit

    data_m = _get(data, "data", (), probs, dict, required=True, default={}) or {}
    _unknown(data_m, ("id", "fields"), ("data",), probs)
    data_id = _byte(data_m.get("id"), ("data", "id"), probs, "the data frame's type id 0..255") if "id" in data_m else None
    if "id" not in data_m:
        probs.add(("data", "id"), "missing")
    fields = _fields(data_m.get("fields"), header_len, order, probs)
    payload_len = sum(f.size for f in fields)
    if payload_len > length_limit:
        probs.add(("data", "fields"), f"the data payload is {payload_len} bytes; the length item holds at most {length_limit}")
    names = {f.name for f in fields}
    if fields and "board_time" not in names:
        probs.add(("data", "fields"), "a field named board_time (the board's clock) is needed: it gives every row its run time")

    status_bits = {}
    sb = _get(data, "status_bits", (), probs, dict, default={}) or {}
    for k, v in sb.items():
        if k not in STATUS_BITS:
            probs.add(("status_bits", k), f"expected one of {', '.join(STATUS_BITS)}")
        elif isinstance(v, bool) or not isinstance(v, int) or v < 0:
            probs.add(("status_bits", k), f"expected a bit mask such as 0x04, got {v!r}")
        else:
            status_bits[k] = v
    status_f = next((f for f in fields if f.name == "status"), None)
    if status_bits and status_f is None:
        probs.add(("status_bits",), "status bits need a field named status")
    elif status_f is not None:
        for k, v in status_bits.items():
            if v >= status_f.modulus:
                probs.add(("status_bits", k), f"0x{v:X} does not fit the {status_f.type} status field")

    commands = _commands(data.get("commands"), probs)
    nak = _nak(data["nak"], probs) if "nak" in data else None
    ids = [(("data", "id"), data_id)] + [(("commands", c.op, "id"), c.id) for c in commands.values()] + \
          ([(("nak", "id"), nak.id)] if nak else [])
    seen: dict[int, tuple] = {}
    for path, i in ids:
        if i is None:
            continue
        if i in seen:
            probs.add(path, f"frame id 0x{i:02X} is also {path_text(seen[i])}")
        seen[i] = path
    reply_ids = {c.reply.id: c.op for c in commands.values()}
    for op, c in commands.items():
        if c.reply.id in seen and c.reply.id != c.id:
            probs.add(("commands", op, "reply", "id"), f"reply id 0x{c.reply.id:02X} is also {path_text(seen[c.reply.id])}")
    if len(reply_ids) != len(commands):
        probs.add(("commands",), "two commands share a reply id: their answers could not be told apart")

    pu = _get(data, "power_up", (), probs, dict, default={}) or {}
    _unknown(pu, ("odr_hz", "moving_avg_n", "sensors_on", "streaming"), ("power_up",), probs)
    power_up = {"odr_hz": 100, "moving_avg_n": 1, "sensors_on": 0 if "sensor_power" in commands else 1, "streaming": 0}
    for k in ("odr_hz", "moving_avg_n"):
        if k in pu:
            v = pu[k]
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 65535:
                probs.add(("power_up", k), f"expected a whole number 1..65535, got {v!r}")
            else:
                power_up[k] = v
    for k in ("sensors_on", "streaming"):
        if k in pu:
            if not isinstance(pu[k], bool):
                probs.add(("power_up", k), f"expected true or false, got {pu[k]!r}")
            else:
                power_up[k] = int(pu[k])
    max_odr = _get(data, "max_odr_hz", (), probs, int, default=1000)
    if max_odr is not None and not 1 <= max_odr <= 100_000:
        probs.add(("max_odr_hz",), "expected 1..100000 Hz")
    if probs.items:
        raise FrameDescriptionError(probs.items, source)
    return FrameDescription(name, order, bytes(sync), tuple(header), version, CHECKS[algo], check_from, check_order,
                            max_payload, data_id, tuple(fields), commands, nak, status_bits, power_up, max_odr, doc, source, text)


def _fields(value: Any, header_len: int, order: str, probs: _Problems) -> list[Field]:
    path = ("data", "fields")
    if not isinstance(value, list) or not value:
        probs.add(path, "expected a non-empty list of fields")
        return []
    out: list[Field] = []
    at = header_len
    for i, m in enumerate(value):
        p = path + (i,)
        if not isinstance(m, dict):
            probs.add(p, "expected a mapping such as {name: gyro, type: i2, count: 3, scale: 250/32768, units: deg/s}")
            continue
        _unknown(m, ("name", "type", "count", "at", "byte_order", "scale", "offset", "units", "quantity", "value", "sim", "doc"), p, probs)
        name = m.get("name")
        if not isinstance(name, str) or not NAME_RE.fullmatch(name):
            probs.add(p + ("name",), f"expected a name of lower-case letters, digits and '_' (at most 32), got {name!r}")
            name = f"field{i}"
        elif any(f.name == name for f in out):
            probs.add(p + ("name",), f"field {name!r} given twice")
        ftype = m.get("type")
        if ftype not in TYPES:
            probs.add(p + ("type",), f"expected one of {', '.join(TYPES)}, got {ftype!r}")
            ftype = "u1"
            at = None  # the offsets after it are unknown: not checked
        count = m.get("count", 1)
        if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= 16:
            probs.add(p + ("count",), f"expected 1..16 values, got {count!r}")
            count = 1
        if "at" in m and at is not None and m["at"] != at:
            probs.add(p + ("at",), f"the fields before it end at byte {at}, not {m['at']!r} (a gap needs a field of its own)")
        forder = _order(m["byte_order"], p + ("byte_order",), probs) if "byte_order" in m else order
        scale = _number(m.get("scale", 1), p + ("scale",), probs, nonzero=True) or 1.0
        offset = _number(m.get("offset", 0), p + ("offset",), probs) or 0.0
        units = m.get("units", "1")
        doc = m.get("doc", "") if isinstance(m.get("doc", ""), str) else ""
        if not isinstance(units, str) or not units.strip():
            probs.add(p + ("units",), f"expected units such as deg/s, V or 1, got {units!r}")
            units = "1"
        quantity = m.get("quantity")
        std = STANDARD_FIELDS.get(name)
        integer = TYPES[ftype][2]
        value_c = m.get("value")
        if value_c is not None:
            if not integer or isinstance(value_c, bool) or not isinstance(value_c, int) or count != 1:
                probs.add(p + ("value",), "a constant needs a single integer field (an item id, a size byte)")
                value_c = None
            elif not np.iinfo(np.dtype(TYPES[ftype][0])).min <= value_c <= np.iinfo(np.dtype(TYPES[ftype][0])).max:
                probs.add(p + ("value",), f"{value_c} does not fit a {ftype}")
                value_c = None
            elif std is not None:
                probs.add(p + ("value",), f"{name} is read by bench: it cannot be a constant")
        if std is not None:
            if quantity is not None and quantity != std[0]:
                probs.add(p + ("quantity",), f"{name} is always {std[0] or 'a plain count'}")
            quantity = std[0]
            lo, hi = std[1]
            if not lo <= count <= hi:
                probs.add(p + ("count",), f"{name} has {lo if lo == hi else f'{lo} to {hi}'} value(s) per frame, got {count}")
            if name in INTEGER_ONLY and (not integer or ftype.startswith("i")):
                probs.add(p + ("type",), f"{name} must be an unsigned integer (u1, u2 or u4), got {ftype}")
            if name in ("counter", "status") and (m.get("scale", 1) != 1 or m.get("offset", 0) != 0):
                probs.add(p + ("scale",), f"{name} is a plain count: no scale or offset")
        elif quantity is not None and quantity not in QUANTITIES:
            probs.add(p + ("quantity",), f"expected one of {', '.join(q for q in QUANTITIES if q != 'time')}, got {quantity!r}")
            quantity = None
        if quantity is not None:
            accepted = QUANTITIES[quantity].accepted
            if "units" not in m:
                probs.add(p + ("units",), f"{name} needs units, one of {', '.join(accepted)}")
            elif units not in accepted:
                probs.add(p + ("units",), f"{quantity.replace('_', ' ')} in {units!r}: expected one of {', '.join(accepted)}")
            else:
                factor, shift = accepted[units]
                scale, offset, units = scale * factor, offset * factor + shift, QUANTITIES[quantity].record_units
        sim = _number(m.get("sim", 0), p + ("sim",), probs) or 0.0
        out.append(Field(name, ftype, count, at or 0, forder, scale, offset, units, quantity, value_c, sim, doc))
        at = None if at is None else at + TYPES[ftype][1] * count
    return out


def _payload(items: Any, path: tuple, allowed: tuple[str, ...], probs: _Problems, *, formats: bool = False) -> tuple[PayloadItem, ...]:
    if items is None:
        return ()
    if not isinstance(items, list):
        probs.add(path, "expected a list of {name: ..., type: ...} or {value: ..., type: ...}")
        return ()
    out = []
    for i, m in enumerate(items):
        p = path + (i,)
        if not isinstance(m, dict):
            probs.add(p, "expected {name: ..., type: ...} or {value: ..., type: ...}")
            continue
        _unknown(m, ("name", "value", "type") + (("format",) if formats else ()), p, probs)
        t = m.get("type")
        if t not in TYPES or not TYPES[t][2]:
            probs.add(p + ("type",), f"expected an integer type ({', '.join(k for k, v in TYPES.items() if v[2])}), got {t!r}")
            t = "u1"
        name, value = m.get("name"), m.get("value")
        if (name is None) == (value is None):
            probs.add(p, "give either name (a value the command carries) or value (a constant)")
        elif name is not None and name not in allowed:
            probs.add(p + ("name",), f"expected one of {', '.join(allowed) or 'nothing (this frame carries no values)'}, got {name!r}")
        elif value is not None and (isinstance(value, bool) or not isinstance(value, int)):
            probs.add(p + ("value",), f"expected an integer constant, got {value!r}")
        fmt = m.get("format", "dec")
        if fmt not in ("dec", "hex"):
            probs.add(p + ("format",), f"expected dec or hex, got {fmt!r}")
        out.append(PayloadItem(t, name, value, fmt))
    return tuple(out)


def _commands(value: Any, probs: _Problems) -> dict[str, Command]:
    if not isinstance(value, dict):
        probs.add(("commands",), f"expected a mapping of commands ({', '.join(OPS)}) to their frames")
        return {}
    out = {}
    for op, m in value.items():
        p = ("commands", op)
        if op not in OPS:
            probs.add(p, f"unknown command (known: {', '.join(OPS)})")
            continue
        if not isinstance(m, dict):
            probs.add(p, "expected {id: 0x10, reply: {id: 0x90}}")
            continue
        _unknown(m, ("id", "payload", "reply", "requires"), p, probs)
        sends, answers = OPS[op]
        cid = _byte(m.get("id"), p + ("id",), probs, "the command's frame id 0..255")
        payload = _payload(m.get("payload"), p + ("payload",), sends, probs)
        missing = [s for s in sends if s not in {it.name for it in payload}]
        if missing:
            probs.add(p + ("payload",), f"{op} must carry {', '.join(missing)}")
        r = m.get("reply")
        if not isinstance(r, dict):
            probs.add(p + ("reply",), "expected {id: ...} (the board's acknowledgement)")
            continue
        _unknown(r, ("id", "payload", "text", "separator", "echo"), p + ("reply",), probs)
        rid = _byte(r.get("id"), p + ("reply", "id"), probs, "the reply's frame id 0..255")
        rpayload = _payload(r.get("payload"), p + ("reply", "payload"), answers, probs, formats=True)
        text = r.get("text", [])
        if not isinstance(text, list) or not all(t in answers for t in text):
            probs.add(p + ("reply", "text"), f"expected a list of {', '.join(answers) or 'nothing'}")
            text = []
        if text and rpayload:
            probs.add(p + ("reply",), "a reply is either text or payload, not both")
        sep = r.get("separator", ";")
        if not isinstance(sep, str) or len(sep) != 1:
            probs.add(p + ("reply", "separator"), "expected one character")
            sep = ";"
        echo = r.get("echo", False)
        if not isinstance(echo, bool):
            probs.add(p + ("reply", "echo"), "expected true or false")
            echo = False
        got = {it.name for it in rpayload if it.name} | set(text)
        need = {"run_bit": ("failed_mask",), "get_config": ("odr_hz", "moving_avg_n", "streaming")}.get(op, ())
        if op == "identify" and not got & {"serial", "model"}:
            probs.add(p + ("reply",), "identify's reply must carry the serial or the model (text or payload)")
        for k in need:
            if k not in got:
                probs.add(p + ("reply", "payload"), f"{op}'s reply must carry {k}")
        req = m.get("requires", [])
        if not isinstance(req, list) or not all(x in REQUIREMENTS for x in req):
            probs.add(p + ("requires",), f"expected a list of {', '.join(REQUIREMENTS)}")
            req = []
        if cid is not None and rid is not None:
            out[op] = Command(op, cid, payload, Reply(rid, rpayload, tuple(text), sep, echo), tuple(req))
    for op in REQUIRED_OPS:
        if op not in value:
            probs.add(("commands", op), "missing: the runner identifies the board and starts and stops its stream")
    return out


def _nak(m: Any, probs: _Problems) -> Nak | None:
    p = ("nak",)
    if not isinstance(m, dict):
        probs.add(p, "expected {id: 0x7F, payload: [...], codes: {...}}")
        return None
    _unknown(m, ("id", "payload", "codes"), p, probs)
    nid = _byte(m.get("id"), p + ("id",), probs)
    payload = _payload(m.get("payload"), p + ("payload",), ("command", "code"), probs)
    if "code" not in {it.name for it in payload}:
        probs.add(p + ("payload",), "a NAK must carry its code")
    codes_m = m.get("codes", {})
    codes: dict[str, int | None] = {}
    if not isinstance(codes_m, dict):
        probs.add(p + ("codes",), f"expected a mapping of {', '.join(NAK_REASONS)} to codes (null: no answer)")
        codes_m = {}
    for k, v in codes_m.items():
        if k not in NAK_REASONS:
            probs.add(p + ("codes", k), f"expected one of {', '.join(NAK_REASONS)}")
        elif v is not None and _byte(v, p + ("codes", k), probs, "a code 0..255 or null (no answer)") is None:
            pass
        else:
            codes[k] = v
    names: dict[int, str] = {}
    for k, v in codes.items():
        if v is not None:
            names.setdefault(v, k.upper())
    return Nak(nid, payload, codes, names) if nid is not None else None



# ---- the descriptions that ship with bench ------------------------------------------------------------
def builtin_path(name: str) -> Path:
    return BUILTIN_DIR / f"{name}.yaml"


@lru_cache(maxsize=8)
def builtin_description(name: str = "acs_board") -> FrameDescription:
    """A description shipped in ``drivers/frames/`` (``acs_board``: ours), parsed once."""
    import yaml

    path = builtin_path(name)
    text = path.read_text(encoding="utf-8")
    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml when there: a few ms less at every config load
    return description_from_mapping(yaml.load(text, Loader=loader), str(path), text)

