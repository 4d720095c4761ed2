"""Lab configuration (``bench-config/1``): instruments, their ports, simulators and the world.

Validated like procedures: every problem is a located one-line :class:`InputError`.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from datetime import date
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bench.errors import InputError, InputErrors, Location
from bench.inputs import CONFIG_ROOTS, confined_path
from bench.identity import check_identity_text, parse_iso_date
from bench.model.imu_simple import ImuModelParams
from bench.sim.world import WorldParams
from bench.units import to_units
from bench.yamlsrc import Fields, Node, load_yaml
from bench.sim.table_motion import Eccentricity
from drivers.stepper_bench import AXES as GRBL_AXES, BenchSetup

if TYPE_CHECKING:  # pragma: no cover
    from bench.procedure.signals import StreamSignals

CONFIG_SCHEMA = "bench-config/1"
SENSOR_MODEL_SCHEMA = "bench-sensor-model/1"
DRIVERS = ("acs_board", "stepper_bench", "thermocouple_reader", "tvac", "rate_table")
SIM_BACKENDS = DRIVERS
DEFAULT_BAUDRATE = {"tvac": 9600}
"""Per-driver default baud rate (bit/s) when the config gives none: Watlow F4 and TPG 261 ship at
9600 (protocols.md sections 1-2); the others default to 115200."""
DEFAULT_CAN_CHANNEL = "bench-sim"
SAFE_STATE_TIMEOUT_S = {"rate_table": 5.0, "stepper_bench": 5.0, "acs_board": 30.0, "thermocouple_reader": 30.0, "tvac": 30.0}
"""Per-driver default deadline of the safe state on an abort (s of wall time, and of run time in a
dry-run; config ``safe_state_timeout``; docs/reliability.md). Our choice [U]: the moving axes must
be confirmed at rest within a few seconds (the rate table's quick stop from 60 deg/s takes 1 s per
axis; 5 s leaves room for one reconnection of 0.5 + 1 + 2 s) or be reported for the operator's
emergency stop; the others are retried as long as a link fault during the run is by default
(``reconnect_timeout``, 30 s): the chamber's safe set point matters, and as every instrument is
told at once their deadlines delay only the closing of the run file, not the table."""
DEFAULT_SAFE_STATE_TIMEOUT_S = 30.0
"""Deadline of the safe state of an instrument whose driver has no default in :data:`SAFE_STATE_TIMEOUT_S` (s)."""
SAFE_STATE_TIMEOUT_RANGE_S = (0.1, 300.0)
"""Accepted ``safe_state_timeout`` (s): long enough for one command, short enough to be a deadline."""
SIM_TRANSPORTS = {"acs_board": ("uart", "can"), "tvac": ("tcp", "rtu")}
"""Simulated link choices (``sim.transport``) per backend, default first: the chamber controller's
Modbus runs on TCP (127.0.0.1) or RTU (a serial line: ``sim://`` or a pty, docs/tvac.md)."""


@dataclass
class SimConfig:
    backend: str
    seed: int = 0
    serial: str = "SIM-0001"
    bit_fail_mask: int = 0
    model: ImuModelParams = field(default_factory=ImuModelParams)
    sensor_spec: Any = None
    """The loaded model file when it is not ``imu_simple`` (:class:`bench.model.loader.SensorModelSpec`)."""
    model_path: str = ""
    grbl: "GrblSimConfig" = field(default_factory=lambda: GrblSimConfig())
    """stepper_bench: the simulated GRBL's EEPROM, input pins and DTR reset."""
    open_channels: list[int] = field(default_factory=list)
    modbus_port: int = 0
    """TCP port of the simulated Modbus server on 127.0.0.1 (0: any free port)."""
    scpi_port: int = 5025
    """thermocouple_reader under ``bench sim serve``: TCP port of the SCPI raw socket on 127.0.0.1
    (5025, the 34972A's LAN port; 0: any free port)."""
    can_channel: str = DEFAULT_CAN_CHANNEL
    """python-can virtual-bus channel the simulated CAN devices sit on."""
    node_id: int = 1
    """CAN node id: the rate table's rotation axis (tilt: node_id + 1), or the board's (default 16)."""
    transport: str = "uart"
    """acs_board: ``uart`` (serial) or ``can`` (byte stream in CAN frames, docs/acs-board-can.md);
    tvac: the chamber controller's Modbus, ``tcp`` (default) or ``rtu`` (serial line, docs/tvac.md)."""
    periodic_errors: list[Eccentricity] = field(default_factory=list)
    """Stepper bench / rate table: true-rate errors periodic in the angle (worm eccentricity, microstep ripple)."""


@dataclass
class GrblSimConfig:
    """The simulated bench's GRBL (bench/sim/stepper_bench.py): ``eeprom`` ``bench`` (set up as
    the bench: steps per degree, max rate deg/s, acceleration deg/s², build info) or ``blank`` (a
    freshly flashed board); ``pins`` input pins that read triggered (``PXYZRHS``: grbl-sim's);
    ``dtr_reset_s`` the board resets on open and answers this long after (None: no reset)."""

    axis: str = "X"
    steps_per_deg: float = BenchSetup.steps_per_deg
    max_rate_dps: float = BenchSetup.max_rate_dps
    acceleration_dps2: float = 10.0
    """GRBL's default $120 (defaults.h): the thesis gives no acceleration."""
    eeprom: str = "bench"
    build_info: str = ""
    """Default: ``STEPPER_BENCH:`` and the sim's serial."""
    pins: str = ""
    dtr_reset_s: float | None = None
    true_steps_per_deg: float | None = None
    """The mechanics' steps per table degree when it differs from what GRBL is told (a bench to
    calibrate); None: the same."""


@dataclass
class InstrumentConfig:
    name: str
    driver: str
    port: str
    baudrate: int = 115200
    timeout_s: float = 0.5
    sim: SimConfig | None = None
    location: Location | None = None
    bench_setup: BenchSetup = field(default_factory=BenchSetup)
    """stepper_bench: its axis in GRBL, steps per degree, top rate and acceleration."""
    gauge_port: str = ""
    """tvac: serial URL of the vacuum gauge controller (TPG 261)."""
    gauge_baudrate: int = 9600
    safe_set_point_c: float = 20.0
    """tvac: chamber set point of the safe state (°C)."""
    channels: list[int] = field(default_factory=lambda: [101, 102, 103, 104])
    """thermocouple_reader: channels scanned during a run."""
    tc_type: str = "K"
    poll_interval_s: float = 1.0
    """Run time between two readings of a polled (non-streaming) instrument (s)."""
    limits: dict[str, tuple] = field(default_factory=dict)
    """Safety limits of this lab's instrument: quantity -> (low, high); see bench.procedure.limits."""
    reconnect_timeout_s: float = 30.0
    """How long a run keeps reconnecting to this instrument after a link fault before it aborts (s)."""
    compensation: Any = None
    """acs_board: gyro compensation (NPSAT1 Eq. 2) from the ``calibration:`` files
    (:class:`bench.model.compensation.Compensation`), or None."""
    serial: str = ""
    """The instrument's serial number as the lab knows it (config ``serial:``), ``""`` if not given."""
    firmware: str = ""
    """The firmware the lab expects on it (config ``firmware:``), ``""`` if not given."""
    calibration_due: date | None = None
    """Date (UTC) its calibration is due (config ``calibration_due: YYYY-MM-DD``), None if not given."""
    calibration_due_location: Location | None = None
    """Where ``calibration_due`` is written in the config (for messages about an overdue calibration)."""
    safe_state_timeout_s: float = DEFAULT_SAFE_STATE_TIMEOUT_S
    """Deadline of this instrument's safe state on an abort (s; config ``safe_state_timeout``, default
    :data:`SAFE_STATE_TIMEOUT_S` of its driver)."""
    frames: Any = None
    """acs_board: the board's frame description (config ``frames:``,
    :class:`drivers.board_frames.FrameDescription`); None: our board's (docs/acs-board-protocol.md)."""


@dataclass
class LabConfig:
    name: str
    path: Path
    text: str
    world: WorldParams
    instruments: dict[str, InstrumentConfig]
    flush_interval_s: float = 1.0
    mode: str = "hardware"
    """``sim``: the config describes a simulated lab; commands use its simulators without ``--sim``."""
    station: str = ""
    """Name of the test station (config ``station:``); ``""``: ``bench run`` records the host name."""
    catalog: str = ""
    """Catalogue of runs this station writes to (config ``catalog:``, a URL or file, docs/catalog.md);
    ``""``: ``RUNS_DIR/catalog.sqlite``. Checked by ``bench run`` (``catalog_location`` for messages)."""
    catalog_location: Location | None = None
    sources: dict[str, str] = field(default_factory=dict)
    operators: tuple[str, ...] = ()
    """The lab's operators (config ``operators:``): when given, a run's operator must be one of them
    (``bench run --operator``, the web station's start form; :mod:`bench.operators`)."""
    operators_location: Location | None = None
    """Texts of the files the config named and :func:`load_config` read (sensor models,
    calibration files): resolved absolute path -> text (and the same text under the absolute name
    the config gives when a symbolic link made them differ). ``bench run`` keeps them in the run
    file (``config_sources`` event), so a replay loads the config with them and nothing from disk."""

    def kinds(self) -> dict[str, str]:
        """Instrument name -> driver."""
        return {n: i.driver for n, i in self.instruments.items()}

    def signals(self) -> dict[str, "StreamSignals"]:
        """Instrument name -> the signals of its data stream, for the boards (from their frame
        descriptions; ours when a board names none)."""
        from bench.procedure.signals import StreamSignals
        from drivers.frame_schema import builtin_description

        out = {}
        for n, i in self.instruments.items():
            if i.driver == "acs_board":
                d = i.frames or builtin_description()
                columns, vectors = d.signal_table()
                out[n] = StreamSignals(columns, vectors, d.ops, d.name)
        return out

    def limits(self) -> dict[str, dict[str, tuple]]:
        """Instrument name -> quantity -> (low, high) of this lab."""
        return {n: i.limits for n, i in self.instruments.items() if i.limits}


def load_config(path: str | Path, *, recorded: bool = False) -> LabConfig:
    """Read and validate a lab config; raises :class:`InputErrors` (an InputError) listing problems.

    ``recorded``: a config read back from a run file (replay): keys that earlier versions of bench
    took and that mean nothing now are ignored instead of refused (:data:`RETIRED_KEYS`)."""
    src = load_yaml(path, "config")
    errors: list[InputError] = []
    top = Fields(src.root, "config", errors)
    schema = top.get("schema", str, required=True)
    if schema is not None and schema != CONFIG_SCHEMA:
        errors.append(InputError(f"unsupported schema {schema!r}; expected {CONFIG_SCHEMA!r}", top.map["schema"].location, "schema"))
    name = top.get("name", str, default=src.path.stem)
    mode = top.get("mode", str, default="hardware")
    if mode not in ("hardware", "sim"):
        errors.append(InputError(f"expected 'hardware' or 'sim', got {mode!r}", top.map["mode"].location, "mode"))
    station = _identity_text(top, "station", errors)
    catalog = top.get("catalog", str, default="")
    operators = _operators(top.node_at("operators"), errors)
    top.used.add("operators")
    world = _world(top.node_at("world"), errors)
    instruments: dict[str, InstrumentConfig] = {}
    sources: dict[str, str] = {}
    inode = top.node_at("instruments")
    if inode is None or not isinstance(inode.value, dict) or not inode.value:
        errors.append(InputError("expected a mapping of instrument names to settings", (inode or src.root).location, "instruments"))
    else:
        for iname, node in inode.value.items():
            if not isinstance(iname, str) or not INSTRUMENT_NAME_RE.fullmatch(iname):
                errors.append(InputError(f"instrument name {str(iname)[:70]!r}: expected letters, digits, '_' or '-', at most 64 "
                                         "(it is the first part of signals such as tvac.air_c, and a run file's group name)",
                                         node.location, "instruments"))
                continue
            inst = _instrument(iname, node, src.path.parent, errors, sources, recorded)
            if inst is not None:
                instruments[iname] = inst
    flush = 1.0
    rnode = top.node_at("recorder")
    if rnode is not None:
        rf = Fields(rnode, "recorder", errors)
        fnode = rf.node_at("flush_interval")
        if fnode is not None:
            flush = _quantity(fnode, "s", "flush_interval", errors, 1.0)
            if not 0 < flush <= 1.0:
                errors.append(InputError("must be > 0 s and at most 1 s (data on disk at least once per second)", fnode.location, "flush_interval"))
        rf.check_unknown()
    top.check_unknown()
    if errors:
        raise InputErrors(errors)
    return LabConfig(name, src.path, src.text, world, instruments, flush, mode, station, catalog,
                     top.map["catalog"].location if catalog else None, sources, operators,
                     top.map["operators"].location if operators else None)


def _operators(node: Node | None, errors: list[InputError]) -> tuple[str, ...]:
    """The optional ``operators:`` list: names (printable, at most 64 characters), no duplicates."""
    if node is None:
        return ()
    if not isinstance(node.value, list) or not node.value:
        errors.append(InputError("expected a list of operator names such as [alice, bob]", node.location, "operators"))
        return ()
    names: list[str] = []
    for item in node.value:
        try:
            name = check_identity_text(item.value, item.location, "operators")
        except InputError as exc:
            errors.append(exc)
            continue
        if name.lower() in {n.lower() for n in names}:
            errors.append(InputError(f"{name!r} is listed twice", item.location, "operators"))
            continue
        names.append(name)
    return tuple(names)


INSTRUMENT_NAME_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_\-]{0,63}")
"""An instrument's name in a lab config (a subset of what replay accepts as a recorded name)."""


