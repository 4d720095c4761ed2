"""A sensor board's frames as data: the frame description and its encoding.

A lab describes its board's wire format in YAML (``docs/frame-descriptions.md``): sync bytes, the
header (frame type, payload length, version byte), the check (CRC or checksum) and its byte
order, the data frame's fields (type, count, byte order, scale, offset, units), the commands the
board understands with their frame ids and payloads, its NAK and its status bits. Ours is one
such description (``drivers/frames/acs_board.yaml``, the page ``docs/acs-board-protocol.md``).

This module holds the data model (:class:`FrameDescription`), the numpy structured dtype of the
data frame built from it, the encoding (:meth:`FrameDescription.encode_frame`,
:meth:`FrameDescription.encode_data` for ``n`` data frames at once, :meth:`FrameDescription.to_raw`
from physical values to the wire's counts) and the command payloads (:func:`pack_items`,
:func:`parse_reply`, :func:`build_reply`, :func:`parse_nak`). Building one from plain data with
every problem's key path, and the shipped descriptions: :mod:`drivers.frame_schema`; decoding a
byte stream: :mod:`drivers.frame_decoder`. The drivers layer imports nothing from bench:
``bench/board_frames.py`` loads a description file with located errors (file:line:column).

Physical value of a field = (raw × scale + offset) in the field's ``units``, converted to the
record units of its quantity (deg/s, g, uT, degC, s) when it has one (:data:`QUANTITIES`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from typing import Any

import numpy as np

from drivers.errors import ProtocolError

SCHEMA = "bench-board-frames/1"

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
    def rows(r: np.ndarray) -> np.ndarray:
        from drivers.crc import crc16_xmodem_rows  # its 128-KiB table is built on first use, not at a config's load

        return crc16_xmodem_rows(r, init)

    return rows


def _sum8_rows(rows: np.ndarray) -> np.ndarray:
    return ((-rows.sum(axis=1, dtype=np.int64)) & 0xFF).astype(np.uint16)


def _crc16_one(init: int):
    def one(data: bytes) -> int:
        from drivers.crc import crc16_xmodem

        return crc16_xmodem(data, init)

    return one


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
    that does not fit the description. ``identify`` gives text for those of :data:`IDENTITY_KEYS`
    the board's reply carries; ``get_config``'s flags are booleans."""
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
        return {k: str(values[k]) for k in IDENTITY_KEYS if k in values}
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


