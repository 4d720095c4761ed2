"""A sensor board's frames as data: the frame description, its validation and its codec.

A lab describes its board's wire format in YAML (``docs/frame-descriptions.md``): sync bytes, the
header (frame type, payload length, version byte), the check (CRC or checksum) and its byte
order, the data frame's fields (type, count, byte order, scale, offset, units), the commands the
board understands with their frame ids and payloads, its NAK and its status bits. Ours is one
such description (``drivers/frames/acs_board.yaml``, the page ``docs/acs-board-protocol.md``).

This module holds the data model (:class:`FrameDescription`, built from plain data by
:func:`description_from_mapping`, which reports every problem with its key path), the numpy
structured dtype of the data frame built from it, and the codec: :func:`encode_frame`,
:meth:`FrameDescription.encode_data` (``n`` data frames at once), :meth:`FrameDescription.to_raw`
(physical values to the wire's counts, saturating) and :class:`FrameDecoder` (a byte stream in any
chunking to decoded batches, vectorised). The drivers layer imports nothing from bench:
``bench/board_frames.py`` loads a description file with located errors (file:line:column).

Physical value of a field = (raw × scale + offset) in the field's ``units``, converted to the
record units of its quantity (deg/s, g, uT, degC, s) when it has one (:data:`QUANTITIES`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from drivers.crc import crc16_xmodem, crc16_xmodem_rows
from drivers.errors import ProtocolError

SCHEMA = "bench-board-frames/1"
BUILTIN_DIR = Path(__file__).with_name("frames")
"""Where the descriptions that ship with bench live (``acs_board.yaml``: ours)."""

TYPES: dict[str, tuple[str, int, bool]] = {
    "u1": ("u1", 1, True), "i1": ("i1", 1, True), "u2": ("u2", 2, True), "i2": ("i2", 2, True),
    "u4": ("u4", 4, True), "i4": ("i4", 4, True), "f4": ("f4", 4, False), "f8": ("f8", 8, False),
}
"""Field type -> (numpy kind, size in bytes, integer)."""


@dataclass(frozen=True)
class Quantity:
    """A physical quantity the core knows: the units it records it in, the units a procedure's
    limits on it are parsed in (pint), and the units a description may declare for it, each as
    (factor, offset) to the record units."""

    record_units: str
    signal_units: str
    accepted: dict[str, tuple[float, float]]


QUANTITIES: dict[str, Quantity] = {
    "angular_rate": Quantity("deg/s", "deg/s", {"deg/s": (1.0, 0.0), "rad/s": (180.0 / math.pi, 0.0), "mdeg/s": (1e-3, 0.0)}),
    "specific_force": Quantity("g", "g_n", {"g": (1.0, 0.0), "g_n": (1.0, 0.0), "mg": (1e-3, 0.0), "m/s^2": (1.0 / 9.80665, 0.0)}),
    "magnetic_field": Quantity("uT", "uT", {"uT": (1.0, 0.0), "nT": (1e-3, 0.0), "mT": (1e3, 0.0), "T": (1e6, 0.0),
                                            "gauss": (100.0, 0.0), "mgauss": (0.1, 0.0)}),
    "temperature": Quantity("degC", "degC", {"degC": (1.0, 0.0), "K": (1.0, -273.15), "degF": (5.0 / 9.0, -32.0 * 5.0 / 9.0)}),
    "time": Quantity("s", "s", {"s": (1.0, 0.0), "ms": (1e-3, 0.0), "us": (1e-6, 0.0)}),
}
"""Quantities by name. ``g`` means standard gravity (9.80665 m/s², pint's ``g_n``), as in run files."""

STANDARD_FIELDS: dict[str, tuple[str | None, tuple[int, int]]] = {
    "counter": (None, (1, 1)),
    "board_time": ("time", (1, 1)),
    "status": (None, (1, 1)),
    "gyro": ("angular_rate", (3, 3)),
    "accel": ("specific_force", (3, 3)),
    "mag": ("magnetic_field", (3, 3)),
    "temp": ("temperature", (1, 3)),
}
"""Field names bench itself reads: name -> (quantity, (least, most) values per frame). ``gyro``,
``accel`` and ``mag`` are the three axes; ``temp`` the temperatures, the first one the gyro's
(used by the gyro compensation and the analyses); ``counter`` the frame counter (dropped frames),
``board_time`` the board's clock (run time of each row), ``status`` the status word."""

INTEGER_ONLY = ("counter", "board_time", "status")

OPS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "identify": ((), ("vendor", "model", "serial", "firmware")),
    "start_stream": ((), ()),
    "stop_stream": ((), ()),
    "set_odr": (("odr_hz",), ()),
    "set_moving_avg": (("n",), ()),
    "run_bit": ((), ("failed_mask",)),
    "sensor_power": (("power",), ()),
    "get_config": ((), ("odr_hz", "moving_avg_n", "streaming", "sensor_power", "baud")),
}
"""Commands the driver and the simulator know: op -> (values it sends, values its reply carries).
``identify``, ``start_stream`` and ``stop_stream`` are required; the rest are the board's choice
(a procedure step that needs a missing one is refused when it is validated)."""
REQUIRED_OPS = ("identify", "start_stream", "stop_stream")
NAK_REASONS = ("unknown_command", "bad_length", "bad_value", "not_allowed_in_state", "crc_error")
STATUS_BITS = ("streaming", "sensor_power", "bit_failed", "saturated", "overrun", "always")
REQUIREMENTS = ("sensors_on", "not_streaming")
HEADER_ITEMS = {"type": 1, "length": 1, "length16": 2, "version": 1}
NAME_RE = re.compile(r"[a-z][a-z0-9_]{0,31}")
RATIO_RE = re.compile(r"\s*([-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?)\s*/\s*(\d+(?:\.\d*)?(?:[eE][-+]?\d+)?)\s*")
"""A scale written as a ratio, ``250/32768``: two numbers, nothing evaluated."""