def _identity_text(f: Fields, key: str, errors: list[InputError]) -> str:
    """An optional identity text (station, serial, firmware): printable, at most 64 characters
    (:func:`bench.identity.check_identity_text`); ``""`` when absent or bad (the error recorded)."""
    node = f.node_at(key)
    if node is None:
        return ""
    try:
        return check_identity_text(node.value, node.location, key)
    except InputError as exc:
        errors.append(exc)
        return ""


def _quantity(node: Node, units: str, fname: str, errors: list[InputError], default: float) -> float:
    try:
        return to_units(node.value, units, node.location, fname)
    except InputError as exc:
        errors.append(exc)
        return default


def _world(node: Node | None, errors: list[InputError]) -> WorldParams:
    p = WorldParams()
    if node is None:
        return p
    f = Fields(node, "world", errors)
    if (n := f.node_at("ambient_temp")) is not None:
        p.ambient_temp_c = _quantity(n, "degC", "ambient_temp", errors, p.ambient_temp_c)
    if (n := f.node_at("latitude")) is not None:
        p.latitude_deg = _quantity(n, "deg", "latitude", errors, p.latitude_deg)
        if not -90 <= p.latitude_deg <= 90:
            errors.append(InputError("latitude must be within -90..90 deg", n.location, "latitude"))
    if (n := f.node_at("magnetic_field")) is not None:
        if not isinstance(n.value, list) or len(n.value) != 3:
            errors.append(InputError("expected three components [north, west, up] such as [23.6 uT, 0 uT, -42 uT]", n.location, "magnetic_field"))
        else:
            p.field_ut = [_quantity(c, "uT", "magnetic_field", errors, 0.0) for c in n.value]
    f.check_unknown()
    return p


