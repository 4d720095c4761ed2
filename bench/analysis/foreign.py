"""Foreign HDF5 / netCDF-4 files as a :class:`~bench.analysis.dataset.Dataset`, through a column mapping.

Files written by other software (a phone logger, a biologging tag, another DAQ) name their variables
as they like and keep the units in attributes. A *mapping* says which variable (and which of its
columns) becomes which dataset column, and in which units the values are; ``docs/analysis.md``
("Foreign HDF5/netCDF files") has the syntax. netCDF-4 files are HDF5 files and are read with h5py.

* ``--map TARGET=VARIABLE[COLUMNS]:UNITS`` on the command line (repeatable; ``[COLUMNS]`` and
  ``:UNITS`` optional), ``--map sample_rate_hz=10``, ``--map latitude_deg=36.4``, or
  ``--map mapping.yaml``: a YAML mapping of the same entries (:func:`parse_mapping`).
* Targets (:data:`TARGETS`): ``gyro``, ``accel``, ``ref_rate`` (3 columns each, or one axis as
  ``gyro_x`` ...), ``temp``, ``chamber_temp``, ``pressure``, ``table_angle``, ``time``, ``power_on``.
* Units are converted with pint to the dataset's (deg/s, g, °C, Torr, deg, s); without units in the
  mapping the variable's ``units`` attribute is used. ``g`` means standard gravity
  (9.80665 m/s²), ``C`` degrees Celsius, ``m/s2`` m/s² (UDUNITS exponents).
* ``time_s`` comes from the ``time`` entry (``units: "seconds since 2021-09-20 08:52:00"`` is
  seconds, the origin kept in the metadata as ``time_origin``), else from the sample index and a
  sample rate: the mapping's ``sample_rate_hz``, else the ``sampling_rate`` attribute of the mapped
  variables (with ``sampling_rate_units``, Hz when absent). ``meta["time_source"]`` says which.
* netCDF conventions: ``_FillValue`` / ``missing_value`` are missing values, ``scale_factor`` /
  ``add_offset`` unpack packed integers. Rows where a mapped value is missing or not finite are
  dropped (``meta["dropped_rows"]``, and a note); none left is an error.

Nothing from the file or the mapping executes: names are looked up, column ranges and units are
parsed by regular expressions and pint's unit parser. Sizes are bounded (:data:`MAX_ROWS` rows,
:data:`MAX_ENTRIES` entries, attribute texts, the number of objects listed). External links and
virtual datasets (data in other files) are refused.

Every problem is an :class:`~bench.errors.InputError` of one line,
``DATA.nc: mapping entry 'gyro': ...``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from bench.analysis.dataset import COLUMNS, HDF5_SIGNATURE, Dataset, is_hdf5
from bench.errors import InputError, InputErrors, Location
from bench.inputs import read_head
from bench.record.layout import ATTR_FORMAT_VERSION

MAX_ROWS = 20_000_000
"""Most rows (samples) read from a foreign file: 23 days at 10 Hz, 5.5 h at 1 kHz."""
MAX_ENTRIES = 32
"""Most entries a mapping may have."""
MAX_SPEC_CHARS = 500
"""Longest ``--map`` entry, variable name or units text."""
MAX_MAPPING_FILE_BYTES = 64 * 1024
"""Largest mapping YAML file."""
MAX_ATTR_CHARS = 200
"""Attribute texts (units, sampling_rate_units) longer than this are not read."""
MAX_VISIT = 10_000
"""Objects of a file looked at when listing its variables."""
MAX_LISTED = 40
"""Variables named in a message."""
MAX_RATE_HZ = 1e9

MAPPING_SCHEMA = "bench-mapping/1"
SOURCE_FORMAT = "HDF5/netCDF-4 (mapped)"
"""``meta["source_format"]`` of a dataset read through a mapping."""


@dataclass(frozen=True)
class Kind:
    """What a target measures: the dataset's units (pint), the radian exponent its units must have
    (angular rate and angle 1, everything else 0) and examples for messages."""

    units: str
    radian: int
    examples: str


KINDS: dict[str, Kind] = {
    "rate": Kind("deg/s", 1, "an angular rate such as rad/s, mrad/s or deg/s"),
    "accel": Kind("standard_gravity", 0, "an acceleration such as m/s2, m/s^2 or g"),
    "temp": Kind("degC", 0, "a temperature such as degC, C or K"),
    "pressure": Kind("Torr", 0, "a pressure such as Torr, Pa or mbar"),
    "angle": Kind("deg", 1, "an angle such as deg or rad"),
    "time": Kind("s", 0, "a time such as s, ms or us"),
}

_AXES = ("x", "y", "z")


def _targets() -> dict[str, tuple[tuple[str, ...], str]]:
    out: dict[str, tuple[tuple[str, ...], str]] = {}
    for name, fmt, kind in (("gyro", "gyro_{}_dps", "rate"), ("accel", "accel_{}_g", "accel"),
                            ("ref_rate", "ref_rate_{}_dps", "rate")):
        out[name] = (tuple(fmt.format(a) for a in _AXES), kind)
        for a in _AXES:
            out[f"{name}_{a}"] = ((fmt.format(a),), kind)
    out.update({
        "temp": (("temp_c",), "temp"),
        "chamber_temp": (("chamber_temp_c",), "temp"),
        "pressure": (("pressure_torr",), "pressure"),
        "table_angle": (("table_angle_deg",), "angle"),
        "tilt": (("tilt_deg",), "angle"),
        "time": (("time_s",), "time"),
        "power_on": (("power_on_s",), "time"),
    })
    assert all(c in COLUMNS for cols, _ in out.values() for c in cols)
    return out


TARGETS: dict[str, tuple[tuple[str, ...], str]] = _targets()
"""Mapping target -> (dataset columns it fills, kind of quantity)."""

META_KEYS = {"sample_rate_hz": "Hz", "latitude_deg": "deg", "tilt_deg": "deg"}
"""Mapping keys that are numbers for the dataset's metadata, with their units."""