class FrameDescriptionError(ValueError):
    """A frame description that cannot be used: every problem with its key path
    (``("data", "fields", 2, "scale")``) and message."""

    def __init__(self, problems: list[tuple[tuple, str]], source: str = ""):
        self.problems = problems
        self.source = source
        first = problems[0] if problems else ((), "invalid")
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        super().__init__(f"{source + ': ' if source else ''}{path_text(first[0])}: {first[1]}{more}")


def path_text(path: tuple) -> str:
    """``data.fields[2].scale`` for the key path ``("data", "fields", 2, "scale")``."""
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out or "description"


# ---- checks -------------------------------------------------------------------------------------
def _crc16_rows(init: int):
    return lambda rows: crc16_xmodem_rows(rows, init)


def _sum8_rows(rows: np.ndarray) -> np.ndarray:
    return ((-rows.sum(axis=1, dtype=np.int64)) & 0xFF).astype(np.uint16)


def _crc16_one(init: int):
    return lambda data: crc16_xmodem(data, init)


def _sum8_one(data: bytes) -> int:
    return -sum(data) & 0xFF


@dataclass(frozen=True)
class CheckAlgorithm:
    """A frame check: its size in bytes, one message, many equal-length rows (numpy)."""

    name: str
    size: int
    one: Any
    rows: Any
    doc: str


CHECKS: dict[str, CheckAlgorithm] = {
    "crc16_xmodem": CheckAlgorithm("crc16_xmodem", 2, _crc16_one(0), _crc16_rows(0),
                                   "CRC-16/XMODEM: poly 0x1021, init 0, no reflection, no final XOR (check 0x31C3)"),
    "crc16_ccitt_false": CheckAlgorithm("crc16_ccitt_false", 2, _crc16_one(0xFFFF), _crc16_rows(0xFFFF),
                                        "CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, no final XOR (check 0x29B1)"),
    "sum8_complement": CheckAlgorithm("sum8_complement", 1, _sum8_one, _sum8_rows,
                                      "one byte that makes the checked bytes and itself sum to 0 mod 256 (Xsens Xbus)"),
    "none": CheckAlgorithm("none", 0, lambda data: 0, lambda rows: np.zeros(rows.shape[0], np.uint16), "no check"),
}


# ---- the model ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Field:
    """One field of the data frame. ``at``: byte offset in the frame; physical value =
    (raw × scale + offset) × factor + shift, in :attr:`units` (record units of its quantity)."""

    name: str
    type: str
    count: int
    at: int
    byte_order: str
    scale: float = 1.0
    offset: float = 0.0
    units: str = "1"
    """Units of the decoded (physical) value: the quantity's record units when it has one."""
    quantity: str | None = None
    value: int | None = None
    """A constant (an item id, a size byte): checked on every frame, not recorded."""
    sim: float = 0.0
    """What the simulator sends in a field it has no physics for (physical units)."""
    doc: str = ""

    @cached_property
    def integer(self) -> bool:
        return TYPES[self.type][2]

    @cached_property
    def size(self) -> int:
        return TYPES[self.type][1] * self.count

    @cached_property
    def dtype(self) -> str:
        return self.byte_order + TYPES[self.type][0]

    @cached_property
    def role(self) -> str:
        """``constant``, ``counter``, ``board_time``, ``status`` or ``signal``."""
        if self.value is not None:
            return "constant"
        return self.name if self.name in INTEGER_ONLY else "signal"

    @cached_property
    def raw_limits(self) -> tuple[float, float]:
        """Smallest and largest raw value of an integer field."""
        info = np.iinfo(np.dtype(TYPES[self.type][0]))
        return float(info.min), float(info.max)

    @cached_property
    def modulus(self) -> int:
        """2^bits of an integer field (where its counter or clock wraps)."""
        return 1 << (8 * TYPES[self.type][1])

    @cached_property
    def shape(self) -> tuple[int, ...]:
        return () if self.count == 1 else (self.count,)