RETIRED_KEYS = {"speed_calibration": "the thesis firmware's n (Eq. 3.1); the bench runs stock GRBL 1.1 now: give steps_per_deg "
                                     "(GRBL $100; 'bench calibrate-bench' fits it from rotation times)"}
"""Keys of earlier configs that mean nothing now -> why (refused in a config, ignored in a recorded one)."""


def _retired(f: Fields, errors: list[InputError], recorded: bool) -> None:
    for key, why in RETIRED_KEYS.items():
        if (n := f.node_at(key)) is not None and not recorded:
            errors.append(InputError(f"{key} is {why}", n.location, key))


def _instrument(name: str, node: Node, base: Path, errors: list[InputError], sources: dict[str, str],
                recorded: bool = False) -> InstrumentConfig | None:
    """One instrument's settings; ``sources`` receives path -> text of the files it names."""
    before = len(errors)
    f = Fields(node, f"instrument {name!r}", errors)
    driver = f.get("driver", str, required=True)
    if driver is not None and driver not in DRIVERS:
        errors.append(InputError(f"unknown driver {driver!r} (available: {', '.join(DRIVERS)})", f.map["driver"].location, "driver"))
    port = f.get("port", str, required=True)
    baud = f.get("baudrate", int, default=DEFAULT_BAUDRATE.get(driver or "", 115200))
    if baud is not None and not 300 <= baud <= 4_000_000:
        errors.append(InputError("expected a baud rate between 300 and 4000000", f.map["baudrate"].location, "baudrate"))
    timeout = 0.5
    if (n := f.node_at("timeout")) is not None:
        timeout = _quantity(n, "s", "timeout", errors, 0.5)
        if not 0 < timeout <= 60:
            errors.append(InputError("expected a timeout between 0 and 60 s", n.location, "timeout"))
    sim = None
    if (n := f.node_at("sim")) is not None:
        sim = _sim(name, n, base, errors, sources, recorded)
    if driver == "stepper_bench":
        _retired(f, errors, recorded)
    setup = _bench_setup(f, errors) if driver == "stepper_bench" else BenchSetup()
    gauge_port = f.get("gauge_port", str, default="")
    if driver == "tvac" and not gauge_port:
        errors.append(InputError("a tvac instrument needs 'gauge_port' (serial port of its vacuum gauge controller, e.g. /dev/ttyUSB1)", node.location, "gauge_port"))
    gauge_baud = f.get("gauge_baudrate", int, default=9600)
    safe_sp = 20.0
    if (n := f.node_at("safe_set_point")) is not None:
        safe_sp = _quantity(n, "degC", "safe_set_point", errors, safe_sp)
    channels = f.get("channels", list, default=[101, 102, 103, 104])
    if not channels or not all(isinstance(c, int) and not isinstance(c, bool) and 101 <= c <= 399 for c in channels):
        errors.append(InputError("expected a list of channel numbers such as [101, 102] (slot 1-3, channel 01-99)", (f.map.get("channels") or node).location, "channels"))
    tc_type = f.get("tc_type", str, default="K")
    if tc_type not in ("K", "T"):
        errors.append(InputError(f"expected thermocouple type K or T, got {tc_type!r}", f.map["tc_type"].location, "tc_type"))
    poll = 1.0
    if (n := f.node_at("poll_interval")) is not None:
        poll = _quantity(n, "s", "poll_interval", errors, poll)
        if not 0.05 <= poll <= 3600:
            errors.append(InputError("expected a poll interval between 50 ms and 1 h", n.location, "poll_interval"))
    limits = _instrument_limits(driver, f.node_at("limits"), errors)
    if driver == "tvac" and (n := f.node_at("safe_set_point")) is not None:
        _check_safe_set_point(safe_sp, limits, n, errors)
    reconnect = 30.0
    if (n := f.node_at("reconnect_timeout")) is not None:
        reconnect = _quantity(n, "s", "reconnect_timeout", errors, reconnect)
        if not 0 <= reconnect <= 3600:
            errors.append(InputError("expected a reconnect timeout between 0 s (abort at once) and 1 h", n.location, "reconnect_timeout"))
    safe_default = SAFE_STATE_TIMEOUT_S.get(driver or "", DEFAULT_SAFE_STATE_TIMEOUT_S)
    safe_timeout = safe_default
    if (n := f.node_at("safe_state_timeout")) is not None:
        safe_timeout = _quantity(n, "s", "safe_state_timeout", errors, safe_default)
        lo, hi = SAFE_STATE_TIMEOUT_RANGE_S
        if not lo <= safe_timeout <= hi:
            errors.append(InputError(f"expected a safe-state deadline between {lo:g} s and {hi:g} s "
                                     f"(the {driver} default: {safe_default:g} s)", n.location, "safe_state_timeout"))
    compensation = _compensation(driver, f.node_at("calibration"), base, errors, sources)
    frames = _frames(driver, f.node_at("frames"), base, errors, sources)
    if frames is not None or driver == "acs_board":
        _check_board(frames, f, sim, compensation, errors)
    serial = _identity_text(f, "serial", errors)
    firmware = _identity_text(f, "firmware", errors)
    due: date | None = None
    due_node = f.node_at("calibration_due")
    if due_node is not None:
        try:
            due = parse_iso_date(due_node.value, due_node.location, "calibration_due")
        except InputError as exc:
            errors.append(exc)
    f.check_unknown()
    if len(errors) > before:
        return None
    return InstrumentConfig(name, driver, port, baud, timeout, sim, node.location, setup, gauge_port, gauge_baud, safe_sp,
                            channels, tc_type, poll, limits, reconnect, compensation, serial=serial, firmware=firmware,
                            calibration_due=due, calibration_due_location=due_node.location if due_node is not None else None,
                            safe_state_timeout_s=safe_timeout, frames=frames)