# ---- the mapping ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class MapEntry:
    """One target: ``variable`` of the file, its ``columns`` (``(start, stop)`` of the second
    dimension, or None for all), ``units`` (None: the variable's ``units`` attribute), and where the
    entry was written (``origin``: ``--map`` or ``mapping.yaml:3:7``)."""

    target: str
    variable: str
    columns: tuple[int, int] | None
    columns_text: str | None
    units: str | None
    origin: str

    @property
    def text(self) -> str:
        """The entry in ``--map`` syntax."""
        cols = f"[{self.columns_text}]" if self.columns_text is not None else ""
        return f"{self.target}={self.variable}{cols}" + (f":{self.units}" if self.units else "")


@dataclass
class ForeignMapping:
    """Entries by target, and the metadata numbers (``sample_rate_hz``, ``latitude_deg``) with the
    origin of each."""

    entries: dict[str, MapEntry] = field(default_factory=dict)
    meta: dict[str, float] = field(default_factory=dict)
    meta_origin: dict[str, str] = field(default_factory=dict)

    @property
    def text(self) -> str:
        """The whole mapping in ``--map`` syntax, ``; `` between entries (kept in the metadata)."""
        parts = [e.text for e in self.entries.values()] + [f"{k}={v:g}" for k, v in self.meta.items()]
        return "; ".join(parts)


_SPEC = re.compile(r"^\s*(?P<var>[^\[\]:=]+?)\s*(?:\[(?P<cols>[^\]]*)\])?\s*(?::\s*(?P<units>.*?))?\s*$")
_COLS = re.compile(r"^\s*(?:(?P<one>\d{1,9})|(?P<a>\d{0,9})\s*:\s*(?P<b>\d{0,9}))\s*$")
_VARIABLE = re.compile(r"^[^\x00-\x1f\x7f]+$")


def parse_columns(text: str) -> tuple[int, int]:
    """``"3:6"`` -> (3, 6), ``"0"`` -> (0, 1), ``":3"`` -> (0, 3); ``"3:"`` -> (3, -1) (to the last
    column). ValueError for anything else (no steps, no negative indices)."""
    m = _COLS.match(text)
    if not m:
        raise ValueError(f"columns {text!r} are not START:STOP or INDEX (such as 3:6 or 0)")
    if m.group("one") is not None:
        k = int(m.group("one"))
        return k, k + 1
    a = int(m.group("a")) if m.group("a") else 0
    b = int(m.group("b")) if m.group("b") else -1
    if b != -1 and b <= a:
        raise ValueError(f"columns {text!r} select nothing (STOP must be greater than START)")
    return a, b


def _entry(target: str, variable: str, cols: str | None, units: str | None, origin: str,
           where: Location | None, fieldname: str) -> MapEntry:
    def bad(msg: str) -> InputError:
        return InputError(msg, where, fieldname)

    if target not in TARGETS:
        raise bad(f"unknown target {target!r} (targets: {', '.join(TARGETS)}, sample_rate_hz, latitude_deg)")
    variable = variable.strip()
    if not variable or len(variable) > MAX_SPEC_CHARS or not _VARIABLE.match(variable):
        raise bad(f"target {target!r}: {variable!r} is not a variable name")
    span = None
    if cols is not None:
        try:
            span = parse_columns(cols)
        except ValueError as exc:
            raise bad(f"target {target!r}: {exc}") from None
        cols = cols.strip()
    if units is not None:
        units = units.strip()
        if not units:
            units = None
        elif len(units) > MAX_SPEC_CHARS:
            raise bad(f"target {target!r}: units text longer than {MAX_SPEC_CHARS} characters")
    return MapEntry(target, variable, span, cols, units, origin)


def parse_mapping(specs: Sequence[str]) -> ForeignMapping:
    """The ``--map`` values: ``TARGET=VARIABLE[COLUMNS]:UNITS``, ``sample_rate_hz=N``,
    ``latitude_deg=N``, or the path of a mapping YAML file (a value without ``=``).

    A target or metadata key given twice, or two targets filling the same column (``gyro`` and
    ``gyro_x``), is an :class:`InputError`."""
    mapping = ForeignMapping()
    if len(specs) > MAX_ENTRIES:
        raise InputError(f"more than {MAX_ENTRIES} mapping entries", None, "--map")
    for spec in specs:
        if not isinstance(spec, str) or len(spec) > MAX_SPEC_CHARS:
            raise InputError(f"an entry longer than {MAX_SPEC_CHARS} characters", None, "--map")
        if "=" not in spec:
            _merge(mapping, _load_mapping_file(Path(spec)))
            continue
        key, _, rest = spec.partition("=")
        key = key.strip()
        one = ForeignMapping()
        if key in META_KEYS:
            one.meta[key] = _meta_number(key, rest.strip(), None, "--map")
            one.meta_origin[key] = "--map"
        else:
            m = _SPEC.match(rest)
            if key in TARGETS and not m:
                raise InputError(f"{spec!r}: expected TARGET=VARIABLE[COLUMNS]:UNITS such as "
                                 "gyro=angular_velocity[3:6]:rad/s", None, "--map")
            entry = _entry(key, m.group("var") if m else rest, m.group("cols") if m else None,
                           m.group("units") if m else None, "--map", None, "--map")
            one.entries[key] = entry
        _merge(mapping, one)
    if len(mapping.entries) > MAX_ENTRIES:
        raise InputError(f"more than {MAX_ENTRIES} mapping entries", None, "--map")
    return mapping


