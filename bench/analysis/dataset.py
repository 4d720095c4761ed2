"""Measured data for the analysis commands: one table of named columns with units in the names.

Every analysis (``bench calibrate``, ``bench diagnose``, ``bench report``) takes a :class:`Dataset`,
loaded by :func:`load_dataset` from either

* a measured-data CSV (``docs/analysis.md``): optional leading ``# key: value`` lines (metadata such
  as ``sample_rate_hz``, ``latitude_deg``), one header row, numeric rows; known columns are
  :data:`COLUMNS` (``tilt_deg`` among them); ``time_s`` and at least one gyro column are required,
  extra columns are ignored; a CSV whose columns have other names is read through a mapping
  (``--map``, ``bench/analysis/foreign.py``);
  or
* a bench run file (``.h5``): the ACS board stream gives time, gyro, accelerometer and temperature;
  the rate-table, chamber and thermocouple monitors are interpolated onto the board's sample times;
  or
* another program's HDF5/netCDF-4 file with a column mapping (``--map``; ``bench/analysis/foreign.py``).

Units are those in the column names: s, deg/s, deg, °C, Torr, g.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.csvsrc import read_numeric_table
from bench.errors import InputError, Location
from bench.inputs import read_head

COLUMNS: dict[str, str] = {
    "time_s": "sample time (s)",
    "power_on_s": "time since the sensor was powered on (s)",
    "ref_rate_x_dps": "reference (true) rate about sensor x (deg/s)",
    "ref_rate_y_dps": "reference (true) rate about sensor y (deg/s)",
    "ref_rate_z_dps": "reference (true) rate about sensor z (deg/s)",
    "table_angle_deg": "rate-table (or bench) angle (deg)",
    "tilt_deg": "rate-table tilt: angle of the platter normal from the vertical (deg)",
    "temp_c": "sensor temperature channel (°C)",
    "chamber_temp_c": "chamber temperature (°C)",
    "pressure_torr": "chamber pressure (Torr)",
    "accel_x_g": "specific force along sensor x (g)",
    "accel_y_g": "specific force along sensor y (g)",
    "accel_z_g": "specific force along sensor z (g)",
    "gyro_x_dps": "gyro output x (deg/s)",
    "gyro_y_dps": "gyro output y (deg/s)",
    "gyro_z_dps": "gyro output z (deg/s)",
}
"""The measured-data columns the analysis knows, with their meaning and units."""

AXES = ("x", "y", "z")
GYRO = {a: f"gyro_{a}_dps" for a in AXES}
REF_RATE = {a: f"ref_rate_{a}_dps" for a in AXES}
ACCEL = {a: f"accel_{a}_g" for a in AXES}


@dataclass
class Dataset:
    """Named float columns of equal length (units in the names), ``time_s`` strictly increasing.

    ``meta`` holds the CSV's ``# key: value`` lines (numbers converted to float) or the run file's
    attributes; ``source`` names where the data came from (for messages and reports);
    ``line_numbers`` the 1-based CSV line of each row (``None`` for run files); ``notes`` what the
    operator must know about rows left out while reading (a run file's damaged chunks, each
    ``excluded rows 4096–8191 of stream acs_board (t 40.96–81.91 s): checksum failed (gyro)``).
    """

    columns: dict[str, np.ndarray]
    meta: dict[str, float | str] = field(default_factory=dict)
    source: str = ""
    line_numbers: np.ndarray | None = None
    notes: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return int(self.columns["time_s"].shape[0])

    def __contains__(self, name: str) -> bool:
        return name in self.columns

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.columns[name]
        except KeyError:
            raise InputError(f"{self.source}: the analysis needs column {name!r} "
                             f"(present: {', '.join(self.columns)})") from None

    @property
    def gyro_axes(self) -> list[str]:
        """Axes ('x', 'y', 'z') with a gyro column."""
        return [a for a in AXES if GYRO[a] in self.columns]

    @property
    def sample_rate_hz(self) -> float:
        """``sample_rate_hz`` from the metadata, else 1 / median sample interval (Hz)."""
        if isinstance(self.meta.get("sample_rate_hz"), float):
            return float(self.meta["sample_rate_hz"])
        t = self.columns["time_s"]
        return 1.0 / float(np.median(np.diff(t))) if t.shape[0] > 1 else float("nan")

    def latitude_deg(self, default: float | None = None) -> float | None:
        """``latitude_deg`` from the metadata (deg), else ``default``."""
        v = self.meta.get("latitude_deg")
        return float(v) if isinstance(v, float) else default

    def select(self, mask: np.ndarray) -> "Dataset":
        """The rows where ``mask`` is true (a boolean array or index array)."""
        lines = None if self.line_numbers is None else self.line_numbers[mask]
        return Dataset({k: v[mask] for k, v in self.columns.items()}, dict(self.meta), self.source, lines, list(self.notes))


MAX_ABS_VALUE = 1e9
"""Largest magnitude of a measured value (deg/s, deg, °C, Torr, g) the analyses take: no sensor,
table or chamber reading comes near it, and squares and polynomial products of larger values
(1e300) overflow float64 in the fits."""


def _where(ds: Dataset, name: str, row: int | None = None) -> Location:
    """The location of column ``name`` (at ``row``: its CSV line when known) in ``ds``."""
    line = None if row is None or ds.line_numbers is None else int(ds.line_numbers[row])
    return Location(ds.source or "dataset", line)


def check_magnitudes(ds: Dataset) -> None:
    """Refuse a measured value beyond :data:`MAX_ABS_VALUE` (times excepted): :class:`InputError`
    at the first such row (its CSV line when known) and column."""
    for name, v in ds.columns.items():
        if name in ("time_s", "power_on_s"):
            continue
        a = np.asarray(v, dtype=float)
        big = np.isfinite(a) & (np.abs(a) > MAX_ABS_VALUE)
        if big.any():
            i = int(np.argmax(big))
            raise InputError(f"value {float(a[i]):g} is beyond ±{MAX_ABS_VALUE:g}: not a measurement "
                             f"({int(big.sum())} such row(s))", _where(ds, name, i), name)


def constant_columns(ds: Dataset, names: list[str]) -> list[str]:
    """The columns of ``names`` whose finite values are all one value (or that have none)."""
    out = []
    for name in names:
        a = np.asarray(ds.columns[name], dtype=float)
        a = a[np.isfinite(a)]
        if a.size == 0 or float(np.ptp(a)) == 0.0:
            out.append(name)
    return out


def constant_text(ds: Dataset, name: str) -> str:
    """``"gyro_x_dps is constant (0 in all 400 rows)"``."""
    a = np.asarray(ds.columns[name], dtype=float)
    a = a[np.isfinite(a)]
    if a.size == 0:
        return f"{name} has no finite value"
    return f"{name} is constant ({float(a[0]):g} in all {a.size} rows)"


def refuse_nothing_to_fit(ds: Dataset, names: list[str], what: str) -> None:
    """:class:`InputError` ``nothing to fit: ...`` when every column of ``names`` is constant
    (all-zero, a single sample, a dead channel): ``what`` says what the analysis needs."""
    if names and len(constant_columns(ds, names)) == len(names):
        raise InputError(f"nothing to fit: {'; '.join(constant_text(ds, n) for n in names)}; {what}",
                         _where(ds, names[0]), names[0])


def load_dataset(path: str | Path, mapping=None) -> Dataset:
    """A run file (``.h5``/``.hdf5``, or any file starting with the HDF5 signature) or a measured-data
    CSV as a :class:`Dataset`. Bad files raise :class:`InputError` with file:line and the reason.

    With ``mapping`` (the ``--map`` values, or a :class:`bench.analysis.foreign.ForeignMapping`) the
    file is another program's HDF5/netCDF-4 file read through that mapping (``bench/analysis/foreign.py``)."""
    p = Path(path)
    if not p.exists():
        raise InputError("data file not found", Location(p))
    read_head(p, 0)  # a FIFO or device is refused here, before any reader could block on it
    if mapping is not None:
        from bench.analysis.foreign import dataset_from_foreign

        return dataset_from_foreign(p, mapping)
    if p.suffix.lower() in (".h5", ".hdf5") or is_hdf5(p):
        return dataset_from_run(p)
    return dataset_from_csv(p)


HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
"""The first 8 bytes of every HDF5 (and netCDF-4) file."""


def is_hdf5(p: Path) -> bool:
    """Whether ``p`` starts with the HDF5 signature (False when it cannot be read or is not a
    regular file: a FIFO is never opened for reading, which would block)."""
    try:
        return read_head(p, len(HDF5_SIGNATURE)) == HDF5_SIGNATURE
    except InputError:
        return False


# ---- CSV ----------------------------------------------------------------------------------------
def dataset_from_csv(path: str | Path) -> Dataset:
    """Load a measured-data CSV (see module docstring); :class:`InputError` names file:line and column.
    Read block by block into float arrays (:func:`bench.csvsrc.read_numeric_table`)."""
    problem: list[InputError] = []

    def wanted(header: list[str]) -> list[str]:
        present = [c for c in COLUMNS if c in header]
        if "time_s" not in present:
            problem.append(InputError(f"missing required column (header has: {', '.join(header) or 'nothing'})",
                                      None, "time_s"))
        elif not any(GYRO[a] in present for a in AXES):
            problem.append(InputError("expected at least one gyro column (gyro_x_dps, gyro_y_dps or gyro_z_dps)", None))
        return present if not problem else []

    table = read_numeric_table(path, wanted)
    where = Location(table.path, table.header_line)
    if problem:
        raise InputError(problem[0].message, where, problem[0].field)
    if not table.rows:
        raise InputError("no data rows after the header", where)
    values = table.columns
    t = values["time_s"]
    bad = np.nonzero(np.diff(t) <= 0)[0]
    if bad.size:
        i = int(bad[0]) + 1
        raise InputError(f"time must increase from row to row: {float(t[i])!r} s follows {float(t[i - 1])!r} s",
                         Location(table.path, int(table.lines[i])), "time_s")
    return Dataset(values, csv_meta(table), str(table.path), np.asarray(table.lines, dtype=np.int64))


