"""The kind record: everything bench knows about one kind of instrument, in one place.

A *kind* is what a lab config names with ``driver:`` (``tvac``, ``rate_table``, a lab's own
``dc_supply``...). Its :class:`Kind` record holds, as data, what used to be spread over string-keyed
tables in nine core modules: the driver class, the config section with its own typed and located
validation, the simulator and its settings, the signals with their units and roles (declared once),
the default and step limits, the safe-state deadline, the ``instruments check`` reading and hints,
the replay wiring, the fault classes, the procedure steps the kind adds (fields, handler, duration
estimate), the report figures and the words messages use (docs/instruments.md).

Everything executable is a *dotted path* (``"package.module:name"``), imported only when it is
used (:func:`bench.kinds.registry.load`), as python-can's interface table holds (module, class)
pairs: reading the records imports no driver, simulator or runner, so every layer may read them
(a report finds the chamber's air temperature by role without importing the chamber's driver) and
``bench validate`` starts as fast as before. The records are :class:`~bench.kinds.frozen.Frozen`
(frozen dataclasses in all but their making: no code is generated when this module is imported);
this module imports nothing else of bench.
"""

from __future__ import annotations

from typing import Any

from bench.kinds.frozen import Frozen

# ---- the procedure schema's vocabulary (bench.procedure.schema re-exports it) --------------------


class FieldSpec(Frozen):
    """One field of a step. ``kind``: instrument | quantity | int | bool | str | signal | choice | vibration (a file)."""

    kind: str
    units: str = ""
    required: bool = True
    default: object = None
    minimum: float | None = None
    maximum: float | None = None
    exclusive_minimum: bool = False
    """The value must be above ``minimum``, not equal to it (a band of 0 could never be met)."""
    doc: str = ""
    choices: tuple[str, ...] = ()
    instrument_kinds: tuple[str, ...] = ()
    """For ``instrument`` fields: the kinds that can do this step (empty: any, unless ``streams``)."""
    streams: bool = False
    """For ``instrument`` fields: the instrument must be of a kind that streams (``Kind.streams``)."""


class StepSpec(Frozen):
    fields: dict[str, FieldSpec]
    doc: str
    scalar_field: str | None = None  # a step written as ``TYPE: value`` fills this field


WAIT_TIMEOUT = FieldSpec("quantity", "s", required=False, default=12 * 3600.0, minimum=0.0, doc="give up after this long (default 12 h)")
"""The ``timeout`` field of a step that waits for the lab."""


def instrument_field(*kinds: str) -> FieldSpec:
    """The ``instrument`` field of a step only instruments of ``kinds`` can do."""
    return FieldSpec("instrument", instrument_kinds=kinds, doc="name of an instrument in the procedure's `instruments` list"
                     + (f" (driver {' or '.join(kinds)})" if kinds else ""))


# ---- what a kind declares -------------------------------------------------------------------------


ROLES: dict[str, str] = {
    "gyro": "angular rate the unit under test measures (x, y, z)",
    "accel": "specific force the unit under test measures (x, y, z)",
    "mag": "magnetic field the unit under test measures (x, y, z)",
    "sensor_temp": "a temperature the unit under test reports of itself (its first channel: the gyro's)",
    "unit_temp": "a temperature measured on the unit under test by the lab (a thermocouple)",
    "air_temp": "the air around the unit (a chamber's)",
    "mount_temp": "the plate or fixture the unit is mounted on",
    "pressure": "the pressure around the unit",
    "table_rate": "the rate of the turntable carrying the unit about its axis: the reference rate (deg/s)",
    "table_angle": "the angle of that turntable (deg)",
    "table_tilt": "the tilt of that turntable's axis (deg)",
    "bench_angle": "the angle of a turning bench whose rate is taken from its angle (deg)",
    "supply_voltage": "the voltage a supply puts on the unit (V)",
    "supply_current": "the current the unit draws from a supply (A)",
}
"""Roles a signal can play, by which readers, analysis, report and web find it whatever the
instrument is called (docs/instruments.md, "Roles"). A kind may use others; these are the ones the
core reads."""