def _merge(into: ForeignMapping, more: ForeignMapping) -> None:
    for key, value in more.meta.items():
        if key in into.meta:
            raise InputError(f"{key} is given twice ({into.meta_origin[key]} and {more.meta_origin[key]})", None, "--map")
        into.meta[key] = value
        into.meta_origin[key] = more.meta_origin[key]
    for target, entry in more.entries.items():
        if target in into.entries:
            raise InputError(f"target {target!r} is mapped twice ({into.entries[target].origin} and {entry.origin})",
                             None, "--map")
        cols = set(TARGETS[target][0])
        for other in into.entries.values():
            both = cols & set(TARGETS[other.target][0])
            if both:
                raise InputError(f"targets {other.target!r} and {target!r} both fill {', '.join(sorted(both))}",
                                 None, "--map")
        into.entries[target] = entry


def _meta_number(key: str, value: Any, where: Location | None, fieldname: str) -> float:
    from bench.units import to_units

    if isinstance(value, str):
        try:
            value = float(value)  # a bare number means the key's units ("10" Hz)
        except ValueError:
            pass
    v = to_units(value, META_KEYS[key], where, fieldname if where is not None else f"{fieldname}: {key}")
    if key == "sample_rate_hz" and not 0 < v <= MAX_RATE_HZ:
        raise InputError(f"sample_rate_hz must be above 0 Hz (and at most {MAX_RATE_HZ:g}), got {v:g}",
                         where, fieldname if where is not None else f"{fieldname}: {key}")
    if key == "tilt_deg" and not -360 <= v <= 360:
        raise InputError(f"tilt_deg must lie in -360..360 deg, got {v:g}", where,
                         fieldname if where is not None else f"{fieldname}: {key}")
    if key == "latitude_deg" and not -90 <= v <= 90:
        raise InputError(f"latitude_deg must lie in -90..90 deg, got {v:g}", where,
                         fieldname if where is not None else f"{fieldname}: {key}")
    return v


def _load_mapping_file(path: Path) -> ForeignMapping:
    """A mapping YAML file (``docs/analysis.md``): targets as keys, each either an entry in ``--map``
    syntax (``gyro: angular_velocity[3:6]:rad/s``) or ``{variable, columns, units}``; optional
    ``schema: bench-mapping/1``, ``sample_rate_hz``, ``latitude_deg``."""
    from bench.yamlsrc import Node, load_yaml

    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise InputError(f"{str(path)!r} is not TARGET=VARIABLE[COLUMNS]:UNITS and no such mapping file exists",
                         None, "--map") from None
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read mapping file {str(path)!r}: {exc}", None, "--map") from None
    if path.is_dir():
        raise InputError(f"{str(path)!r} is a directory, not a mapping file", None, "--map")
    if size > MAX_MAPPING_FILE_BYTES:
        raise InputError(f"mapping file larger than {MAX_MAPPING_FILE_BYTES // 1024} KiB", Location(path))
    src = load_yaml(path, "mapping file")
    lines = src.text.split("\n")
    out = ForeignMapping()
    errors: list[InputError] = []
    root: dict[str, Node] = src.root.value
    for key, node in root.items():
        kloc = src.root.key_locations.get(key, src.root.location)
        origin = str(kloc)
        try:
            if key == "schema":
                if node.value != MAPPING_SCHEMA:
                    raise InputError(f"expected {MAPPING_SCHEMA!r}, got {node.value!r}", node.location, key)
            elif key in META_KEYS:
                if isinstance(node.value, (bool, list, dict)) or node.value is None:
                    raise InputError(f"expected a number, got {node.plain()!r}", node.location, key)
                out.meta[key] = _meta_number(key, node.value, node.location, key)
                out.meta_origin[key] = origin
            elif key not in TARGETS:
                raise InputError(f"unknown key (targets: {', '.join(TARGETS)}; also schema, "
                                 f"{', '.join(META_KEYS)})", kloc, key)
            elif isinstance(node.value, str):
                m = _SPEC.match(node.value)
                if not m:
                    raise InputError("expected VARIABLE[COLUMNS]:UNITS such as angular_velocity[3:6]:rad/s, "
                                     "or a mapping with variable, columns, units", node.location, key)
                one = ForeignMapping()
                one.entries[key] = _entry(key, m.group("var"), m.group("cols"), m.group("units"), origin,
                                          node.location, key)
                _merge_located(out, one, node.location, key)
            elif isinstance(node.value, dict):
                fields: dict[str, Node] = node.value
                unknown = [k for k in fields if k not in ("variable", "columns", "units")]
                if unknown:
                    raise InputError(f"unknown field {unknown[0]!r} (fields: variable, columns, units)",
                                     node.key_locations.get(unknown[0], node.location), key)
                var = fields.get("variable")
                if var is None or not isinstance(var.value, str):
                    raise InputError("needs 'variable:' naming the file's variable", node.location, key)
                cols = fields.get("columns")
                cols_text = None if cols is None else _columns_text(cols, lines)
                units = fields.get("units")
                if units is not None and not isinstance(units.value, str):
                    raise InputError(f"units must be text such as rad/s, got {units.plain()!r}", units.location, key)
                one = ForeignMapping()
                one.entries[key] = _entry(key, var.value, cols_text, None if units is None else units.value, origin,
                                          node.location, key)
                _merge_located(out, one, node.location, key)
            else:
                raise InputError(f"expected VARIABLE[COLUMNS]:UNITS or a mapping, got {node.plain()!r}",
                                 node.location, key)
        except InputErrors as exc:
            errors.extend(exc.errors)
        except InputError as exc:
            errors.append(exc)
    if not errors and not out.entries:
        errors.append(InputError("the mapping file maps no variable (keys such as gyro, accel, temp, time)",
                                 src.root.location))
    if len(errors) == 1:
        raise errors[0]
    if errors:
        raise InputErrors(errors)
    return out


