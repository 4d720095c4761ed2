"""Lab configuration (``bench-config/1``): instruments, their ports, simulators and the world.

Validated like procedures: every problem is a located one-line :class:`InputError`.

What every instrument has (``driver``, ``port``, ``baudrate``, ``timeout``, ``poll_interval``,
``limits``, ``reconnect_timeout``, ``safe_state_timeout``, identity, ``powered_by``, and a ``sim``
section's ``backend``, ``seed``, ``serial``, ``transport``) is read here; the rest of a section
belongs to its kind, whose record names the function that reads it with the same located errors
(:class:`bench.kinds.record.Kind`, ``settings`` and ``sim.settings``; docs/instruments.md). This
module names no kind.
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
from bench.kinds import registry
from bench.kinds.record import Kind
from bench.model.eccentricity import Eccentricity
from bench.model.world import WorldParams
from bench.units import to_units
from bench.yamlsrc import Fields, Node, load_yaml

if TYPE_CHECKING:  # pragma: no cover
    from bench.procedure.signals import StreamSignals

CONFIG_SCHEMA = "bench-config/1"
DEFAULT_CAN_CHANNEL = "bench-sim"
DEFAULT_SAFE_STATE_TIMEOUT_S = 30.0
"""Deadline of the safe state of an instrument whose kind gives none (s)."""
SAFE_STATE_TIMEOUT_RANGE_S = (0.1, 300.0)
"""Accepted ``safe_state_timeout`` (s): long enough for one command, short enough to be a deadline."""
POSITIVE_RANGE = (1e-3, 1e6)
"""Accepted values of :meth:`ConfigContext.positive` quantities: beyond this they are typing errors."""


@dataclass
class SimConfig:
    """An instrument's ``sim:`` section: the simulator ``backend`` (a kind with a simulator, the
    instrument's own), its random ``seed`` and ``serial``, the simulated link ``transport`` (one of the
    kind's, ``""`` when it has no choice), and the kind's own ``settings``."""

    backend: str
    seed: int = 0
    serial: str = "SIM-0001"
    transport: str = ""
    settings: Any = None


@dataclass
class PowerLink:
    """``powered_by: {instrument: psu, output: 1}``: which output of which instrument powers this one.
    A dry-run wires the two simulators (the supply's output powers the unit's simulator); a run opens
    the supply first and switches that output on before the unit is identified (docs/instruments.md)."""

    instrument: str
    output: str
    location: Location | None = None


@dataclass
class InstrumentConfig:
    name: str
    driver: str
    port: str
    baudrate: int = 115200
    timeout_s: float = 0.5
    sim: SimConfig | None = None
    location: Location | None = None
    poll_interval_s: float = 1.0
    """Run time between two readings of a polled (non-streaming) instrument (s)."""
    limits: dict[str, tuple] = field(default_factory=dict)
    """Safety limits of this lab's instrument: quantity -> (low, high); see bench.procedure.limits."""
    reconnect_timeout_s: float = 30.0
    """How long a run keeps reconnecting to this instrument after a link fault before it aborts (s)."""
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
    its kind's ``safe_state_timeout_s``)."""
    settings: Any = None
    """The kind's own settings (what its ``settings`` reader returned), None when it has none."""
    powered_by: PowerLink | None = None

    @property
    def kind(self) -> Kind:
        """This instrument's kind record."""
        k = registry.get(self.driver)
        if k is None:  # pragma: no cover - load_config refuses unknown drivers
            raise InputError(f"instrument {self.name!r}: no installed kind {self.driver!r} (installed: {registry.known()})")
        return k

    def open_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of the driver's ``open`` from the kind's settings (hardware URLs included)."""
        fn = getattr(self.settings, "open_kwargs", None)
        return dict(fn()) if fn is not None else {}

    def ports(self) -> list[tuple[str, str]]:
        """Every link of the instrument as (config key, URL): ``port`` and what the kind adds (a
        chamber's ``gauge_port``)."""
        extra = getattr(self.settings, "ports", None)
        return [("port", self.port), *(extra() if extra is not None else [])]


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
        """Instrument name -> the signals of its data stream, for the instruments whose settings give
        their own (a board's, from its frame description; the others have their kind's)."""
        out = {}
        for n, i in self.instruments.items():
            fn = getattr(i.settings, "signals", None)
            if fn is not None:
                out[n] = fn()
        return out

    def limits(self) -> dict[str, dict[str, tuple]]:
        """Instrument name -> quantity -> (low, high) of this lab."""
        return {n: i.limits for n, i in self.instruments.items() if i.limits}


@dataclass
class ConfigContext:
    """What a kind's settings reader gets besides the :class:`Fields` of its section: the
    instrument's ``name`` and ``driver``, the config's directory ``base``, the ``errors`` to append
    to, the ``sources`` (path -> text of every file the config names), whether the config is a
    ``recorded`` one (replay), the instrument's ``sim`` section and ``limits`` once read, and
    helpers that give the same located errors everywhere."""

    name: str
    driver: str
    base: Path
    errors: list[InputError]
    sources: dict[str, str]
    recorded: bool = False
    sim: SimConfig | None = None
    limits: dict[str, tuple] = field(default_factory=dict)

    def quantity(self, node: Node, units: str, key: str, default: float) -> float:
        """``node`` as a float in ``units`` (``default`` after recording the error)."""
        try:
            return to_units(node.value, units, node.location, key)
        except InputError as exc:
            self.errors.append(exc)
            return default

    def positive(self, f: Fields, key: str, unit: str, default: float | None, hint: str) -> float | None:
        """``key`` as a finite quantity in ``unit`` within :data:`POSITIVE_RANGE`; ``default`` when absent."""
        n = f.node_at(key)
        if n is None:
            return default
        value = self.quantity(n, unit, key, default if default is not None else 1.0)
        lo, hi = POSITIVE_RANGE
        if not (math.isfinite(value) and lo <= value <= hi):
            self.errors.append(InputError(f"{key} must be a finite number from {lo:g} to {hi:g} {unit} ({hint})", n.location, key))
            return default
        return value

    def tcp_port(self, f: Fields, key: str, default: int) -> int:
        """A TCP port 0..65535 at ``key`` (0: any free port)."""
        port = f.get(key, int, default=default)
        if port is not None and not 0 <= port <= 65535:
            self.errors.append(InputError("expected a TCP port 0..65535 (0: any free port)", f.map[key].location, key))
            return default
        return default if port is None else port

    def can_node(self, f: Fields, default_node: int) -> tuple[str, int]:
        """``can_channel`` (python-can virtual channel of the simulated bus) and ``node_id`` (CANopen 1..126)."""
        channel = f.get("can_channel", str, default=DEFAULT_CAN_CHANNEL)
        node = f.get("node_id", int, default=default_node)
        if node is not None and not 1 <= node <= 126:
            self.errors.append(InputError("expected a CANopen node id 1..126 (the tilt axis takes the next one)", f.map["node_id"].location, "node_id"))
            node = default_node
        return channel or DEFAULT_CAN_CHANNEL, default_node if node is None else node

    def file(self, node: Node, what: str, key: str) -> Path | None:
        """The file a ``key: NAME`` names: inside the config's directory tree or ``configs/``
        (bench/inputs.py); None, with a located error, when it is not."""
        return named_file(node.value, self.base, what, node.location, key, self.errors)

    def keep_as_named(self, name: str, path: Path) -> None:
        """Keep the text read from ``path`` also under the name the config gives (:func:`keep_as_named`)."""
        keep_as_named(self.sources, name, self.base, path)

    def retired(self, f: Fields, keys: dict[str, str]) -> None:
        """Keys of earlier configs that mean nothing now (key -> why): refused in a config, ignored
        in a recorded one."""
        for key, why in keys.items():
            if (n := f.node_at(key)) is not None and not self.recorded:
                self.errors.append(InputError(f"{key} is {why}", n.location, key))

    def periodic_error(self, node: Node, key: str, default_harmonic: int | None) -> Eccentricity | None:
        """``{amplitude: 0.002, harmonic: 200, phase: 0 deg}``: a fractional rate error periodic in the angle."""
        f = Fields(node, key, self.errors)
        amplitude = f.get("amplitude", (int, float), required=True)
        harmonic = f.get("harmonic", int, default=default_harmonic, required=default_harmonic is None)
        phase = 0.0
        if (n := f.node_at("phase")) is not None:
            phase = self.quantity(n, "rad", "phase", 0.0)
        f.check_unknown()
        if amplitude is None or harmonic is None:
            return None
        try:
            return Eccentricity(float(amplitude), int(harmonic), phase)
        except ValueError as exc:
            self.errors.append(InputError(str(exc), node.location, key))
            return None


def load_config(path: str | Path, *, recorded: bool = False) -> LabConfig:
    """Read and validate a lab config; raises :class:`InputErrors` (an InputError) listing problems.

    ``recorded``: a config read back from a run file (replay): keys that earlier versions of bench
    took and that mean nothing now are ignored instead of refused (the kinds' retired keys)."""
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
                                         "(it is the first part of signals such as tvac.air_temp, and a run file's group name)",
                                         node.location, "instruments"))
                continue
            inst = _instrument(iname, node, src.path.parent, errors, sources, recorded)
            if inst is not None:
                instruments[iname] = inst
        _check_power_links(instruments, errors)
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