@dataclass(frozen=True)
class PayloadItem:
    """One value of a command's or reply's payload: a named value or a constant."""

    type: str
    name: str | None = None
    value: int | None = None
    format: str = "dec"
    """For identity fields sent as numbers: ``dec`` or ``hex`` (8 hex digits for a u4)."""

    @property
    def fmt(self) -> str:
        return TYPES[self.type][0]


@dataclass(frozen=True)
class Reply:
    id: int
    payload: tuple[PayloadItem, ...] = ()
    text: tuple[str, ...] = ()
    separator: str = ";"
    echo: bool = False


@dataclass(frozen=True)
class Command:
    op: str
    id: int
    payload: tuple[PayloadItem, ...]
    reply: Reply
    requires: tuple[str, ...] = ()


@dataclass(frozen=True)
class Nak:
    id: int
    payload: tuple[PayloadItem, ...]
    codes: dict[str, int | None]
    names: dict[int, str] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class FrameDescription:
    """A board's wire format (see the module docstring). Build it with :func:`description_from_mapping`."""

    name: str
    byte_order: str
    sync: bytes
    header: tuple[str, ...]
    version: int | None
    check: CheckAlgorithm
    check_from: int
    check_byte_order: str
    max_payload: int
    data_id: int
    fields: tuple[Field, ...]
    commands: dict[str, Command]
    nak: Nak | None
    status_bits: dict[str, int]
    power_up: dict[str, int]
    max_odr_hz: int
    doc: str = ""
    source: str = ""
    text: str = ""

    # -- layout ---------------------------------------------------------------------------------
    @cached_property
    def header_len(self) -> int:
        """Bytes before the payload: sync and header items."""
        return len(self.sync) + sum(HEADER_ITEMS[h] for h in self.header)

    def _item_at(self, item: str) -> int:
        at = len(self.sync)
        for h in self.header:
            if h == item:
                return at
            at += HEADER_ITEMS[h]
        return -1

    @cached_property
    def type_at(self) -> int:
        return self._item_at("type")

    @cached_property
    def length_at(self) -> int:
        return self._item_at("length") if "length" in self.header else self._item_at("length16")

    @cached_property
    def length_size(self) -> int:
        return 2 if "length16" in self.header else 1

    @cached_property
    def version_at(self) -> int:
        return self._item_at("version")

    @cached_property
    def overhead(self) -> int:
        return self.header_len + self.check.size

    @cached_property
    def data_payload_len(self) -> int:
        return sum(f.size for f in self.fields)

    @cached_property
    def data_frame_len(self) -> int:
        return self.overhead + self.data_payload_len

    @cached_property
    def check_at(self) -> int:
        """Offset of the check in a data frame."""
        return self.header_len + self.data_payload_len

    def field(self, name: str) -> Field | None:
        return self._by_name.get(name)

    @cached_property
    def _by_name(self) -> dict[str, Field]:
        return {f.name: f for f in self.fields}

    @cached_property
    def recorded(self) -> tuple[Field, ...]:
        """Fields recorded as run-file columns (constants are not)."""
        return tuple(f for f in self.fields if f.value is None)

    @cached_property
    def signals(self) -> tuple[Field, ...]:
        """Fields decoded to physical values: the recorded ones but the counter, clock and status word."""
        return tuple(f for f in self.recorded if f.role == "signal")

    def signal_table(self) -> tuple[dict[str, str], tuple[str, ...]]:
        """(column -> signal units, vector columns) of the signals a procedure can name
        (``INSTRUMENT.NAME[.AXIS]``): fields of one value, x/y/z vectors (three values) and
        ``temp`` (named without an axis: its first value, the gyro's). Fields of other counts (a
        quaternion) are recorded but not named."""
        columns, vectors = {}, []
        for f in self.signals:
            if f.count not in (1, 3) and f.name != "temp":
                continue
            columns[f.name] = QUANTITIES[f.quantity].signal_units if f.quantity else f.units
            if f.count == 3:
                vectors.append(f.name)
        return columns, tuple(vectors)

    def stream_columns(self) -> list[tuple[str, str, str, tuple[int, ...]]]:
        """``(name, units, dtype, row shape)`` of every recorded column of the data stream, in frame
        order: ``counter`` and ``status`` as sent, ``board_time`` in s, the signals in their units
        (float64)."""
        return [(f.name, "1", TYPES[f.type][0], ()) if f.role in ("counter", "status") else (f.name, f.units, "f8", f.shape)
                for f in self.recorded]

    @cached_property
    def ops(self) -> frozenset[str]:
        return frozenset(self.commands)

    def command_by_id(self, ftype: int) -> Command | None:
        return _by_id(self)[0].get(ftype)

    def frame_name(self, ftype: int) -> str:
        """``IDENTIFY``, ``IDENTIFY_ACK``, ``NAK``, ``DATA`` or ``0x3C``: readable frame types for traffic logs."""
        return _by_id(self)[1].get(ftype, f"0x{ftype:02X}")

    @cached_property
    def known_types(self) -> frozenset[int]:
        return frozenset(_by_id(self)[1])

    # -- numpy ----------------------------------------------------------------------------------
    @cached_property
    def data_dtype(self) -> np.dtype:
        """Structured dtype of one whole data frame (sync, header, fields, check), itemsize = frame length."""
        return _dtype(self)

    # -- codec ----------------------------------------------------------------------------------
    def header_bytes(self, ftype: int, length: int) -> bytes:
        out = bytearray(self.sync)
        for h in self.header:
            if h == "type":
                out.append(ftype & 0xFF)
            elif h == "version":
                out.append(self.version or 0)
            elif h == "length":
                out.append(length)
            else:
                out += length.to_bytes(2, "little" if self.byte_order == "<" else "big")
        return bytes(out)

    def encode_frame(self, ftype: int, payload: bytes = b"") -> bytes:
        """One frame of type ``ftype`` with ``payload``."""
        limit = 0xFF if self.length_size == 1 else 0xFFFF
        if len(payload) > limit:
            raise ValueError(f"payload of {len(payload)} bytes exceeds {limit}")
        head = self.header_bytes(ftype, len(payload)) + bytes(payload)
        return head + self.check_bytes(self.check.one(head[self.check_from:]))

    def check_bytes(self, value: int) -> bytes:
        return int(value).to_bytes(self.check.size, "big" if self.check_byte_order == ">" else "little") if self.check.size else b""

    def encode_data(self, raw: dict[str, np.ndarray]) -> bytes:
        """``n`` data frames from raw (wire) values per recorded field name ((n,) or (n, count)),
        concatenated; constants and the header are filled in; no Python loop over frames."""
        n = int(np.asarray(next(iter(raw.values()))).shape[0]) if raw else 0
        frames = np.zeros(n, dtype=self.data_dtype)
        frames["sync"] = np.frombuffer(self.sync, np.uint8)
        frames["header"] = self._data_header
        for f in self.fields:
            frames[f.name] = f.value if f.value is not None else raw[f.name]
        rows = frames.view(np.uint8).reshape(n, self.data_frame_len)
        if self.check.size:
            c = self.check.rows(rows[:, self.check_from:self.check_at])
            if self.check.size == 1:
                rows[:, self.check_at] = c
            elif self.check_byte_order == ">":
                rows[:, self.check_at] = c >> 8
                rows[:, self.check_at + 1] = c & 0xFF
            else:
                rows[:, self.check_at] = c & 0xFF
                rows[:, self.check_at + 1] = c >> 8
        return rows.tobytes()

    @cached_property
    def _data_header(self) -> np.ndarray:
        """The header items of every data frame (type, length, version), as bytes."""
        return np.frombuffer(self.header_bytes(self.data_id, self.data_payload_len)[len(self.sync):], np.uint8)

    def to_raw(self, values: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
        """Physical values (record units) of the signal fields in ``values`` to their wire counts:
        rounded to the nearest count and saturated at the type's limits for integer fields.
        Returns ``(raw, saturated)``: ``saturated`` (n,) marks rows in which a ``gyro``, ``accel`` or
        ``mag`` value hit its limit (NaN counts as saturated), None if there are none."""
        out: dict[str, np.ndarray] = {}
        saturated = None
        for name, v in values.items():
            f = self.field(name)
            counts = (np.asarray(v, dtype=np.float64) - f.offset) / f.scale  # a new array: rounded and clipped in place
            if f.integer:
                np.rint(counts, out=counts)
                lo, hi = f.raw_limits
                if name in ("gyro", "accel", "mag"):
                    bad = ~((counts >= lo) & (counts <= hi))
                    s = bad.any(axis=1) if bad.ndim == 2 else bad
                    saturated = s if saturated is None else saturated | s
                np.clip(counts, lo, hi, out=counts)
            out[name] = counts.astype(TYPES[f.type][0])
        return out, saturated

    def clock_ticks(self, t_s: np.ndarray) -> np.ndarray:
        """The board clock's raw value (ticks, wrapped at the field's width) at board times ``t_s`` (s)."""
        f = self.field("board_time")
        per_s = 1.0 / f.scale
        if abs(per_s - round(per_s)) < 1e-6:
            per_s = float(round(per_s))  # 1e6 ticks per s exactly: t * 1e6, not t / 1e-6
        return np.round((np.asarray(t_s, dtype=np.float64) - f.offset) * per_s).astype(np.int64) % f.modulus

    def decode_fields(self, frames: np.ndarray) -> dict[str, np.ndarray]:
        """Physical values of the signal fields of structured data frames (float64)."""
        out = {}
        for f in self.signals:
            v = frames[f.name].astype(np.float64)
            if f.scale != 1.0:
                v *= f.scale
            if f.offset:
                v += f.offset
            out[f.name] = v
        return out


@lru_cache(maxsize=64)
def _by_id(d: FrameDescription) -> tuple[dict[int, Command], dict[int, str]]:
    cmds = {c.id: c for c in d.commands.values()}
    names = {d.data_id: "DATA"}
    for c in d.commands.values():
        names[c.id] = c.op.upper()
        names.setdefault(c.reply.id, c.op.upper() + "_ACK")
    if d.nak is not None:
        names[d.nak.id] = "NAK"
    return cmds, names


@lru_cache(maxsize=64)
def _dtype(d: FrameDescription) -> np.dtype:
    names = ["sync", "header"] + [f.name for f in d.fields]
    formats = [(np.uint8, (len(d.sync),)), (np.uint8, (d.header_len - len(d.sync),))] + \
              [(f.dtype, (f.count,)) if f.count > 1 else f.dtype for f in d.fields]
    offsets = [0, len(d.sync)] + [f.at for f in d.fields]
    if d.check.size:
        names.append("check")
        formats.append((d.check_byte_order + "u2") if d.check.size == 2 else "u1")
        offsets.append(d.check_at)
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": d.data_frame_len})


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


# ---- payloads of commands and replies --------------------------------------------------------------
def pack_items(d: FrameDescription, items: tuple[PayloadItem, ...], values: dict[str, Any]) -> bytes:
    """The bytes of ``items`` with named values from ``values`` (integers), in ``d``'s byte order."""
    out = bytearray()
    for it in items:
        v = it.value if it.value is not None else values[it.name]
        if isinstance(v, str):
            v = int(v, 16) if it.format == "hex" else int(v)
        size = TYPES[it.type][1]
        out += int(v).to_bytes(size, "little" if d.byte_order == "<" else "big", signed=it.type.startswith("i"))
    return bytes(out)


def items_len(items: tuple[PayloadItem, ...]) -> int:
    return sum(TYPES[it.type][1] for it in items)


def unpack_items(d: FrameDescription, items: tuple[PayloadItem, ...], payload: bytes) -> dict[str, Any] | None:
    """Named values of ``payload`` laid out as ``items`` (None if its length or a constant differs);
    identity values formatted as text (``hex``: upper-case, two digits per byte)."""
    if len(payload) != items_len(items):
        return None
    out: dict[str, Any] = {}
    at = 0
    for it in items:
        size = TYPES[it.type][1]
        v = int.from_bytes(payload[at:at + size], "little" if d.byte_order == "<" else "big", signed=it.type.startswith("i"))
        at += size
        if it.value is not None:
            if v != it.value:
                return None
        elif it.format == "hex":
            out[it.name] = f"{v:0{2 * size}X}"
        else:
            out[it.name] = v
    return out


IDENTITY_KEYS = ("vendor", "model", "serial", "firmware")


def parse_reply(d: FrameDescription, op: str, payload: bytes) -> dict[str, Any]:
    """The values of the reply to command ``op`` (:data:`OPS`); :class:`ProtocolError` for a payload
    that does not fit the description. ``identify`` gives text for all of :data:`IDENTITY_KEYS`
    (``""`` where the board sends none); ``get_config``'s flags are booleans."""
    reply = d.commands[op].reply
    if reply.text:
        parts = payload.decode("ascii", "replace").split(reply.separator)
        keys = list(reply.text)
        parts += [""] * (len(keys) - len(parts))
        values: dict[str, Any] = dict(zip(keys, parts[: len(keys) - 1] + [reply.separator.join(parts[len(keys) - 1:])]))
    else:
        got = unpack_items(d, reply.payload, payload)
        if got is None:
            consts = " with its constants" if any(i.value is not None for i in reply.payload) else ""
            raise ProtocolError(f"acs_board: {op.upper()} payload must be {items_len(reply.payload)} bytes{consts}, got "
                                f"{len(payload)} (frame description {d.name!r})")
        values = got
    if op == "identify":
        return {k: str(values.get(k, "")) for k in IDENTITY_KEYS}
    if op == "get_config":
        for k in ("streaming", "sensor_power"):
            if k in values:
                values[k] = bool(values[k])
    return values


def build_reply(d: FrameDescription, op: str, values: dict[str, Any], request: bytes = b"") -> bytes:
    """The payload of the reply to ``op`` carrying ``values`` (the board side); ``request``: the
    command's payload, for a reply that echoes it."""
    reply = d.commands[op].reply
    if reply.echo:
        return bytes(request)
    if reply.text:
        return reply.separator.join(str(values.get(k, "")) for k in reply.text).encode("ascii", "replace")[: d.max_payload]
    return pack_items(d, reply.payload, values)


def parse_nak(d: FrameDescription, payload: bytes) -> tuple[int | None, int]:
    """(refused command or None when the NAK does not say, code); :class:`ProtocolError` for a payload
    that does not fit the description's NAK."""
    got = unpack_items(d, d.nak.payload, payload)
    if got is None:
        raise ProtocolError(f"acs_board: NAK payload must be {items_len(d.nak.payload)} bytes, got {len(payload)} "
                            f"(frame description {d.name!r})")
    return got.get("command"), got["code"]


# ---- decoding ---------------------------------------------------------------------------------------
@dataclass
class DecodedBatch:
    """What one :meth:`FrameDecoder.feed` produced. Arrays have one row per good data frame:
    ``counter`` (frames, uint), ``board_time_s`` (s, unwrapped), ``status`` (uint) and
    :attr:`columns`, the physical values of the board's signal fields by name (float64, (n,) or
    (n, count); units: :attr:`Field.units`)."""

    counter: np.ndarray
    board_time_s: np.ndarray
    status: np.ndarray
    columns: dict[str, np.ndarray]
    replies: list[tuple[int, bytes]] = field(default_factory=list)
    crc_errors: int = 0
    garbage_bytes: int = 0
    dropped_frames: int = 0
    frames_ok: int = 0
    layout_errors: int = 0
    """Frames with a good check whose constant fields differ from the description (another output
    configuration than described): not decoded, their bytes counted as garbage."""

    @classmethod
    def empty(cls, d: FrameDescription) -> "DecodedBatch":
        def kind(name: str) -> str:
            f = d.field(name)
            return TYPES[f.type][0] if f is not None else "u2"

        return cls(np.zeros(0, kind("counter")), np.zeros(0), np.zeros(0, kind("status")),
                   {f.name: np.zeros((0,) + f.shape) for f in d.signals})

    # the names bench's own code reads (docs/acs-board-protocol.md): NaN-free views of columns
    @property
    def gyro_dps(self) -> np.ndarray:
        return self.columns["gyro"]

    @property
    def accel_g(self) -> np.ndarray:
        return self.columns["accel"]

    @property
    def mag_ut(self) -> np.ndarray:
        return self.columns["mag"]

    @property
    def temp_degc(self) -> np.ndarray:
        return self.columns["temp"]


def merge_batches(batches: list[DecodedBatch]) -> DecodedBatch:
    """Concatenate decoded batches in order: arrays joined, reply lists joined, counts summed."""
    if len(batches) == 1:
        return batches[0]
    first = batches[0]
    return DecodedBatch(
        np.concatenate([b.counter for b in batches]), np.concatenate([b.board_time_s for b in batches]),
        np.concatenate([b.status for b in batches]),
        {k: np.concatenate([b.columns[k] for b in batches], axis=0) for k in first.columns},
        [r for b in batches for r in b.replies], sum(b.crc_errors for b in batches), sum(b.garbage_bytes for b in batches),
        sum(b.dropped_frames for b in batches), sum(b.frames_ok for b in batches), sum(b.layout_errors for b in batches))


class FrameDecoder:
    """Streaming batch decoder of the frames of ``description``. Feed it bytes in any chunking.

    Resynchronises after garbage; counts check errors (frames with a plausible header whose check
    fails), garbage bytes (bytes skipped that were not part of a good frame, including those of
    corrupted frames), dropped frames (gaps in the data-frame counter, modulo its width, also
    across feeds) and unwraps the board's clock. Cumulative totals are attributes. The sequential
    rule it follows, in numpy batches, is docs/acs-board-protocol.md "Receiving"."""

    def __init__(self, description: FrameDescription, accept_unknown_types: bool = False) -> None:
        """``accept_unknown_types``: treat frames of any type as candidates (the board side uses this
        so that it can NAK unknown commands; the host side skips them as garbage)."""
        d = self.d = description
        self._plausible = np.ones(256, dtype=bool)
        if not accept_unknown_types:
            self._plausible[:] = False
            self._plausible[list(d.known_types)] = True
        self._sync = np.frombuffer(d.sync, np.uint8)
        self._dtype = d.data_dtype
        self._consts = [(f.name, f.value) for f in d.fields if f.value is not None]
        self._counter = d.field("counter")
        self._clock = d.field("board_time")
        self._status = d.field("status")
        self._prefix_crc = d.check.one(d.header_bytes(d.data_id, d.data_payload_len)[d.check_from:])
        self._tail = b""
        self._last_counter: int | None = None
        self._last_ticks: int | None = None
        self._wraps = 0
        self.crc_errors = 0
        self.garbage_bytes = 0
        self.dropped_frames = 0
        self.frames_ok = 0
        self.layout_errors = 0

    @property
    def pending_bytes(self) -> int:
        """Bytes held back until more data shows whether they start a frame."""
        return len(self._tail)

    def _lengths(self, buf: np.ndarray, cand: np.ndarray) -> np.ndarray:
        d = self.d
        at = cand + d.length_at
        if d.length_size == 1:
            return buf[at].astype(np.int64)
        lo, hi = (buf[at], buf[at + 1]) if d.byte_order == "<" else (buf[at + 1], buf[at])
        return lo.astype(np.int64) | (hi.astype(np.int64) << 8)

    def feed(self, data: bytes) -> DecodedBatch:
        """Decode ``data`` (appended to the bytes held back from the previous feed)."""
        d = self.d
        buf_bytes = self._tail + bytes(data)
        buf = np.frombuffer(buf_bytes, dtype=np.uint8)
        size = buf.size
        k = self._sync.size
        hl = d.header_len
        if size >= k:
            hit = buf[: size - k + 1] == self._sync[0]
            for j in range(1, k):
                hit &= buf[j: size - k + 1 + j] == self._sync[j]
            cand = np.flatnonzero(hit)
        else:
            cand = np.zeros(0, np.int64)
        # Stop points: places from which the rest of the buffer is undecidable (an incomplete
        # header or frame, or trailing bytes that may be part of a sync word) unless they turn out
        # to lie inside an accepted frame.
        stops = [j for j in range(max(0, size - k + 1), size) if buf_bytes[j:] == d.sync[: size - j]]
        header_ok = cand + hl <= size
        if not header_ok.all():
            stops.append(int(cand[~header_ok][0]))
        cand = cand[header_ok]
        ftype = buf[cand + d.type_at]
        flen = self._lengths(buf, cand)
        plausible = self._plausible[ftype] & np.where(ftype == d.data_id, flen == d.data_payload_len, flen <= d.max_payload)
        if d.version is not None:
            plausible &= buf[cand + d.version_at] == d.version
        cand, ftype, flen = cand[plausible], ftype[plausible], flen[plausible]
        ends = cand + d.overhead + flen
        complete = ends <= size
        if not complete.all():
            stops.extend(cand[~complete].tolist())
            cand, ftype, ends = cand[complete], ftype[complete], ends[complete]

        good = np.zeros(cand.size, dtype=bool)
        is_data = ftype == d.data_id
        d_idx = np.flatnonzero(is_data)
        rows = np.zeros((0, d.data_frame_len), dtype=np.uint8)
        frames = None
        layout_bad = 0
        if d_idx.size:
            # gather whole frames as rows (one copy each), check them in one pass
            rows = np.lib.stride_tricks.sliding_window_view(buf, d.data_frame_len)[cand[d_idx]]
            frames = rows.view(self._dtype).reshape(rows.shape[0])
            ok = self._check_rows(rows, frames)
            if self._consts:
                fits = np.ones(ok.shape, dtype=bool)
                for name, value in self._consts:
                    fits &= frames[name] == value
                layout_bad_mask = ok & ~fits
                ok &= fits
            good[d_idx] = ok
        cs, co = d.check.size, d.check_from
        for i in np.flatnonzero(~is_data):  # replies and commands are rare: a loop is fine
            s, e = int(cand[i]), int(ends[i])
            if cs:
                good[i] = d.check.one(buf_bytes[s + co: e - cs]) == int.from_bytes(
                    buf_bytes[e - cs: e], "big" if d.check_byte_order == ">" else "little")
            else:
                good[i] = True

        g_start, g_end, g_type = cand[good], ends[good], ftype[good]
        data_good = good[d_idx]
        if g_start.size > 1 and np.any(g_end[:-1] > g_start[1:]):  # rare: overlapping valid frames
            accept = _non_overlapping(g_start, g_end)
            data_good = data_good.copy()
            data_good[data_good] = accept[g_type == d.data_id]
            g_start, g_end, g_type = g_start[accept], g_end[accept], g_type[accept]
        # the first stop point outside every accepted frame ends what this feed can decide
        limit = size
        if stops:
            st = np.unique(np.asarray(stops, dtype=np.int64))
            if g_start.size:
                st = st[~_inside(st, g_start, g_end)]
            if st.size:
                limit = int(st[0])
        if g_start.size and g_start[-1] >= limit:  # frames after the stop point wait for the next feed
            keep = g_start < limit
            data_good = data_good.copy()
            data_good[data_good] = keep[g_type == d.data_id]
            g_start, g_end, g_type = g_start[keep], g_end[keep], g_type[keep]
        bad = cand[~good]
        if d_idx.size and self._consts:
            layout_starts = cand[d_idx][layout_bad_mask]
            layout_starts = layout_starts[layout_starts < limit]
            if g_start.size:
                layout_starts = layout_starts[~_inside(layout_starts, g_start, g_end)]
            layout_bad = int(layout_starts.size)
            bad = np.setdiff1d(bad, layout_starts, assume_unique=True)
        bad = bad[bad < limit]
        if bad.size and g_start.size:
            bad = bad[~_inside(bad, g_start, g_end)]
        crc_errors = int(bad.size)
        garbage = limit - int((g_end - g_start).sum())
        self._tail = buf_bytes[limit:]

        if frames is not None and not data_good.all():
            frames = rows[data_good].view(self._dtype).reshape(-1)  # rows of bytes copy faster than structured records
        batch = self._decode_data(frames)
        other = g_type != d.data_id
        if other.any():
            for s, e, t in zip(g_start[other].tolist(), g_end[other].tolist(), g_type[other].tolist()):
                batch.replies.append((t, buf_bytes[s + hl: e - cs]))
        batch.crc_errors = crc_errors
        batch.garbage_bytes = garbage
        batch.frames_ok = int(g_start.size)
        batch.layout_errors = layout_bad
        self.crc_errors += crc_errors
        self.garbage_bytes += garbage
        self.frames_ok += batch.frames_ok
        self.dropped_frames += batch.dropped_frames
        self.layout_errors += layout_bad
        return batch

    def _check_rows(self, rows: np.ndarray, frames: np.ndarray) -> np.ndarray:
        d = self.d
        if not d.check.size:
            return np.ones(rows.shape[0], dtype=bool)
        covered = rows[:, d.check_from:d.check_at]
        if d.check.name in ("crc16_xmodem", "crc16_ccitt_false") and d.check_byte_order == ">" and d.data_payload_len % 2 == 0:
            # no final XOR: the CRC over the covered bytes and the big-endian CRC is 0; the data
            # header's constant bytes go in as the starting register (the rows' words are then read in place)
            return crc16_xmodem_rows(rows[:, d.header_len:], self._prefix_crc) == 0
        return d.check.rows(covered) == frames["check"]

    def _decode_data(self, frames: np.ndarray | None) -> DecodedBatch:
        """Decode good data frames (a structured array of the description's data dtype)."""
        d = self.d
        if frames is None or frames.shape[0] == 0:
            return DecodedBatch.empty(d)
        n = frames.shape[0]
        dropped = 0
        if self._counter is not None:
            mod = self._counter.modulus
            counter = frames["counter"].astype(TYPES[self._counter.type][0])
            c = counter.astype(np.int64)
            if self._last_counter is not None:
                step = (c - np.concatenate(([self._last_counter], c[:-1]))) % mod
            else:
                step = np.concatenate(([1], (c[1:] - c[:-1]) % mod))
            dropped = int(np.where(step == 0, 0, step - 1).sum())
            self._last_counter = int(c[-1])
        else:
            counter = np.zeros(n, np.uint16)
        ticks = frames["board_time"].astype(np.int64)
        prev = np.concatenate(([self._last_ticks if self._last_ticks is not None else ticks[0]], ticks[:-1]))
        wraps = self._wraps + np.cumsum(ticks < prev)
        self._wraps = int(wraps[-1])
        self._last_ticks = int(ticks[-1])
        clock = self._clock
        board_time_s = (ticks + wraps * clock.modulus) * clock.scale
        if clock.offset:
            board_time_s += clock.offset
        status = frames["status"].astype(TYPES[self._status.type][0]) if self._status is not None else np.zeros(n, np.uint16)
        return DecodedBatch(counter, board_time_s, status, d.decode_fields(frames), dropped_frames=dropped)


def _inside(points: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Which ``points`` fall strictly after the start and before the end of a (sorted, disjoint) frame."""
    j = np.searchsorted(starts, points, side="right") - 1
    return (j >= 0) & (points > starts[np.maximum(j, 0)]) & (points < ends[np.maximum(j, 0)])


def _non_overlapping(starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Greedy left-to-right choice of check-valid frames that do not overlap (rare path)."""
    accept = np.zeros(starts.size, dtype=bool)
    end = -1
    for i, (s, e) in enumerate(zip(starts.tolist(), ends.tolist())):
        if s >= end:
            accept[i] = True
            end = e
    return accept


# ---- the descriptions that ship with bench ------------------------------------------------------------
def builtin_path(name: str) -> Path:
    return BUILTIN_DIR / f"{name}.yaml"


@lru_cache(maxsize=8)
def builtin_description(name: str = "acs_board") -> FrameDescription:
    """A description shipped in ``drivers/frames/`` (``acs_board``: ours), parsed once."""
    import yaml

    path = builtin_path(name)
    text = path.read_text(encoding="utf-8")
    return description_from_mapping(yaml.safe_load(text), str(path), text)