def _merge_located(into: ForeignMapping, one: ForeignMapping, where: Location, key: str) -> None:
    try:
        _merge(into, one)
    except InputError as exc:
        raise InputError(exc.message, where, key) from None


def _columns_text(node, lines: list[str]) -> str:
    """The ``columns:`` value as written. YAML 1.1 reads an unquoted ``3:6`` as the base-60 number
    186, so an integer is taken from the source text at the node's position."""
    v = node.value
    if isinstance(v, str):
        return v
    if isinstance(v, int) and not isinstance(v, bool):
        loc = node.location
        if loc.line is not None and loc.column is not None and 0 < loc.line <= len(lines):
            m = re.match(r"\s*(\d+(?:\s*:\s*\d*)?)", lines[loc.line - 1][loc.column - 1:])
            if m:
                return m.group(1)
        return str(v)
    raise InputError(f"columns must be START:STOP or INDEX such as \"3:6\" or 0, got {node.plain()!r}",
                     node.location, "columns")


# ---- units ---------------------------------------------------------------------------------------
_UNITS_TEXT = re.compile(r"^[A-Za-z0-9_µμ°/*^.\-+ ()%]+$")
_SINCE = re.compile(r"^\s*(?P<unit>[A-Za-z]+)\s+since\s+(?P<origin>\S.*?)\s*$", re.IGNORECASE)
_CELSIUS = re.compile(r"^(?:°\s*|deg(?:rees?)?[\s_]*)?C(?:elsius)?$", re.IGNORECASE)
_FAHRENHEIT = re.compile(r"^(?:°\s*|deg(?:rees?)?[\s_]*)?F(?:ahrenheit)?$", re.IGNORECASE)
_KELVIN = re.compile(r"^(?:°\s*|deg(?:rees?)?[\s_]*)?K(?:elvin)?$", re.IGNORECASE)
_GRAVITY = {"g": "standard_gravity", "G": "standard_gravity", "gn": "standard_gravity", "g0": "standard_gravity",
            "g_n": "standard_gravity", "g_0": "standard_gravity", "mg": "millistandard_gravity",
            "mG": "millistandard_gravity", "ug": "microstandard_gravity", "µg": "microstandard_gravity",
            "μg": "microstandard_gravity"}
_RATE = {"dps": "deg/s", "deg/sec": "deg/s", "rad/sec": "rad/s", "°/s": "deg/s"}
_EXPONENT = re.compile(r"(?<=[A-Za-zµμ])(-?\d+)(?![\d.])")


def _unit_candidates(text: str, kind: str) -> list[str]:
    """Texts to try with pint, in order: the kind's aliases (g, C, dps), the text, UDUNITS exponents
    written out (``m/s2`` -> ``m/s**2``, ``m s-2`` -> ``m s**-2``)."""
    t = text.strip()
    out: list[str] = []
    if kind == "accel" and t in _GRAVITY:
        out.append(_GRAVITY[t])
    if kind == "temp":
        if _CELSIUS.match(t):
            out.append("degC")
        elif _FAHRENHEIT.match(t):
            out.append("degF")
        elif _KELVIN.match(t):
            out.append("kelvin")
    if kind in ("rate", "angle") and t in _RATE:
        out.append(_RATE[t])
    out.append(t.replace("^", "**"))
    spelled = _EXPONENT.sub(r"**\1", t.replace("^", "**").replace("***", "**"))
    if spelled not in out:
        out.append(spelled)
    return out


@dataclass(frozen=True)
class Conversion:
    """``values`` in some units -> the kind's units: ``convert(values)``."""

    text: str
    quantity: Any  # pint Quantity: magnitude (1 unless the units text has a number) and units
    target: str

    def convert(self, values: np.ndarray) -> np.ndarray:
        from bench.units import registry

        q = self.quantity
        scaled = values * float(q.magnitude) if q.magnitude != 1 else values
        return np.asarray(registry().Quantity(scaled, q.units).to(self.target).magnitude, dtype=float)


def conversion(text: str, kind: str) -> Conversion:
    """The :class:`Conversion` from units ``text`` to the dataset units of ``kind``; ValueError with
    the reason when the text is not units pint reads, or units of another quantity."""
    import pint

    from bench.units import registry

    k = KINDS[kind]
    if len(text) > MAX_SPEC_CHARS or not _UNITS_TEXT.match(text.strip() or "?"):
        raise ValueError(f"units {text!r} are not units bench reads (expected {k.examples})")
    ureg = registry()
    q = None
    last = ""
    for cand in _unit_candidates(text, kind):
        try:
            parsed = ureg.Quantity(cand)
        except Exception as exc:  # noqa: BLE001 - pint's parser raises many types
            last = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            continue
        if isinstance(parsed, pint.Quantity):
            q = parsed
            break
        last = "a number, not units"
    if q is None:
        raise ValueError(f"unknown units {text!r} ({last}); expected {k.examples}")
    try:
        ureg.Quantity(1.0, q.units).to(k.units)
        # radians are dimensionless to pint: Hz would pass as an angular rate without this check
        ok = dict(ureg.get_root_units(q.units)[1]._units).get("radian", 0) == k.radian
    except Exception:  # noqa: BLE001 - DimensionalityError, offset-unit errors
        ok = False
    if not ok:
        raise ValueError(f"units {text!r} ({q.units}) are not {k.examples}")
    if not (isinstance(q.magnitude, (int, float)) and math.isfinite(q.magnitude) and q.magnitude != 0):
        raise ValueError(f"units {text!r} have a scale that is not a finite non-zero number")
    return Conversion(text, q, k.units)