def _frames(driver: str | None, node: Node | None, base: Path, errors: list[InputError], sources: dict[str, str]) -> Any:
    """``frames: FILE`` (acs_board): the board's frame description (docs/frame-descriptions.md),
    a path relative to the config's directory or in ``configs/``; its text into ``sources``. None
    when absent (our board's frames) or bad (the errors recorded, located in that file)."""
    if node is None:
        return None
    if driver != "acs_board":
        errors.append(InputError("only a sensor board (driver acs_board) takes a frame description", node.location, "frames"))
        return None
    if not isinstance(node.value, str) or not node.value:
        errors.append(InputError("expected the frame description's file, e.g. frames/xsens_mti.yaml", node.location, "frames"))
        return None
    path = _named_file(node.value, base, "frame description", node.location, "frames", errors)
    if path is None:
        return None
    from bench.board_frames import frame_description_from_source

    try:
        src = load_yaml(path, "frame description")
        sources[str(path)] = src.text  # kept in the run file: a replay reads it from there
        description = frame_description_from_source(src)
    except InputErrors as exc:
        errors.extend(exc.errors)
        return None
    except InputError as exc:
        errors.append(InputError(f"frame description {path}: {exc.message}", exc.location if exc.location and exc.location.line else node.location, "frames"))
        return None
    _keep_as_named(sources, node.value, base, path)
    return description