class Signal(Frozen):
    """One signal of a kind: column ``name`` (``ch*``: a pattern, ``ch`` and a number within
    ``numbers``), its ``units`` (pint; ``""`` dimensionless), its ``role`` (:data:`ROLES`), whether it
    is an x, y, z ``vector``, and the ``label`` a report gives it (``{column}`` is replaced by the
    column's name; for a vector of channels, ``labels`` per channel)."""

    name: str
    units: str
    role: str = ""
    vector: bool = False
    label: str = ""
    labels: tuple[str, ...] = ()
    numbers: tuple[int, int] = (0, 999)
    """The numbers a pattern's columns carry (a 34901A's channels 101..399, a supply's outputs 1..3)."""

    def matches(self, column: str) -> bool:
        """Whether ``column`` is this signal (a pattern ``ch*`` matches ``chN`` for N within :attr:`numbers`)."""
        if self.name.endswith("*"):
            stem, rest = self.name[:-1], column[len(self.name) - 1:]
            return column.startswith(stem) and rest.isdigit() and self.numbers[0] <= int(rest) <= self.numbers[1]
        return column == self.name

    @property
    def shown(self) -> str:
        """The name for people: a pattern as ``chNNN``."""
        return self.name.replace("*", "N" * len(str(self.numbers[1]))) if self.name.endswith("*") else self.name


class Limit(Frozen):
    """A quantity a kind's steps command, with its ``units`` and the ``default`` (low, high) the
    instrument class can take (None: open). ``magnitude``: how a single value is read in a
    ``limits:`` block — ``signed`` (``10 deg/s`` means -10..10), ``positive`` (0..10), or ``""``
    (a single value is refused: give [low, high])."""

    quantity: str
    units: str
    default: tuple[float | None, float | None] = (None, None)
    magnitude: str = ""
    source: str = ""
    """Where the default comes from (a document, or [U] our choice)."""


class StepDef(Frozen):
    """A procedure step a kind adds: its ``type`` name, its schema ``spec``, the ``handler``
    (``"module:function"``, called as ``handler(runner, step) -> (outcome, message)``, runner layer),
    the duration ``estimate`` (``"module:function"``, ``estimate(step, ctx) -> StepEstimate``,
    procedure layer; ``""``: it takes no time), the ``limits`` checked before a run
    (step field -> limited quantity of this kind), ``needs``: step field (``""``: the step itself)
    -> what the instrument must be able to do (``StreamSignals.commands``: a board command), and
    whether it ``moves`` the unit (the report's static test)."""

    type: str
    spec: StepSpec
    handler: str
    estimate: str = ""
    limits: tuple[tuple[str, str], ...] = ()
    needs: tuple[tuple[str, tuple[str, ...]], ...] = ()
    moves: bool = False


class SimSpec(Frozen):
    """The simulator of a kind: ``builder`` (``"module:function"``, ``builder(name, inst, ctx) ->
    SimInstrument``, sim layer), ``settings`` (``"module:function"`` reading the kind's own keys of
    a ``sim:`` section; ``""``: none), the ``transports`` ``sim.transport`` may name (default first;
    empty: no choice), and ``tcp_ports`` (``"module:function"``, ``(sim settings) -> [(port, what)]``:
    the TCP ports ``bench sim serve`` binds, checked before any server starts)."""

    builder: str
    settings: str = ""
    transports: tuple[str, ...] = ()
    tcp_ports: str = ""


LINK_WORDS = ("link", "no frames", "reconnect", "timeout", "not answer", "disconnected")
"""Words of an abort reason that a fault of an instrument's link explains (bench/faults.py)."""


class FaultDef(Frozen):
    """A fault class a kind's simulator can be made to suffer (bench/faults.py, docs/reliability.md):
    ``start`` is ``"module:function"`` building the injector (``start(target, rng, duration)``);
    ``rank`` orders the classes of every kind in one list (the draw order of a seeded soak)."""

    name: str
    severity: str
    description: str
    duration_s: tuple[float, float] | None
    explains: tuple[str, ...]
    start: str
    rank: float = 1000.0


class Envelope(Frozen):
    """An always-on safety envelope: the ``columns`` of this kind's readings must stay within its
    ``limit`` quantity's effective limits ± ``margin`` (in the limit's units), or the run aborts
    (the chamber: air and mount within its set-point limits ± 5 degC)."""

    limit: str
    columns: tuple[str, ...]
    margin: float
    units: str
    watch: str = ""
    """What is watched, for people (``air and mount temperature``); default: the columns."""


class RateSchedule(Frozen):
    """How a ``rate_steps`` block turns this kind: the step that sets a rate (``turn``, with fields
    ``instrument``, ``rate``, ``settle`` and, when ``accel`` is True, ``accel``) and the step that stops
    it (``stop`` with ``stop_fields``)."""

    turn: str
    stop: str
    stop_fields: tuple[tuple[str, Any], ...] = ()
    accel: bool = False