# ---- reading the file ----------------------------------------------------------------------------
def _open(path: Path):
    """The file opened read-only with h5py; :class:`InputError` when it cannot be."""
    import h5py

    if not path.exists():
        raise InputError("data file not found", Location(path))
    if path.is_dir():
        raise InputError("is a directory, not a data file", Location(path))
    head = read_head(path, 8)  # a FIFO or device: refused, never opened blocking
    if head != HDF5_SIGNATURE:
        what = ("a netCDF-3 classic file; convert it to netCDF-4 (nccopy -k nc4 IN OUT)" if head[:3] == b"CDF"
                else "not an HDF5 or netCDF-4 file (no HDF5 signature at its start)")
        raise InputError(f"{what}; --map reads HDF5 and netCDF-4 files (a measured-data CSV needs no --map)",
                         Location(path))
    last: Exception | None = None
    for kwargs in ({}, {"locking": False}):
        try:
            return h5py.File(path, "r", **kwargs)
        except Exception as exc:  # noqa: BLE001 - h5py raises OSError subclasses, RuntimeError...
            last = exc
    text = str(last).splitlines()[0] if str(last) else type(last).__name__
    raise InputError(f"cannot open as HDF5: {text}", Location(path))


def is_run_file(path: Path) -> bool | None:
    """True for a bench run file (root attribute ``format_version``), False for another HDF5 file,
    None when it cannot be told (not HDF5, cannot be opened: the run file reader then says why)."""
    if not is_hdf5(path):
        return None
    try:
        f = _open(path)
    except InputError:
        return None
    try:
        return ATTR_FORMAT_VERSION in f.attrs
    except Exception:  # noqa: BLE001 - a damaged file: let the run reader report it
        return None
    finally:
        f.close()


def _attr_text(obj, name: str) -> str | None:
    """Attribute ``name`` as text (str, bytes, or a one-element array of those), None otherwise."""
    try:
        if name not in obj.attrs:
            return None
        v = obj.attrs[name]
    except Exception:  # noqa: BLE001 - an attribute h5py cannot read (unsupported type)
        return None
    if isinstance(v, np.ndarray):
        if v.size != 1:
            return None
        v = v.reshape(-1)[0]
    if isinstance(v, (bytes, np.bytes_)):
        v = bytes(v).decode("utf-8", errors="replace")
    if not isinstance(v, str):
        return None
    v = v.strip("\x00 ").strip()
    return v if 0 < len(v) <= MAX_ATTR_CHARS else None


def _attr_number(obj, name: str) -> float | None:
    try:
        if name not in obj.attrs:
            return None
        v = np.asarray(obj.attrs[name])
    except Exception:  # noqa: BLE001
        return None
    if v.size != 1 or v.dtype.kind not in "iuf":
        return None
    x = float(v.reshape(-1)[0])
    return x if math.isfinite(x) else None


def _is_variable(obj) -> bool:
    """A numeric dataset that is a netCDF variable (not a bare dimension)."""
    import h5py

    if not isinstance(obj, h5py.Dataset) or obj.dtype.kind not in "iuf":
        return False
    name = _attr_text(obj, "NAME") or ""
    return not name.startswith("This is a netCDF dimension but not a netCDF variable")


def _describe(obj) -> str:
    shape = "×".join(str(n) for n in obj.shape) or "scalar"
    units = _attr_text(obj, "units")
    return f"{obj.name.lstrip('/')} ({shape}" + (f", {units})" if units else ", no units)")


def list_variables(f) -> str:
    """The file's numeric variables with shapes and units, for messages (at most :data:`MAX_LISTED`)."""
    found: list[str] = []
    seen = 0

    def visit(name: str, obj) -> bool | None:
        nonlocal seen
        seen += 1
        if seen > MAX_VISIT:
            return True
        if _is_variable(obj):
            found.append(_describe(obj))
        return None

    try:
        f.visititems(visit)
    except Exception:  # noqa: BLE001 - a damaged file: list what was found
        pass
    if not found:
        return "no numeric variables"
    more = f", ... ({len(found) - MAX_LISTED} more)" if len(found) > MAX_LISTED else ""
    return ", ".join(found[:MAX_LISTED]) + more


def foreign_file_error(path: Path) -> InputError:
    """The error for a foreign HDF5/netCDF-4 file given without ``--map``: what to pass, and the
    file's variables."""
    f = _open(path)
    try:
        listing = list_variables(f)
    finally:
        f.close()
    return InputError("not a bench run file: to analyse another program's HDF5/netCDF-4 data pass "
                      "--map TARGET=VARIABLE[COLUMNS]:UNITS (such as --map gyro=angular_velocity[3:6]:rad/s, "
                      f"docs/analysis.md); variables: {listing}", Location(path))