def _check_board(frames: Any, f: Fields, sim: "SimConfig | None", compensation: Any, errors: list[InputError]) -> None:
    """What the rest of the board's settings need from its frames: a gyro and a temperature for a
    calibration, a number for the simulated serial where the board sends its serial as one."""
    from drivers.board_frames import TYPES
    from drivers.frame_schema import builtin_description

    d = frames or builtin_description()
    if compensation is not None and (d.field("gyro") is None or d.field("temp") is None):
        errors.append(InputError(f"a calibration compensates the gyro with its temperature: frame description {d.name!r} "
                                 "has no gyro or no temp field", f.map["calibration"].location, "calibration"))
    identify = d.commands["identify"].reply
    item = next((i for i in identify.payload if i.name == "serial"), None)
    if sim is not None and item is not None:
        digits = sim.serial
        ok = all(c in "0123456789abcdefABCDEF" for c in digits) if item.format == "hex" else digits.isdigit()
        width = 2 * TYPES[item.type][1]
        if not digits or not ok or (item.format == "hex" and len(digits) > width) or (ok and item.format == "dec" and int(digits) >= 1 << (4 * width)):
            where = f.map["sim"].value.get("serial") if isinstance(f.map["sim"].value, dict) else None
            errors.append(InputError(f"frame description {d.name!r} sends the serial as a {item.type} number: expected "
                                     f"{'up to ' + str(width) + ' hex digits, e.g. 037003F8' if item.format == 'hex' else 'decimal digits'}"
                                     f", got {sim.serial!r}", (where or f.map["sim"]).location, "serial"))