class Figure(Frozen):
    """A report figure of this kind's readings: ``title``, the ``signals`` plotted against run time
    (each on its own axis when their units differ) and a ``note`` under it."""

    title: str
    signals: tuple[str, ...]
    note: str = ""


class Kind(Frozen):
    """One kind of instrument (see the module docstring). Times in s, rates in bit/s."""

    name: str
    summary: str
    driver: str
    """``"module:Class"`` of the driver (a ``drivers.base.Driver`` with ``open(url, baudrate=,
    timeout_s=, on_traffic=, **open_kwargs)``)."""
    settings: str = ""
    """``"module:function"`` reading the kind's own keys of an instrument's config section
    (``settings(fields, ctx) -> object``; the object may have ``open_kwargs()``, ``ports()``,
    ``signals()``, ``describe()``); ``""``: the kind has none."""
    sim: SimSpec | None = None
    baudrate: int = 115200
    """Default baud rate of its serial link (bit/s) when the config gives none."""
    safe_state_timeout_s: float = 30.0
    safe_state_source: str = ""
    moves: bool = False
    """Whether it moves the unit: told first on an abort."""
    streams: bool = False
    """Whether the runner records a data stream of it (else its polled readings)."""
    needs_clock: bool = False
    """Whether its driver waits on the lab's clock (``clock=`` when opened; virtual in a dry-run)."""
    standard_name: str = ""
    """The instrument name the procedure library uses for it (configs/sim.yaml)."""
    noun: str = ""
    """What messages call it (``chamber``); default: the kind's name."""
    signals: tuple[Signal, ...] = ()
    limits: tuple[Limit, ...] = ()
    steps: tuple[StepDef, ...] = ()
    reading: str = ""
    """``"module:function"``: one reading that changes nothing, formatted with units (``instruments check``)."""
    timeout_note: str = ""
    """What most often makes it silent on a serial line (a hint of ``instruments check``)."""
    faults: tuple[FaultDef, ...] = ()
    serial_faults: tuple[str, ...] = ()
    """The core's fault classes of a serial link it suffers (``serial_unplug``, ``stream_stall``...)."""
    links: tuple[tuple[str, str], ...] = ()
    """Links of an instrument reached over several (name, regex of its recorded event names; the
    last is the default): the chamber's Modbus ``controller`` and serial ``gauge``. Empty: one link."""
    replay: str = ""
    """``"module:function"`` wiring its replay backends (``replay(ctx, name, inst) -> url``); ``""``:
    the recorded bytes on its one serial link."""
    envelope: Envelope | None = None
    rate_schedule: RateSchedule | None = None
    figures: tuple[Figure, ...] = ()
    usb_ids: tuple[tuple[int, str], ...] = ()
    """USB vendor id -> what such a port usually is (a comment of ``bench lab init``)."""
    config_hint: str = ""
    """One comment line for the config skeleton of ``bench lab init``."""
    example: str = ""
    """One instrument's config section of this kind, with a ``sim:`` section (YAML): the docs show it,
    the tests open every installed kind from it."""
    docs: str = ""
    package: str = ""
    """The distribution the kind comes from (filled in by discovery)."""

    @property
    def what(self) -> str:
        """How messages name it."""
        return self.noun or self.name

    def signal(self, column: str) -> Signal | None:
        """The declared signal ``column`` is (a pattern included), or None."""
        return next((s for s in self.signals if s.matches(column)), None)

    def limit(self, quantity: str) -> Limit | None:
        return next((lim for lim in self.limits if lim.quantity == quantity), None)

    def signals_with_role(self, role: str) -> tuple[Signal, ...]:
        return tuple(s for s in self.signals if s.role == role)


class Registry:
    """The installed kinds, by name, and what went wrong finding any (``problems``: entry point ->
    why it could not be loaded)."""

    __slots__ = ("kinds", "problems")

    def __init__(self, kinds: dict[str, Kind] | None = None, problems: dict[str, str] | None = None) -> None:
        self.kinds: dict[str, Kind] = {} if kinds is None else kinds
        self.problems: dict[str, str] = {} if problems is None else problems

    def __repr__(self) -> str:
        return f"Registry(kinds={self.kinds!r}, problems={self.problems!r})"