def _lookup(f, path: Path, entry: MapEntry):
    """The h5py dataset of ``entry.variable``: hard or soft links only, numeric, 1-D or 2-D."""
    import h5py

    def bad(msg: str) -> InputError:
        return _entry_error(path, entry, msg)

    obj = f
    parts = [p for p in entry.variable.split("/") if p]
    for i, part in enumerate(parts):
        if not isinstance(obj, h5py.Group):
            raise bad(f"{'/'.join(parts[:i])!r} is not a group")
        try:
            link = obj.get(part, getlink=True)
        except Exception:  # noqa: BLE001 - odd names h5py refuses
            link = None
        if link is None:
            raise bad(f"no variable {entry.variable!r} in the file (variables: {list_variables(f)})")
        if isinstance(link, h5py.ExternalLink):
            raise bad(f"{entry.variable!r} is a link to another file ({link.filename}); it is not followed")
        try:
            obj = obj[part]
        except Exception as exc:  # noqa: BLE001 - a dangling soft link, a damaged object
            raise bad(f"cannot open {entry.variable!r}: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
    if isinstance(obj, h5py.Group):
        raise bad(f"{entry.variable!r} is a group, not a variable (variables: {list_variables(f)})")
    if not isinstance(obj, h5py.Dataset):
        raise bad(f"{entry.variable!r} is not a variable")
    if obj.is_virtual:
        raise bad(f"{entry.variable!r} is a virtual dataset (its data lives in other files); it is not read")
    if obj.dtype.kind not in "iuf":
        raise bad(f"{entry.variable!r} holds {obj.dtype} values, not numbers")
    if obj.ndim not in (1, 2):
        raise bad(f"{entry.variable!r} has shape {obj.shape}; bench reads 1-D (samples) and 2-D (samples × columns) "
                  "variables")
    return obj


def _entry_error(path: Path, entry: MapEntry, msg: str) -> InputError:
    where = f"; entry at {entry.origin}" if entry.origin != "--map" else ""
    return InputError(msg + where, Location(path), f"mapping entry {entry.target!r}")


@dataclass
class _Read:
    entry: MapEntry
    values: np.ndarray  # (n, k) floats, converted
    units: str
    units_from: str


def _read_entry(f, path: Path, entry: MapEntry) -> tuple[_Read, Any]:
    """Read, unpack (netCDF conventions) and convert one entry's columns; also return the dataset."""
    obj = _lookup(f, path, entry)
    columns, kind = TARGETS[entry.target]
    want = len(columns)
    rows = int(obj.shape[0])
    if rows == 0:
        raise _entry_error(path, entry, f"{entry.variable!r} has no rows (shape {obj.shape})")
    if rows > MAX_ROWS:
        raise _entry_error(path, entry, f"{entry.variable!r} has {rows} rows; bench reads at most {MAX_ROWS} "
                                        "(cut the file into parts)")
    if obj.ndim == 1:
        if entry.columns is not None and entry.columns != (0, 1):
            raise _entry_error(path, entry, f"{entry.variable!r} is 1-D ({rows} values): it has no columns "
                                            f"[{entry.columns_text}] to select")
        if want != 1:
            raise _entry_error(path, entry, f"needs {want} columns ({', '.join(columns)}) but {entry.variable!r} is "
                                            f"1-D; select 3 columns of a 2-D variable or map "
                                            f"{', '.join(f'{entry.target}_{a}' for a in _AXES)} one by one")
        sel: tuple = (slice(None),)
    else:
        ncols = int(obj.shape[1])
        a, b = entry.columns if entry.columns is not None else (0, ncols)
        b = ncols if b == -1 else b
        if a >= ncols or b > ncols:
            raise _entry_error(path, entry, f"columns [{entry.columns_text}] are out of range: {entry.variable!r} has "
                                            f"{ncols} columns (0 to {ncols - 1})")
        if b - a != want:
            chosen = f"columns [{entry.columns_text}] select {b - a}" if entry.columns is not None else \
                f"{entry.variable!r} has {ncols} columns"
            hint = f"select them as {entry.variable}[START:STOP]" if want > 1 else f"select one as {entry.variable}[INDEX]"
            raise _entry_error(path, entry, f"needs {want} column{'s' if want > 1 else ''} "
                                            f"({', '.join(columns)}); {chosen}; {hint}")
        sel = (slice(None), slice(a, b))
    try:
        raw = np.asarray(obj[sel])
    except Exception as exc:  # noqa: BLE001 - damaged data, a missing filter
        raise _entry_error(path, entry, f"cannot read {entry.variable!r}: "
                                        f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
    values = _unpack(raw, obj).reshape(rows, want)
    units_text = entry.units
    units_from = "the mapping"
    if units_text is None:
        units_text = _attr_text(obj, "units")
        units_from = f"the units attribute of {entry.variable!r}"
        if units_text is None:
            raise _entry_error(path, entry, f"units are needed: {entry.variable!r} has no units attribute; give them "
                                            f"as {entry.target}={entry.variable}"
                                            f"{f'[{entry.columns_text}]' if entry.columns_text is not None else ''}"
                                            f":UNITS ({KINDS[kind].examples})")
    return _Read(entry, values, units_text, units_from), obj


def _unpack(raw: np.ndarray, obj) -> np.ndarray:
    """Floats with netCDF's ``_FillValue`` / ``missing_value`` as NaN and ``scale_factor`` /
    ``add_offset`` applied."""
    values = raw.astype(float)
    for name in ("_FillValue", "missing_value"):
        try:
            fill = np.asarray(obj.attrs[name]) if name in obj.attrs else None
        except Exception:  # noqa: BLE001
            fill = None
        if fill is not None and fill.dtype.kind in "iuf" and 0 < fill.size <= 16:
            for x in fill.reshape(-1):
                if np.isfinite(x):
                    values[raw == x] = np.nan
    scale = _attr_number(obj, "scale_factor")
    offset = _attr_number(obj, "add_offset")
    if scale is not None:
        values *= scale
    if offset is not None:
        values += offset
    return values


def _convert(path: Path, r: _Read) -> tuple[np.ndarray, str | None]:
    """Values of ``r`` in the dataset's units, and the time origin for ``UNITS since ORIGIN``."""
    kind = TARGETS[r.entry.target][1]
    text, origin = r.units, None
    m = _SINCE.match(text)
    if m:
        if kind != "time":
            raise _entry_error(path, r.entry, f"units {text!r} (from {r.units_from}) are times, not "
                                              f"{KINDS[kind].examples}")
        text, origin = m.group("unit"), m.group("origin")
    try:
        conv = conversion(text, kind)
    except ValueError as exc:
        raise _entry_error(path, r.entry, f"{exc} (units from {r.units_from})") from None
    try:
        with np.errstate(all="ignore"):
            return conv.convert(r.values), origin
    except Exception as exc:  # noqa: BLE001 - pint refusing a conversion it accepted for 1.0
        raise _entry_error(path, r.entry, f"cannot convert {text!r}: {exc}") from None


def _sample_rate(path: Path, mapping: ForeignMapping, objs: dict[str, Any]) -> tuple[float, str] | None:
    """The sample rate (Hz) and where it came from: the mapping's ``sample_rate_hz``, else the
    ``sampling_rate`` attributes of the mapped variables (which must agree)."""
    if "sample_rate_hz" in mapping.meta:
        origin = mapping.meta_origin["sample_rate_hz"]
        return mapping.meta["sample_rate_hz"], ("sample_rate_hz of --map" if origin == "--map"
                                                 else f"sample_rate_hz at {origin}")
    found: dict[str, float] = {}
    for target, obj in objs.items():
        rate = _attr_number(obj, "sampling_rate")
        if rate is None:
            continue
        units = _attr_text(obj, "sampling_rate_units") or "Hz"
        from bench.units import registry

        try:
            if not _UNITS_TEXT.match(units):
                raise ValueError(units)
            hz = float(registry().Quantity(rate, units.replace("^", "**")).to("Hz").magnitude)
        except Exception:  # noqa: BLE001 - units pint does not read, or not a frequency
            raise InputError(f"sampling_rate_units {units!r} of {mapping.entries[target].variable!r} is not a "
                             "frequency such as Hz; give --map sample_rate_hz=N", Location(path),
                             f"mapping entry {target!r}") from None
        if not (math.isfinite(hz) and 0 < hz <= MAX_RATE_HZ):
            raise InputError(f"sampling_rate {rate:g} {units} of {mapping.entries[target].variable!r} is not a sample "
                             "rate; give --map sample_rate_hz=N", Location(path), f"mapping entry {target!r}")
        found[target] = hz
    if not found:
        return None
    rates = set(found.values())
    if len(rates) > 1:
        listing = ", ".join(f"{mapping.entries[t].variable} {hz:g} Hz" for t, hz in found.items())
        raise InputError(f"the mapped variables' sampling_rate attributes differ ({listing}); map a time variable "
                         "or give --map sample_rate_hz=N", Location(path), "mapping entry 'time'")
    target = next(iter(found))
    return found[target], f"sampling_rate attribute of {mapping.entries[target].variable!r}"


def dataset_from_foreign(path: str | Path, mapping: ForeignMapping | Sequence[str]) -> Dataset:
    """The :class:`Dataset` of foreign HDF5/netCDF-4 file ``path`` through ``mapping`` (a
    :class:`ForeignMapping` or the ``--map`` values). See the module docstring."""
    p = Path(path)
    if not isinstance(mapping, ForeignMapping):
        mapping = parse_mapping(list(mapping))
    if not mapping.entries:
        raise InputError("the mapping maps no variable (--map gyro=VARIABLE[COLUMNS]:UNITS ...)", None, "--map")
    sensors = [t for t in mapping.entries if t.startswith(("gyro", "accel"))]
    if not sensors:
        raise InputError("the mapping maps no gyro or accelerometer variable (targets gyro, gyro_x, accel, ...)",
                         None, "--map")
    if _is_text(p):
        reads, rate, meta = _csv_reads(p, mapping)
        return _assemble(p, mapping, reads, rate, meta)
    f = _open(p)
    try:
        if ATTR_FORMAT_VERSION in f.attrs:
            raise InputError("is a bench run file; it is read without --map", Location(p))
        reads: dict[str, _Read] = {}
        objs: dict[str, Any] = {}
        first: _Read | None = None
        for target, entry in mapping.entries.items():
            r, obj = _read_entry(f, p, entry)
            if first is not None and r.values.shape[0] != first.values.shape[0]:
                raise _entry_error(p, entry, f"{entry.variable!r} has {r.values.shape[0]} rows but "
                                             f"{first.entry.variable!r} (entry {first.entry.target!r}) has "
                                             f"{first.values.shape[0]}; mapped variables need one row per sample")
            first = first or r
            reads[target] = r
            objs[target] = obj
        rate = None if "time" in reads else _sample_rate(p, mapping, objs)
    finally:
        f.close()
    return _assemble(p, mapping, reads, rate, {"source_format": SOURCE_FORMAT})


def _is_text(p: Path) -> bool:
    """A file to read as a CSV under a mapping: it exists, is not HDF5 or netCDF-3, and its first
    4 KiB hold no NUL byte (any other file goes to :func:`_open`, which says what it is)."""
    try:
        with open(p, "rb") as fh:
            head = fh.read(4096)
    except OSError:
        return False
    return bool(head) and not head.startswith(HDF5_SIGNATURE) and not head.startswith(b"CDF") and b"\0" not in head


def _csv_reads(p: Path, mapping: ForeignMapping) -> tuple[dict[str, _Read], tuple[float, str] | None, dict[str, Any]]:
    """The mapped columns of a CSV file (``gyro=gyr_x,gyr_y,gyr_z:deg/s``: a target's columns named
    in order, comma-separated; units from the mapping, a CSV having no units attributes), the sample
    rate (the mapping's, else the CSV's ``# sample_rate_hz:`` line) and the CSV's metadata."""
    from bench.analysis.dataset import csv_meta
    from bench.csvsrc import numeric_columns, read_csv_table

    table = read_csv_table(p)
    header = Location(p, table.header_line)
    reads: dict[str, _Read] = {}
    for target, entry in mapping.entries.items():
        columns, kind = TARGETS[target]
        if entry.columns is not None:
            example = "A,B,C" if len(columns) == 3 else "NAME"
            raise _entry_error(p, entry, f"a CSV column holds one value per row: name the column(s) instead of "
                                         f"[{entry.columns_text}], e.g. {target}={example}:UNITS")
        names = [c.strip() for c in entry.variable.split(",")]
        if len(names) != len(columns):
            raise _entry_error(p, entry, f"needs {len(columns)} column{'s' if len(columns) > 1 else ''} "
                                         f"({', '.join(columns)}); {entry.variable!r} names {len(names)} (name them "
                                         "comma-separated, in x, y, z order)")
        for name in names:
            if name not in table.header:
                raise InputError(f"no column {name!r} in the CSV header (columns: {', '.join(table.header)})", header,
                                 f"mapping entry {target!r}")
        if entry.units is None:
            raise _entry_error(p, entry, f"units are needed: a CSV column has no units attribute; give them as "
                                         f"{entry.text}:UNITS ({KINDS[kind].examples})")
        values = numeric_columns(table, names)
        reads[target] = _Read(entry, np.column_stack([values[c] for c in names]), entry.units, "the mapping")
    meta = csv_meta(table)
    rate = None
    if "time" not in reads:
        if "sample_rate_hz" in mapping.meta:
            origin = mapping.meta_origin["sample_rate_hz"]
            rate = (mapping.meta["sample_rate_hz"], "sample_rate_hz of --map" if origin == "--map"
                    else f"sample_rate_hz at {origin}")
        elif isinstance(meta.get("sample_rate_hz"), float):
            rate = (float(meta["sample_rate_hz"]), f"# sample_rate_hz: at {p}:{table.meta_lines['sample_rate_hz']}")
    meta["source_format"] = "CSV (mapped)"
    return reads, rate, meta


def _assemble(p: Path, mapping: ForeignMapping, reads: dict[str, _Read], rate: tuple[float, str] | None,
              meta: dict[str, Any]) -> Dataset:
    """The dataset of the mapped values ``reads``: units converted, time from the ``time`` entry or
    ``rate``, rows with a missing value dropped (said in the metadata), time increasing."""
    first = next(iter(reads.values()), None)
    n = first.values.shape[0] if first is not None else 0
    cols: dict[str, np.ndarray] = {}
    meta = {**meta, "mapping": mapping.text}
    for target, r in reads.items():
        values, origin = _convert(p, r)
        for k, name in enumerate(TARGETS[target][0]):
            cols[name] = values[:, k]
        if target == "time":
            meta["time_units"] = r.units
            if origin is not None:
                meta["time_origin"] = origin
            meta["time_source"] = f"variable {r.entry.variable!r} ({r.units}, from {r.units_from})"
    if "time_s" not in cols:
        if rate is None:
            raise InputError("no time: map a time variable (--map time=VARIABLE:s) or give the sample rate "
                             "(--map sample_rate_hz=N); the mapped variables have no sampling_rate attribute",
                             Location(p), "mapping entry 'time'")
        hz, where = rate
        cols["time_s"] = np.arange(n, dtype=float) / hz
        meta["time_source"] = f"sample index / {hz:g} Hz ({where})"
        meta["sample_rate_hz"] = float(hz)
    for key, value in mapping.meta.items():
        meta[key] = float(value)

    finite = np.ones(n, dtype=bool)
    for v in cols.values():
        finite &= np.isfinite(v)
    dropped = int(n - np.count_nonzero(finite))
    if dropped:
        if dropped == n:
            raise InputError(f"no row where every mapped value is a finite number ({n} rows; missing values are "
                             "_FillValue / missing_value, NaN or inf)", Location(p), "mapping")
        first_bad = int(np.flatnonzero(~finite)[0])
        bad_cols = [c for c, v in cols.items() if not np.isfinite(v).all()]
        meta["dropped_rows"] = float(dropped)
        meta["dropped_note"] = (f"dropped {dropped} of {n} rows with a missing or non-finite value (first: row "
                                f"{first_bad}, in {', '.join(bad_cols)})")
        cols = {k: v[finite] for k, v in cols.items()}
    t = cols["time_s"]
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        rows = np.flatnonzero(finite)
        raise InputError(f"time must increase from sample to sample: row {int(rows[i])} ({float(t[i])!r} s) follows row "
                         f"{int(rows[i - 1])} ({float(t[i - 1])!r} s)", Location(p), "mapping entry 'time'")
    order = [c for c in COLUMNS if c in cols]
    return Dataset({c: np.ascontiguousarray(cols[c]) for c in order}, meta, str(p))


def load_notes(ds: Dataset) -> list[str]:
    """What the operator should know about how a mapped file was read (time source, dropped rows).
    (A run file imported from one keeps these in its metadata too.)"""
    if ds.meta.get("source_format") not in (SOURCE_FORMAT, "CSV (mapped)"):
        return []
    out = [f"{ds.source}: {len(ds)} samples; time_s from {ds.meta.get('time_source')}"]
    if "dropped_note" in ds.meta:
        out.append(f"{ds.source}: {ds.meta['dropped_note']}")
    return out


def load_data(path: str | Path, mapping: ForeignMapping | Sequence[str] | None = None) -> tuple[Dataset, list[str]]:
    """:func:`~bench.analysis.dataset.load_dataset` for the command line, and the notes on how a
    mapped file was read (:func:`load_notes`). A foreign HDF5/netCDF-4 file without a mapping is
    refused with what to pass and the file's variables."""
    from bench.analysis.dataset import load_dataset

    p = Path(path)
    if not mapping:
        if is_run_file(p) is False:
            raise foreign_file_error(p)
        ds = load_dataset(p)
        return ds, list(ds.notes)  # rows left out of a damaged run file
    ds = load_dataset(p, mapping)
    return ds, load_notes(ds)