def _compensation(driver: str | None, node: Node | None, base: Path, errors: list[InputError], sources: dict[str, str]) -> Any:
    """``calibration: FILE`` or ``[FILE, ...]`` (acs_board): gyro compensation terms, paths relative
    to the config's directory (bench/model/compensation.py); their texts into ``sources``."""
    if node is None:
        return None
    if driver != "acs_board":
        errors.append(InputError("only an acs_board takes calibration files (gyro compensation)", node.location, "calibration"))
        return None
    items = node.value if isinstance(node.value, list) else [node]
    if not items or not all(isinstance(n.value, str) and n.value for n in items):
        errors.append(InputError("expected a calibration file or a list of them", node.location, "calibration"))
        return None
    from bench.model.compensation import load_compensation

    paths = [_named_file(n.value, base, "calibration file", n.location, "calibration", errors) for n in items]
    if None in paths:
        return None
    try:
        comp = load_compensation(paths, sources)
    except InputErrors as exc:
        errors.extend(exc.errors)
        return None
    except InputError as exc:
        errors.append(exc if exc.location is not None else InputError(exc.message, node.location, "calibration"))
        return None
    for n, p in zip(items, paths):
        _keep_as_named(sources, n.value, base, p)
    return comp


def _check_safe_set_point(safe_c: float, limits: dict[str, tuple], node: Node, errors: list[InputError]) -> None:
    """The chamber's safe set point (degC), written on every abort, must lie within its set-point
    limits (the tvac defaults narrowed by this config's ``limits:``): an abort must not heat or
    cool the unit beyond what a procedure may ask."""
    from bench.procedure.limits import effective_limits

    lo, hi, src = effective_limits("tvac", {"set_point": limits["set_point"]} if "set_point" in limits else {})["set_point"]
    if (lo is not None and safe_c < lo) or (hi is not None and safe_c > hi):
        errors.append(InputError(f"{safe_c:g} degC is outside the chamber's set-point limits {lo:g}..{hi:g} degC ({src}): "
                                 "the safe set point is written on every abort", node.location, "safe_set_point"))


def _instrument_limits(driver: str | None, node: Node | None, errors: list[InputError]) -> dict[str, tuple]:
    """``limits: {set_point: [-40 degC, 80 degC]}``: this lab's hardware limits (bench.procedure.limits)."""
    from bench.procedure.limits import parse_limits_block

    return {} if node is None else parse_limits_block(node, driver or "", f"a {driver}", errors)


POSITIVE_RANGE = (1e-3, 1e6)
"""Accepted values of the stepper bench's quantities (steps/deg, deg/s, deg/s², s): GRBL keeps
them as floats with 3 decimals; beyond this they are typing errors."""


def _positive(f: Fields, key: str, unit: str, default: float | None, errors: list[InputError], hint: str) -> float | None:
    """``key`` as a finite quantity in ``unit`` within :data:`POSITIVE_RANGE`; ``default`` when absent."""
    n = f.node_at(key)
    if n is None:
        return default
    value = _quantity(n, unit, key, errors, default if default is not None else 1.0)
    lo, hi = POSITIVE_RANGE
    if not (math.isfinite(value) and lo <= value <= hi):
        errors.append(InputError(f"{key} must be a finite number from {lo:g} to {hi:g} {unit} ({hint})", n.location, key))
        return default
    return value


def _grbl_axis(f: Fields, errors: list[InputError]) -> str:
    axis = f.get("axis", str, default="X")
    if axis not in GRBL_AXES:
        errors.append(InputError(f"expected a GRBL axis {', '.join(GRBL_AXES)}, got {axis!r}", f.map["axis"].location, "axis"))
        return "X"
    return axis


def _bench_setup(f: Fields, errors: list[InputError]) -> BenchSetup:
    """A stepper bench's ``axis`` (X), ``steps_per_deg`` (GRBL $100), ``max_rate`` (deg/s) and
    ``acceleration`` (deg/s², checked against $120 when given)."""
    d = BenchSetup()
    return BenchSetup(_grbl_axis(f, errors),
                      _positive(f, "steps_per_deg", "1/deg", d.steps_per_deg, errors, "GRBL $100: steps per table degree"),
                      _positive(f, "max_rate", "deg/s", d.max_rate_dps, errors, "the fastest the bench is commanded"),
                      _positive(f, "acceleration", "deg/s^2", None, errors, "GRBL $120"))