def csv_meta(table) -> dict[str, float | str]:
    """A CSV's ``# key: value`` lines: numbers as floats, the rest as text; the numbers the analyses
    use (:data:`META_RANGES`) checked, an :class:`InputError` at the line of a bad one."""
    meta: dict[str, float | str] = {}
    for key, text in table.meta.items():
        try:
            num = float(text)
            meta[key] = num if math.isfinite(num) else text
        except ValueError:
            meta[key] = text
        if key in META_RANGES:
            _check_meta(key, meta[key], Location(table.path, table.meta_lines.get(key)))
    return meta


META_RANGES: dict[str, tuple[float, float, bool, str]] = {
    "sample_rate_hz": (0.0, 1e7, False, "Hz"),
    "latitude_deg": (-90.0, 90.0, True, "deg"),
    "tilt_deg": (-360.0, 360.0, True, "deg"),
}
"""Metadata the analyses use as numbers: (low, high, low included, units). Anything else is kept as text."""


def _check_meta(key: str, value: float | str, where: Location) -> None:
    """A metadata number the analyses rely on, within its range; :class:`InputError` at its line."""
    low, high, low_included, units = META_RANGES[key]
    if not isinstance(value, float):
        raise InputError(f"expected a number in {units}, got {value!r}", where, key)
    if not (low <= value if low_included else low < value) or value > high:
        raise InputError(f"{value:g} {units} is outside the allowed range {low:g}..{high:g} {units}", where, key)


# ---- run files ----------------------------------------------------------------------------------
_MOUNT_PROMPT = re.compile(r"Mount the unit with its ([+-]?[xyz]) axis along the table")