def _kind_of(f: Fields, key: str, errors: list[InputError], *, simulated: bool = False) -> Kind | None:
    """The installed kind ``f[key]`` names (a located error naming the installed ones if none)."""
    name = f.get(key, str, required=True)
    if name is None:
        return None
    kind = registry.get(name)
    if kind is None:
        what = "simulator backend" if simulated else "driver"
        errors.append(InputError(f"unknown {what} {name!r} (installed kinds: {registry.known()}; "
                                 "'bench instruments kinds' lists them with their packages)", f.map[key].location, key))
    return kind


def _instrument(name: str, node: Node, base: Path, errors: list[InputError], sources: dict[str, str],
                recorded: bool = False) -> InstrumentConfig | None:
    """One instrument's settings; ``sources`` receives path -> text of the files it names."""
    before = len(errors)
    f = Fields(node, f"instrument {name!r}", errors)
    kind = _kind_of(f, "driver", errors)
    port = f.get("port", str, required=True)
    baud = f.get("baudrate", int, default=kind.baudrate if kind is not None else 115200)
    if baud is not None and not 300 <= baud <= 4_000_000:
        errors.append(InputError("expected a baud rate between 300 and 4000000", f.map["baudrate"].location, "baudrate"))
    timeout = 0.5
    if (n := f.node_at("timeout")) is not None:
        timeout = _quantity(n, "s", "timeout", errors, 0.5)
        if not 0 < timeout <= 60:
            errors.append(InputError("expected a timeout between 0 and 60 s", n.location, "timeout"))
    ctx = ConfigContext(name, kind.name if kind is not None else "", base, errors, sources, recorded)
    if (n := f.node_at("sim")) is not None:
        ctx.sim = _sim(name, kind, n, ctx)
    poll = 1.0
    if (n := f.node_at("poll_interval")) is not None:
        poll = _quantity(n, "s", "poll_interval", errors, poll)
        if not 0.05 <= poll <= 3600:
            errors.append(InputError("expected a poll interval between 50 ms and 1 h", n.location, "poll_interval"))
    ctx.limits = _instrument_limits(kind, f.node_at("limits"), errors)
    reconnect = 30.0
    if (n := f.node_at("reconnect_timeout")) is not None:
        reconnect = _quantity(n, "s", "reconnect_timeout", errors, reconnect)
        if not 0 <= reconnect <= 3600:
            errors.append(InputError("expected a reconnect timeout between 0 s (abort at once) and 1 h", n.location, "reconnect_timeout"))
    safe_default = kind.safe_state_timeout_s if kind is not None else DEFAULT_SAFE_STATE_TIMEOUT_S
    safe_timeout = safe_default
    if (n := f.node_at("safe_state_timeout")) is not None:
        safe_timeout = _quantity(n, "s", "safe_state_timeout", errors, safe_default)
        lo, hi = SAFE_STATE_TIMEOUT_RANGE_S
        if not lo <= safe_timeout <= hi:
            errors.append(InputError(f"expected a safe-state deadline between {lo:g} s and {hi:g} s "
                                     f"(the {ctx.driver} default: {safe_default:g} s)", n.location, "safe_state_timeout"))
    settings = registry.load(kind.settings)(f, ctx) if kind is not None and kind.settings else None
    serial = _identity_text(f, "serial", errors)
    firmware = _identity_text(f, "firmware", errors)
    due: date | None = None
    due_node = f.node_at("calibration_due")
    if due_node is not None:
        try:
            due = parse_iso_date(due_node.value, due_node.location, "calibration_due")
        except InputError as exc:
            errors.append(exc)
    power = _power_link(f.node_at("powered_by"), errors)
    f.check_unknown()
    if len(errors) > before or kind is None:
        return None
    return InstrumentConfig(name, kind.name, port, baud, timeout, ctx.sim, node.location, poll, ctx.limits, reconnect,
                            serial=serial, firmware=firmware, calibration_due=due,
                            calibration_due_location=due_node.location if due_node is not None else None,
                            safe_state_timeout_s=safe_timeout, settings=settings, powered_by=power)