def _grbl_sim(f: Fields, serial: str, errors: list[InputError]) -> GrblSimConfig:
    """The simulated GRBL of a stepper bench (:class:`GrblSimConfig`)."""
    d = GrblSimConfig()
    g = GrblSimConfig(_grbl_axis(f, errors),
                      _positive(f, "steps_per_deg", "1/deg", d.steps_per_deg, errors, "GRBL $100"),
                      _positive(f, "max_rate", "deg/s", d.max_rate_dps, errors, "GRBL $110 / 60"),
                      _positive(f, "acceleration", "deg/s^2", d.acceleration_dps2, errors, "GRBL $120"))
    g.eeprom = f.get("eeprom", str, default="bench")
    if g.eeprom not in ("bench", "blank"):
        errors.append(InputError(f"expected eeprom bench or blank, got {g.eeprom!r}", f.map["eeprom"].location, "eeprom"))
    g.build_info = f.get("build_info", str, default=f"STEPPER_BENCH:{serial}")
    g.pins = f.get("pins", str, default="")
    if g.pins is not None and not re.fullmatch(r"P?X?Y?Z?D?R?H?S?", g.pins):
        errors.append(InputError(f"expected input pins in GRBL's report order (P X Y Z D R H S), got {g.pins!r}", f.map["pins"].location, "pins"))
    g.dtr_reset_s = _positive(f, "dtr_reset", "s", None, errors, "an Uno answers about 2 s after its port opens")
    g.true_steps_per_deg = _positive(f, "true_steps_per_deg", "1/deg", None, errors, "the mechanics, when GRBL's $100 is off")
    return g


def microsteps_per_revolution(steps_per_deg: float) -> int:
    """Steps (microsteps) per stage revolution of a bench with ``steps_per_deg`` (GRBL $100)."""
    return int(round(360.0 * steps_per_deg))


def _periodic_error(node: Node, key: str, default_harmonic: int | None, errors: list[InputError]) -> Eccentricity | None:
    """``{amplitude: 0.002, harmonic: 200, phase: 0 deg}``: a fractional rate error periodic in the angle."""
    f = Fields(node, key, errors)
    amplitude = f.get("amplitude", (int, float), required=True)
    harmonic = f.get("harmonic", int, default=default_harmonic, required=default_harmonic is None)
    phase = 0.0
    if (n := f.node_at("phase")) is not None:
        phase = _quantity(n, "rad", "phase", errors, 0.0)
    f.check_unknown()
    if amplitude is None or harmonic is None:
        return None
    try:
        return Eccentricity(float(amplitude), int(harmonic), phase)
    except ValueError as exc:
        errors.append(InputError(str(exc), node.location, key))
        return None


def _sim(name: str, node: Node, base: Path, errors: list[InputError], sources: dict[str, str],
         recorded: bool = False) -> SimConfig | None:
    f = Fields(node, f"instrument {name!r} sim", errors)
    backend = f.get("backend", str, required=True)
    if backend is not None and backend not in SIM_BACKENDS:
        errors.append(InputError(f"unknown simulator backend {backend!r} (available: {', '.join(SIM_BACKENDS)})", f.map["backend"].location, "backend"))
    sim = SimConfig(backend or "")
    sim.seed = f.get("seed", int, default=0)
    if sim.seed is not None and not 0 <= sim.seed < 2**32:
        errors.append(InputError("expected a seed 0..4294967295 (the simulators' random generators take an unsigned 32-bit seed)",
                                 f.map["seed"].location, "seed"))
    sim.serial = f.get("serial", str, default=sim.serial)
    sim.bit_fail_mask = f.get("bit_fail_mask", int, default=0)
    opened = f.get("open_channels", list, default=[])
    if not all(isinstance(c, int) and not isinstance(c, bool) for c in opened):
        errors.append(InputError("expected a list of channel numbers such as [104]", f.map["open_channels"].location, "open_channels"))
    else:
        sim.open_channels = opened
    if backend == "stepper_bench":
        sim.grbl = _grbl_sim(f, sim.serial, errors)
        _retired(f, errors, recorded)
    sim.modbus_port = f.get("modbus_port", int, default=0)
    if sim.modbus_port is not None and not 0 <= sim.modbus_port <= 65535:
        errors.append(InputError("expected a TCP port 0..65535 (0: any free port)", f.map["modbus_port"].location, "modbus_port"))
    sim.scpi_port = f.get("scpi_port", int, default=5025)
    if sim.scpi_port is not None and not 0 <= sim.scpi_port <= 65535:
        errors.append(InputError("expected a TCP port 0..65535 (0: any free port)", f.map["scpi_port"].location, "scpi_port"))
    for key, default_harmonic in (("eccentricity", None), ("microstep_ripple", microsteps_per_revolution(sim.grbl.steps_per_deg))):
        if (n := f.node_at(key)) is not None:
            err = _periodic_error(n, key, default_harmonic, errors)
            if err is not None:
                sim.periodic_errors.append(err)
    sim.can_channel = f.get("can_channel", str, default=DEFAULT_CAN_CHANNEL)
    transports = SIM_TRANSPORTS.get(backend or "", SIM_TRANSPORTS["acs_board"])
    sim.transport = f.get("transport", str, default=transports[0])
    if sim.transport not in transports:
        errors.append(InputError(f"expected transport {' or '.join(transports)}, got {sim.transport!r}", f.map["transport"].location, "transport"))
    sim.node_id = f.get("node_id", int, default=16 if backend == "acs_board" else 1)
    if sim.node_id is not None and not 1 <= sim.node_id <= 126:
        errors.append(InputError("expected a CANopen node id 1..126 (the tilt axis takes the next one)", f.map["node_id"].location, "node_id"))
    model_rel = f.get("sensor_model", str)
    model_path = _named_file(model_rel, base, "sensor model", f.map["sensor_model"].location, "sensor_model", errors) \
        if model_rel is not None else None
    if model_path is not None:
        sim.model_path = str(model_path)
        model = _sensor_model(model_path, f.map["sensor_model"].location, errors, sources)
        _keep_as_named(sources, model_rel, base, model_path)
        if isinstance(model, ImuModelParams):
            sim.model = model
        else:
            sim.sensor_spec = model
    f.check_unknown()
    return sim