def dataset_from_run(path: str | Path) -> Dataset:
    """The ACS board stream of a run file with the other instruments' monitors interpolated onto it.

    Columns: ``time_s`` (run time), ``gyro_*_dps``, ``accel_*_g``, ``temp_c`` (the board's first
    temperature channel, the gyro's), ``power_on_s`` (since the first board sample), and when
    recorded: ``ref_rate_*_dps`` (rate-table rate about the platter normal turned into the sensor
    frame by the unit's mount, taken from the run's mount prompts; +z up when none),
    ``table_angle_deg``, ``chamber_temp_c`` (chamber air), ``pressure_torr`` (log-interpolated).

    Rows of damaged chunks (a Fletcher-32 checksum that fails, a chunk zeroed on disk) are left out,
    and so are the board rows inside a gap a damaged monitor chunk leaves; each is said in
    :attr:`Dataset.notes`.
    """
    from bench.record.layout import IMPORTED_STREAM, monitor_key
    from bench.record.reader import read_run_summary, read_stream_checked
    from bench.model.geometry import mount_matrix

    p = Path(path)
    # only the events read below (operator prompts, import notes): a long run logs every command
    summary = read_run_summary(p, event_kinds=("operator", "note"))
    streams = {s.key for s in summary.streams}
    notes: list[str] = list(summary.warnings)  # a truncated file, damaged event chunks
    if IMPORTED_STREAM in streams:
        imported = read_stream_checked(p, IMPORTED_STREAM)
        ds = _dataset_from_import(p, summary, imported.data)
        ds.notes = notes + [e.describe() for e in imported.excluded]
        return ds
    if "acs_board" not in streams:
        raise InputError(f"{p}: no ACS board stream in this run (streams: {', '.join(sorted(streams)) or 'none'}); "
                         "the analysis needs the sensor outputs")
    read = read_stream_checked(p, "acs_board", ("gyro", "accel", "temp"))
    board = read.data
    notes += [e.describe() for e in read.excluded]
    t = _column(p, board, "acs_board", "time")
    # keep the rows whose time is finite and later than every row kept before it (a repeated or
    # backward time, or NaN from a damaged file, would break "time_s strictly increasing")
    finite = np.isfinite(t)
    latest = np.maximum.accumulate(np.where(finite, t, -np.inf))
    keep = finite & (t > np.concatenate([[-np.inf], latest[:-1]]))
    if not keep.all():
        notes.append(f"left out {int(np.count_nonzero(~keep)):,} rows of stream acs_board whose run time is not finite "
                     "or does not increase")
    table_monitor, chamber_monitor = monitor_key("rate_table"), monitor_key("tvac")
    monitors = {key: _read_monitor(p, key, cols, notes) for key, cols in ((table_monitor, ("rate", "angle")),
                                                                         (chamber_monitor, ("air_temp", "pressure")))
                if key in streams and t.size}
    for key, (_mon, gaps) in monitors.items():
        for e in gaps:  # the monitor's values would be interpolated across the gap: leave those board rows out
            lo = -np.inf if e.t_before_s is None else e.t_before_s
            hi = np.inf if e.t_after_s is None else e.t_after_s
            inside = (t > lo) & (t < hi) & keep
            if inside.any():
                keep &= ~inside
                notes.append(f"left out {int(np.count_nonzero(inside)):,} rows of stream acs_board "
                             f"(t {float(t[inside][0]):.2f}–{float(t[inside][-1]):.2f} s) inside that gap of stream {key}")
    if keep.all():
        keep = slice(None)  # views, not copies, of a clean recording's columns
    t = t[keep]
    cols: dict[str, np.ndarray] = {"time_s": t}
    gyro = _column(p, board, "acs_board", "gyro", 3)[keep]
    accel = _column(p, board, "acs_board", "accel", 3)[keep]
    for k, a in enumerate(AXES):
        cols[GYRO[a]] = gyro[:, k]
        cols[ACCEL[a]] = accel[:, k]
    temp = _column(p, board, "acs_board", "temp", None if np.ndim(board.get("temp")) == 1 else 1)[keep]
    cols["temp_c"] = temp if temp.ndim == 1 else temp[:, 0]  # the gyro's: the first temperature a board sends
    cols["power_on_s"] = t - (t[0] if t.size else 0.0)

    if table_monitor in monitors:
        mon = monitors[table_monitor][0]
        tm = _column(p, mon, table_monitor, "time")
        rate = _interp(t, tm, _column(p, mon, table_monitor, "rate"))
        ups = [(e.t_s, m.group(1)) for e in summary.events if (m := _MOUNT_PROMPT.search(e.message))]
        ref = np.zeros((t.size, 3))
        for i, (t0, up) in enumerate(ups or [(-math.inf, "z")]):
            t1 = ups[i + 1][0] if i + 1 < len(ups) else math.inf
            sel = (t >= t0) & (t < t1) if ups else np.ones(t.size, bool)
            ref[sel] = np.outer(rate[sel], mount_matrix(up)[:, 2])
        for k, a in enumerate(AXES):
            cols[REF_RATE[a]] = ref[:, k]
        # unwrapped before interpolating: a sample between 359.9 and 0.1 deg is near 0, not 180
        angle = np.degrees(np.unwrap(np.radians(_column(p, mon, table_monitor, "angle"))))
        cols["table_angle_deg"] = _interp(t, tm, angle) % 360.0
    if chamber_monitor in monitors:
        mon = monitors[chamber_monitor][0]
        tm = _column(p, mon, chamber_monitor, "time")
        cols["chamber_temp_c"] = _interp(t, tm, _column(p, mon, chamber_monitor, "air_temp"))
        pressure = np.clip(_column(p, mon, chamber_monitor, "pressure"), 1e-12, None)
        cols["pressure_torr"] = np.exp(_interp(t, tm, np.log(pressure)))
    meta: dict[str, float | str] = {k: v for k, v in summary.attrs.items() if isinstance(v, str)}
    lat = _latitude_from_config(summary.config_text)
    if lat is not None:
        meta["latitude_deg"] = lat
    return Dataset(cols, meta, str(p), notes=notes)