def _sim(name: str, kind: Kind | None, node: Node, ctx: ConfigContext) -> SimConfig | None:
    """An instrument's ``sim:`` section: the common keys here, the rest by the kind's sim settings."""
    errors = ctx.errors
    f = Fields(node, f"instrument {name!r} sim", errors)
    backend = _kind_of(f, "backend", errors, simulated=True)
    if backend is not None and kind is not None and backend.name != kind.name:
        errors.append(InputError(f"the {kind.name} instrument's simulator is its kind's: backend {kind.name} "
                                 f"(a {backend.name} simulator cannot answer a {kind.name} driver)", f.map["backend"].location, "backend"))
    elif backend is not None and backend.sim is None:
        errors.append(InputError(f"kind {backend.name} ({backend.package}) has no simulator", f.map["backend"].location, "backend"))
    sim = SimConfig(backend.name if backend is not None else "")
    sim.seed = f.get("seed", int, default=0)
    if sim.seed is not None and not 0 <= sim.seed < 2**32:
        errors.append(InputError("expected a seed 0..4294967295 (the simulators' random generators take an unsigned 32-bit seed)",
                                 f.map["seed"].location, "seed"))
    sim.serial = f.get("serial", str, default=sim.serial)
    spec = backend.sim if backend is not None else None
    if spec is not None and spec.transports:
        sim.transport = f.get("transport", str, default=spec.transports[0])
        if sim.transport not in spec.transports:
            errors.append(InputError(f"expected transport {' or '.join(spec.transports)}, got {sim.transport!r}",
                                     f.map["transport"].location, "transport"))
    ctx.sim = sim  # the kind's reader sees the common keys (a board checks the serial against its frames)
    if spec is not None and spec.settings:
        sim.settings = registry.load(spec.settings)(f, ctx)
    if spec is not None:
        f.check_unknown()
    return sim