def _named_file(name: str, base: Path, what: str, ref: Location, key: str, errors: list[InputError]) -> Path | None:
    """A file named by the config at ``ref``: inside the config's directory tree or ``configs/``
    (bench/inputs.py); None, with a located error, when it is not."""
    try:
        return confined_path(name, base=base, roots=CONFIG_ROOTS, what=what,
                             where="the config's directory and configs/", location=ref, field=key)
    except InputError as exc:
        errors.append(InputError(f"{what} {name!r}: {exc.message}", ref, key))
        return None


def _keep_as_named(sources: dict[str, str], name: str, base: Path, path: Path) -> None:
    """Keep the text read from ``path`` (resolved) also under the name the config gives, made
    absolute from the config's resolved directory without following links, when a symbolic link
    makes the two differ (``current.yaml -> board_v3.yaml``): a replay, which holds no links, looks
    the name up there."""
    named = os.path.normpath(Path(base).resolve() / name)
    if named != str(path) and str(path) in sources:
        sources[named] = sources[str(path)]


def _other_sensor_model(path: Path, text: str, ref: Location, errors: list[InputError]) -> Any:
    """A model file other than ``imu_simple`` (bench/model/loader.py validates ``text``, read from
    ``path``); None if bad."""
    from bench.model.loader import parse_sensor_model

    try:
        spec = parse_sensor_model(text, str(path))
    except InputErrors as exc:
        errors.extend(exc.errors)
        return None
    except InputError as exc:
        errors.append(exc)
        return None
    if spec.gyro is None and spec.imu is None:
        errors.append(InputError(f"model {spec.model!r} cannot drive the ACS board (expected imu_simple or npsat1_gyro)", ref, "sensor_model"))
        return None
    return spec


def _sensor_model(path: Path, ref: Location, errors: list[InputError], sources: dict[str, str]) -> Any:
    """The sensor model file at ``path`` (read once; its text into ``sources``)."""
    try:
        src = load_yaml(path, "sensor model")
    except InputError as exc:
        errors.append(InputError(f"sensor model {path}: {exc.message}", exc.location if exc.location and exc.location.line else ref, "sensor_model"))
        return ImuModelParams()
    sources[str(path)] = src.text  # kept in the run file: a replay reads it from there
    data: dict[str, Any] = src.root.plain()
    if isinstance(data, dict) and data.get("model") not in (None, "imu_simple"):
        return _other_sensor_model(path, src.text, ref, errors)
    if data.pop("schema", None) != SENSOR_MODEL_SCHEMA:
        errors.append(InputError(f"expected schema: {SENSOR_MODEL_SCHEMA}", src.root.location, "schema"))
    if data.pop("model", None) != "imu_simple":
        errors.append(InputError("expected model: imu_simple", src.root.location, "model"))
    try:
        params = ImuModelParams.from_dict(data)
    except KeyError as exc:
        key = str(exc.args[0]).split(",")[0]
        loc = src.root.key_locations.get(key, src.root.location)
        errors.append(InputError(f"unknown sensor-model parameter(s): {exc.args[0]}", loc, key))
        return ImuModelParams()
    for key, expected_len in (("gyro_bias_dps", 3), ("warmup_amplitude_dps", 3), ("warmup_settling_s", 3), ("accel_bias_g", 3), ("mag_bias_ut", 3)):
        value = getattr(params, key)
        if not isinstance(value, list) or len(value) != expected_len or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in value):
            errors.append(InputError(f"expected a list of {expected_len} numbers", src.root.key_locations.get(key, src.root.location), key))
    for key in ("gyro_noise_density_dps_rthz", "accel_noise_density_g_rthz", "mag_noise_rms_ut", "lowpass_cutoff_hz"):
        value = getattr(params, key)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0:
            errors.append(InputError("expected a non-negative number", src.root.key_locations.get(key, src.root.location), key))
    if not isinstance(params.gyro_bias_poly_degc, list) or not all(isinstance(x, (int, float)) for x in params.gyro_bias_poly_degc):
        errors.append(InputError("expected a list of polynomial coefficients (ascending powers)", src.root.key_locations.get("gyro_bias_poly_degc", src.root.location), "gyro_bias_poly_degc"))
    return params
