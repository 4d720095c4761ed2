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
from bench.sim import registry
from bench.sim.factory import TRANSPORTS, SimInstrument, build_devices, serial_url
from bench.sim.world import World
from drivers.acs_board import AcsBoard
from drivers.rate_table import RateTable
from drivers.stepper_bench import StepperBench
from drivers.thermocouple_reader import ThermocoupleReader
from drivers.tvac import TvacChamber

DRIVER_CLASSES: dict[str, Any] = {
    "acs_board": AcsBoard,
    "stepper_bench": StepperBench,
    "thermocouple_reader": ThermocoupleReader,
    "tvac": TvacChamber,
    "rate_table": RateTable,
}
"""Config ``driver`` name -> driver class (each has ``open(url, baudrate=, timeout_s=, on_traffic=, ...)``)."""

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
    """Driver-specific keyword arguments of ``open`` from the config (hardware URLs included)."""
    if inst.driver == "stepper_bench":
        return {"setup": inst.bench_setup}
    if inst.driver == "tvac":
        return {"gauge_url": inst.gauge_port, "gauge_baudrate": inst.gauge_baudrate, "safe_set_point_c": inst.safe_set_point_c}
    if inst.driver == "thermocouple_reader":
        return {"monitor_channels": inst.channels, "tc_type": inst.tc_type}
    if inst.driver == "acs_board":
        return {"compensation": inst.compensation, "description": inst.frames}
    return {}


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
        if config.instruments[name].driver == "rate_table" or config.instruments[name].port.startswith("can://") or (
                sim and config.instruments[name].sim is not None and config.instruments[name].sim.transport == "can"):
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
    lab.kinds = {name: config.instruments[name].driver for name in names}
    lab.signals = config.signals()
    lab.config_limits = config.limits()
    lab.safe_state_timeouts = {name: config.instruments[name].safe_state_timeout_s for name in names}
    try:
        for name in names:
            inst = config.instruments[name]
            hook = None
            if on_traffic is not None:
                hook = (lambda n: (lambda d, t, raw: on_traffic(n, d, t, raw)))(name)
            cls = DRIVER_CLASSES[inst.driver]
            opener = (lambda c, url, i, h, kw: (lambda: c.open(url, baudrate=i.baudrate, timeout_s=i.timeout_s, on_traffic=h, **kw)))(
                cls, ports[name], inst, hook, kwargs[name])
            lab.openers[name] = opener
            try:
                instruments[name] = opener()
            except Exception as exc:
                if sim:
                    raise
                from bench.instruments_check import diagnose_failure

                problem, hint = diagnose_failure(inst, exc)
                raise InstrumentOpenError(name, problem, hint, exc) from exc
    except Exception:
        lab.close()
        raise
    return lab