def _read_monitor(p: Path, key: str, columns: tuple[str, ...], notes: list[str]):
    """``(rows, excluded)`` of monitor stream ``key`` (only ``columns``): its good rows, and the
    ranges of damaged chunks left out, each said in ``notes``."""
    from bench.record.reader import read_stream_checked

    read = read_stream_checked(p, key, columns)
    notes += [e.describe() for e in read.excluded]
    return read.data, read.excluded


def _dataset_from_import(p: Path, summary, stream: dict[str, np.ndarray]) -> Dataset:
    """A run file written by ``bench import``: the CSV's columns and metadata as they were."""
    import json

    cols = {"time_s": np.asarray(stream["time"], dtype=float)}
    cols.update({k: np.asarray(v, dtype=float) for k, v in stream.items() if k in COLUMNS and k != "time_s"})
    meta: dict[str, float | str] = {}
    for e in summary.events:
        if e.kind == "note" and e.source == "import":
            try:
                meta = {k: v for k, v in json.loads(e.message).get("meta", {}).items() if isinstance(v, (float, int, str))}
            except (ValueError, AttributeError):
                meta = {}
    meta = {k: float(v) if isinstance(v, int) else v for k, v in meta.items()}
    return Dataset(cols, meta, str(p))


def _column(p: Path, stream: dict[str, np.ndarray], key: str, name: str, width: int | None = None) -> np.ndarray:
    """Column ``name`` of stream ``key`` as floats: one value per row, or ``width`` or more per row
    (axes, channels). A damaged or foreign file that does not have it is an :class:`InputError`."""
    if name not in stream:
        raise InputError(f"{p}: stream {key!r} has no column {name!r} (columns: {', '.join(stream)}); "
                         "the analysis needs it")
    try:
        a = np.asarray(stream[name], dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{p}: column {name!r} of stream {key!r} is not numeric ({stream[name].dtype})") from None
    if (a.ndim != 1) if width is None else (a.ndim != 2 or a.shape[1] < width):
        expected = "one value per row" if width is None else f"{width} values per row"
        raise InputError(f"{p}: column {name!r} of stream {key!r} has shape {a.shape}, expected {expected}")
    return a


def _interp(t: np.ndarray, tm: np.ndarray, v: np.ndarray) -> np.ndarray:
    if tm.size == 0:
        return np.full(t.shape, np.nan)
    return np.interp(t, tm, v)


def _latitude_from_config(text: str | None) -> float | None:
    if not text:
        return None
    import yaml

    try:
        data = yaml.safe_load(text)
        lat = (data.get("world") or {}).get("latitude")
    except Exception:  # noqa: BLE001 - a config text we cannot read (damaged file) only means no latitude
        return None
    if lat is None:
        return None
    from bench.units import to_units

    try:
        return float(to_units(lat, "deg")) if isinstance(lat, str) else float(lat)
    except Exception:  # noqa: BLE001 - a latitude we cannot parse is simply unknown
        return None