def _power_link(node: Node | None, errors: list[InputError]) -> PowerLink | None:
    """``powered_by: {instrument: NAME, output: N}`` (``output`` default 1)."""
    if node is None:
        return None
    f = Fields(node, "powered_by", errors)
    inst = f.get("instrument", str, required=True)
    output = f.get("output", (int, str), default=1)
    f.check_unknown()
    if inst is None:
        return None
    return PowerLink(inst, str(output), node.location)


def _check_power_links(instruments: dict[str, InstrumentConfig], errors: list[InputError]) -> None:
    """Every ``powered_by`` names another instrument of the config, whose kind powers others."""
    for name, inst in instruments.items():
        link = inst.powered_by
        if link is None:
            continue
        supplier = instruments.get(link.instrument)
        if supplier is None or link.instrument == name:
            errors.append(InputError(f"powered_by: {link.instrument!r} is not another instrument of this config "
                                     f"(has: {', '.join(n for n in instruments if n != name) or 'none'})", link.location, "powered_by"))
            continue
        outputs = getattr(supplier.settings, "outputs", None)
        if not isinstance(outputs, dict):
            errors.append(InputError(f"powered_by: {link.instrument!r} is a {supplier.driver}, which powers nothing "
                                     "(its kind's settings declare no outputs)", link.location, "powered_by"))
        elif link.output not in outputs:
            errors.append(InputError(f"powered_by: {link.instrument!r} has no output {link.output!r} "
                                     f"(its outputs: {', '.join(outputs)})", link.location, "powered_by"))


def _instrument_limits(kind: Kind | None, node: Node | None, errors: list[InputError]) -> dict[str, tuple]:
    """``limits: {set_point: [-40 degC, 80 degC]}``: this lab's hardware limits (bench.procedure.limits)."""
    from bench.procedure.limits import parse_limits_block

    if node is None or kind is None:
        return {}
    return parse_limits_block(node, kind.name, f"a {kind.name}", errors)


def named_file(name: str, base: Path, what: str, ref: Location, key: str, errors: list[InputError]) -> Path | None:
    """A file named by the config at ``ref``: inside the config's directory tree or ``configs/``
    (bench/inputs.py); None, with a located error, when it is not."""
    try:
        return confined_path(name, base=base, roots=CONFIG_ROOTS, what=what,
                             where="the config's directory and configs/", location=ref, field=key)
    except InputError as exc:
        errors.append(InputError(f"{what} {name!r}: {exc.message}", ref, key))
        return None


def keep_as_named(sources: dict[str, str], name: str, base: Path, path: Path) -> None:
    """Keep the text read from ``path`` (resolved) also under the name the config gives, made
    absolute from the config's resolved directory without following links, when a symbolic link
    makes the two differ (``current.yaml -> board_v3.yaml``): a replay, which holds no links, looks
    the name up there."""
    named = os.path.normpath(Path(base).resolve() / name)
    if named != str(path) and str(path) in sources:
        sources[named] = sources[str(path)]
