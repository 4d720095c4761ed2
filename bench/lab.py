"""The lab a run talks to: a clock and one driver per instrument, on hardware or simulators.

``--sim`` puts the simulators named in the config behind the very same drivers: serial ones
through the ``sim://NAME`` pyserial URL handler; the chamber controller's Modbus TCP ADUs (or RTU
frames with ``sim.transport: rtu``) on an in-process stream and the CAN drives on a synchronous
in-process bus, answered in the caller's thread — or, with ``BENCH_DRYRUN_TRANSPORT=socket``, through
a real Modbus TCP server on 127.0.0.1 and a python-can virtual bus (:data:`bench.sim.factory.TRANSPORTS`;
the same bytes either way). The driver code above the transport is identical to a hardware run.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any, Callable

from bench.clock import Clock, VirtualClock, WallClock
from bench.config import InstrumentConfig, LabConfig
from bench.errors import BenchError, InputError, InputErrors
from bench.kinds import registry as kinds
from bench.sim import registry
from bench.sim.factory import TRANSPORTS, SimInstrument, build_devices, serial_url
from bench.sim.world import World


def driver_class(inst: InstrumentConfig) -> Any:
    """The driver class of ``inst``'s kind (``Kind.driver``, imported on first use; each has
    ``open(url, baudrate=, timeout_s=, on_traffic=, **open_kwargs)``)."""
    return kinds.load(inst.kind.driver)

DRYRUN_TRANSPORT_ENV = "BENCH_DRYRUN_TRANSPORT"
"""Environment variable choosing how a dry-run reaches its simulators: ``inprocess`` (default) or ``socket``."""


def dryrun_transport() -> str:
    """The dry-run transport named by :data:`DRYRUN_TRANSPORT_ENV` (default ``inprocess``);
    :class:`InputError` naming the variable for another value."""
    value = os.environ.get(DRYRUN_TRANSPORT_ENV, "").strip() or "inprocess"
    if value not in TRANSPORTS:
        raise InputError(f"{DRYRUN_TRANSPORT_ENV}={value!r} is not one of {', '.join(TRANSPORTS)}")
    return value


TrafficSink = Callable[[str, str, str, bytes], None]
"""Called with (instrument, "command" | "reply", what (frame or command name), raw bytes)."""


@dataclass
class Lab:
    clock: Clock
    mode: str  # "sim" | "hardware"
    instruments: dict[str, Any]
    ports: dict[str, str]
    sims: dict[str, SimInstrument] = field(default_factory=dict)
    poll_intervals: dict[str, float] = field(default_factory=dict)
    """Run time between readings of each polled instrument (s), from the config."""
    world: World | None = None
    """The simulated world of a dry-run (None on hardware)."""
    reconnect_timeouts: dict[str, float] = field(default_factory=dict)
    """How long a run keeps reconnecting to each instrument after a link fault (s), from the config."""
    openers: dict[str, Callable[[], Any]] = field(default_factory=dict)
    """Instrument name -> how to open its driver again (same URL and settings)."""
    kinds: dict[str, str] = field(default_factory=dict)
    """Instrument name -> driver kind (``tvac``, ``rate_table``, ...), from the config."""
    powered_by: dict[str, tuple[str, str]] = field(default_factory=dict)
    """Instrument name -> (instrument, output) that powers it, from the config (``powered_by``)."""
    powered_up: dict[str, str] = field(default_factory=dict)
    """Instrument name -> what its supply was told when the lab opened it (``power_up``)."""
    signals: dict[str, Any] = field(default_factory=dict)
    """Board name -> the signals of its frame description (:class:`bench.procedure.signals.StreamSignals`)."""
    config_limits: dict[str, dict[str, tuple]] = field(default_factory=dict)
    """This lab's hardware limits per instrument (config ``limits:``; see bench.procedure.limits)."""
    safe_state_timeouts: dict[str, float] = field(default_factory=dict)
    """Deadline of each instrument's safe state on an abort (s), from the config (``safe_state_timeout``)."""

    def reopen(self, name: str) -> Any:
        """Close instrument ``name``'s driver (errors ignored) and open it again; returns the new
        driver (raises the driver's error if the instrument still cannot be reached)."""
        try:
            self.instruments[name].close()
        except Exception:  # noqa: BLE001 - the link is already in trouble
            pass
        drv = self.openers[name]()
        self.instruments[name] = drv
        return drv

    def close(self) -> None:
        """Close every port, stop simulators and unregister them (errors ignored: this runs on the way out)."""
        for drv in self.instruments.values():
            try:
                drv.close()
            except Exception:  # noqa: BLE001 - closing must not mask the run's outcome
                pass
        for name, sim in self.sims.items():
            for sub in sim.serial:
                registry.unregister(serial_url(name, sub).removeprefix("sim://"))
            sim.close()


def driver_kwargs(inst: InstrumentConfig) -> dict[str, Any]:
    """Kind-specific keyword arguments of ``open`` from the config (hardware URLs included)."""
    return inst.open_kwargs()


def needs_clock(inst: InstrumentConfig, sim: bool) -> bool:
    """Whether ``inst``'s driver waits on the lab's clock: its kind says so, or its link is CAN (the
    port's URL, or a simulator on CAN)."""
    return inst.kind.needs_clock or inst.port.startswith("can://") or (sim and inst.sim is not None and inst.sim.transport == "can")


def power_order(config: LabConfig, names: list[str]) -> list[str]:
    """``names`` with every instrument after the one that powers it (``powered_by``), else in order."""
    out: list[str] = []

    def add(name: str, seen: tuple[str, ...] = ()) -> None:
        link = config.instruments[name].powered_by
        if link is not None and link.instrument in names and link.instrument not in seen:
            add(link.instrument, (*seen, name))
        if name not in out:
            out.append(name)

    for n in names:
        add(n)
    return out


def open_drivers(lab: "Lab", config: LabConfig, names: list[str], kwargs: dict[str, dict[str, Any]],
                 on_traffic: "TrafficSink | None", *, explain: bool = False) -> None:
    """Open the driver of each of ``names`` on ``lab.ports`` (filling ``lab.instruments`` and
    ``lab.openers``), a supply before what it powers; before a powered instrument is opened, its
    supply's output is switched on as the config sets it (``power_up``), so the unit answers when
    identified. The same for a run, a dry-run and a replay (the replay's backends answer the same
    exchanges). ``explain``: a failure is an :class:`InstrumentOpenError` naming the instrument with
    what to do (a real lab), else the driver's error as it is."""
    for name in power_order(config, names):
        inst = config.instruments[name]
        link = inst.powered_by
        if link is not None and link.instrument in lab.instruments:
            told = lab.instruments[link.instrument].power_up(link.output)
            lab.powered_up[name] = f"{link.instrument} output {link.output}: {told}"
        hook = None
        if on_traffic is not None:
            hook = (lambda n: (lambda d, t, raw: on_traffic(n, d, t, raw)))(name)
        opener = (lambda c, url, i, h, kw: (lambda: c.open(url, baudrate=i.baudrate, timeout_s=i.timeout_s, on_traffic=h, **kw)))(
            driver_class(inst), lab.ports[name], inst, hook, kwargs[name])
        lab.openers[name] = opener
        try:
            lab.instruments[name] = opener()
        except Exception as exc:
            if not explain:
                raise
            from bench.instruments_check import diagnose_failure

            problem, hint = diagnose_failure(inst, exc)
            raise InstrumentOpenError(name, problem, hint, exc) from exc


def describe_lab(lab: Lab, config: LabConfig, names: list[str]) -> None:
    """What a lab knows of its instruments from the config: kinds, signals, limits, power links."""
    lab.kinds = {name: config.instruments[name].driver for name in names}
    lab.signals = config.signals()
    lab.config_limits = config.limits()
    lab.powered_by = {name: (config.instruments[name].powered_by.instrument, config.instruments[name].powered_by.output)
                      for name in names if config.instruments[name].powered_by is not None
                      and config.instruments[name].powered_by.instrument in names}


class InstrumentOpenError(BenchError):
    """An instrument of a real lab could not be opened or identified: the message names it, says
    what was seen and what to do, as ``bench instruments check`` does (``instrument``, ``cause``)."""

    def __init__(self, instrument: str, problem: str, hint: str, cause: BaseException):
        super().__init__(f"{instrument}: {problem}" + (f" → {hint}" if hint else ""))
        self.instrument, self.problem, self.hint, self.cause = instrument, problem, hint, cause


def check_ports(config: LabConfig, names: list[str]) -> None:
    """Before a real run creates anything: every serial device and CAN interface the instruments
    ``names`` use must be there and usable (``bench instruments check``'s pre-flight). Raises
    :class:`InputErrors` located at each instrument's entry of the config, naming it, with the hint."""
    from bench.instruments_check import preflight

    errors = []
    for name in names:
        inst = config.instruments.get(name)
        if inst is None:
            continue
        seen = preflight(inst)
        if seen is not None:
            problem, hint = seen
            errors.append(InputError(f"{problem} → {hint}", inst.location, name))
    if errors:
        raise InputErrors(errors)


def open_lab(config: LabConfig, names: list[str], *, sim: bool, realtime: bool, on_traffic: TrafficSink | None = None) -> Lab:
    """Open the instruments ``names`` of ``config``.

    ``sim``: simulators behind the drivers, on a virtual clock unless ``realtime``. Raises
    :class:`InputError` for an instrument missing from the config or without a ``sim`` section,
    :class:`InstrumentOpenError` (naming the instrument, with the hint) for a real instrument that
    cannot be opened or identified.
    """
    for name in names:
        if name not in config.instruments:
            raise InputError(f"instrument {name!r} used by the procedure is not in the config (has: {', '.join(config.instruments)})", None, "instruments")
    clock: Clock = WallClock() if (realtime or not sim) else VirtualClock()
    sims: dict[str, SimInstrument] = {}
    world = World(config.world) if sim else None
    if sim:
        try:
            sims = build_devices(config, clock, names, world=world, transport=dryrun_transport())
        except ValueError as exc:
            raise InputError(str(exc)) from None
    ports: dict[str, str] = {}
    kwargs: dict[str, dict[str, Any]] = {name: driver_kwargs(config.instruments[name]) for name in names}
    for name in names:
        if needs_clock(config.instruments[name], sim):
            kwargs[name]["clock"] = clock  # waits run on the lab's clock (virtual in a dry-run)
    for name, s in sims.items():
        for sub, dev in s.serial.items():
            registry.register(serial_url(name, sub).removeprefix("sim://"), dev)
        ports[name] = s.url or serial_url(name, "")
        kwargs[name].update({kw: serial_url(name, sub) for kw, sub in s.url_kwargs.items()})
    if not sim:
        ports = {name: config.instruments[name].port for name in names}
    instruments: dict[str, Any] = {}
    lab = Lab(clock, "sim" if sim else "hardware", instruments, ports, sims,
              {name: config.instruments[name].poll_interval_s for name in names}, world,
              {name: config.instruments[name].reconnect_timeout_s for name in names})
    describe_lab(lab, config, names)
    lab.safe_state_timeouts = {name: config.instruments[name].safe_state_timeout_s for name in names}
    try:
        open_drivers(lab, config, names, kwargs, on_traffic, explain=not sim)
    except Exception:
        lab.close()
        raise
    return lab
