"""The replay lab: the real driver classes on their usual kinds of transport, with replay backends
at the far end of every link, on one virtual clock.

When the recording lacks the traffic of opening the instruments (files written before the
``lab_open`` marker existed), the simulators of the stored config answer that prelude; the
backends go live (answer from the recording) once every driver is open.

The transports are the dry-run's (``BENCH_DRYRUN_TRANSPORT``, :func:`bench.lab.dryrun_transport`):
in-process by default (the controller's ADUs on a ``sim://`` stream, the drives' frames on a
synchronous in-process CAN bus, all answered in the caller's thread), or a Modbus TCP server and a
python-can virtual bus with ``socket``. The recorded bytes are the same on both.
"""

from __future__ import annotations

import itertools
import os
from dataclasses import dataclass, field
from typing import Any, Callable

from bench.clock import VirtualClock
from bench.config import InstrumentConfig, LabConfig
from bench.errors import InputError
from bench.lab import DRIVER_CLASSES, Lab, driver_kwargs, dryrun_transport
from bench.replay.backends import (AcsBoardReplay, Backend, CanReplayNode, ModbusReplayServer, ModbusRtuReplay, ModbusTcpReplay,
                                   ReplaySerial)
from bench.replay.recording import Recording
from bench.sim import registry
from bench.sim.factory import SimInstrument, build_devices
from bench.sim.world import World
from drivers.can_transport import parse_can_url

_ids = itertools.count()

SUPPORTED = ("acs_board", "stepper_bench", "thermocouple_reader", "tvac", "rate_table")


@dataclass
class ReplayLab:
    lab: Lab
    backends: dict[tuple[str, str], Backend]
    registered: list[str] = field(default_factory=list)
    prelude_sims: dict[str, SimInstrument] = field(default_factory=dict)

    def go_live(self) -> None:
        for sim in self.prelude_sims.values():
            sim.close()  # the CAN simulators leave the bus before the replay node joins it
        for b in self.backends.values():
            b.go_live()

    def close(self) -> None:
        for drv in self.lab.instruments.values():
            try:
                drv.close()
            except Exception:  # noqa: BLE001 - closing must not mask the replay's outcome
                pass
        for b in self.backends.values():
            close = getattr(b, "close", None)
            if close is not None:
                close()
        for name in self.registered:
            registry.unregister(name)
        for sim in self.prelude_sims.values():
            sim.close()

    def extra_requests(self) -> dict[tuple[str, str], int]:
        return {k: b.extra_requests for k, b in self.backends.items() if b.extra_requests}


def controller_on_rtu(inst: InstrumentConfig, mode: str) -> bool:
    """Whether the chamber controller of a recording in ``mode`` (``sim`` | ``hardware``) talked
    Modbus RTU: the simulator's ``transport: rtu`` in a dry-run, a ``modbus-rtu://`` port on hardware."""
    if mode == "sim":
        return inst.sim is not None and inst.sim.transport == "rtu"
    return inst.port.startswith("modbus-rtu:")


def open_replay_lab(config: LabConfig, names: list[str], rec: Recording, mode: str,
                    on_traffic: Callable[[str, str, str, bytes], None] | None, on_exhausted: Callable[[str], None]) -> ReplayLab:
    for name in names:
        if name not in config.instruments:
            raise InputError(f"instrument {name!r} used by the procedure is not in the recorded config (has: {', '.join(config.instruments)})")
        if config.instruments[name].driver not in SUPPORTED:
            raise InputError(f"instrument {name!r}: driver {config.instruments[name].driver!r} cannot be replayed")
    clock = VirtualClock()
    drivers = {n: config.instruments[n].driver for n in names}
    links = rec.links(drivers)
    world = World(config.world)
    transport = dryrun_transport()
    inprocess = transport == "inprocess"
    prelude: dict[str, SimInstrument] = {}
    if not rec.prelude_recorded:
        try:
            prelude = build_devices(config, clock, names, world=World(config.world), transport=transport)
        except ValueError as exc:
            raise InputError(f"{rec.path}: the recording lacks the traffic of opening the instruments and {exc}") from None
    tag = f"replay{os.getpid()}-{next(_ids)}"
    backends: dict[tuple[str, str], Backend] = {}
    registered: list[str] = []
    ports: dict[str, str] = {}
    kwargs: dict[str, dict[str, Any]] = {n: driver_kwargs(config.instruments[n]) for n in names}

    def serial(name: str, link: str, sub: str, cls=ReplaySerial, **extra) -> str:
        reg = f"{tag}.{name}" + (f".{sub}" if sub else "")
        pre = prelude[name].serial.get(sub) if name in prelude else None
        b = cls(f"{name} {link}".strip(), links.get((name, link), []), on_exhausted, clock, prelude=pre, **extra)
        backends[(name, link)] = b
        registry.register(reg, b)
        registered.append(reg)
        return f"sim://{reg}"

    try:
        for name in names:
            inst = config.instruments[name]
            if inst.driver == "acs_board":
                ports[name] = serial(name, "", "", AcsBoardReplay, stream=rec.stream(name), description=inst.frames)
            elif inst.driver in ("stepper_bench", "thermocouple_reader"):
                ports[name] = serial(name, "", "")
            elif inst.driver == "tvac" and controller_on_rtu(inst, mode):
                scheme = "modbus-rtu+stream://" if inprocess else "modbus-rtu://"
                ports[name] = scheme + serial(name, "controller", "", ModbusRtuReplay)
                kwargs[name]["gauge_url"] = serial(name, "gauge", "gauge")
            elif inst.driver == "tvac" and inprocess:
                ports[name] = "modbus-tcp+stream://" + serial(name, "controller", "", ModbusTcpReplay)
                kwargs[name]["gauge_url"] = serial(name, "gauge", "gauge")
            elif inst.driver == "tvac":
                addr = None
                if name in prelude:
                    host_port = prelude[name].url.split("://", 1)[1]
                    h, p = host_port.rsplit(":", 1)
                    addr = (h, int(p))
                b = ModbusReplayServer(f"{name} controller", links.get((name, "controller"), []), on_exhausted, addr)
                backends[(name, "controller")] = b
                ports[name] = f"modbus-tcp://127.0.0.1:{b.port}"
                kwargs[name]["gauge_url"] = serial(name, "gauge", "gauge")
            elif inst.driver == "rate_table":
                node = inst.sim.node_id if inst.sim is not None else 1
                channel = parse_can_url(prelude[name].url).channel if name in prelude else f"{tag}-{name}"
                b = CanReplayNode(name, links.get((name, ""), []), on_exhausted, channel, sync=inprocess)
                backends[(name, "")] = b
                ports[name] = f"can://{'sync' if inprocess else 'virtual'}/{channel}?node={node}"
                kwargs[name]["clock"] = clock
        instruments: dict[str, Any] = {}
        lab = Lab(clock, mode, instruments, ports, {}, {n: config.instruments[n].poll_interval_s for n in names},
                  world if mode == "sim" else None)
        lab.kinds = {n: config.instruments[n].driver for n in names}
        lab.signals = config.signals()
        lab.config_limits = config.limits()
        rl = ReplayLab(lab, backends, registered, prelude)
        if not prelude:
            rl.go_live()
        for name in names:
            inst = config.instruments[name]
            hook = None
            if on_traffic is not None:
                hook = (lambda n: (lambda d, t, raw: on_traffic(n, d, t, raw)))(name)
            opener = (lambda cls, url, inst, hook, kw: (lambda: cls.open(url, baudrate=inst.baudrate, timeout_s=inst.timeout_s,
                                                                          on_traffic=hook, **kw)))(
                DRIVER_CLASSES[inst.driver], ports[name], inst, hook, kwargs[name])
            instruments[name] = opener()
            if isinstance(getattr(lab, "openers", None), dict):
                lab.openers[name] = opener  # the runner reopens a link after a fault: on the same backend
        if prelude:
            rl.go_live()
        return rl
    except BaseException:
        for b in backends.values():
            close = getattr(b, "close", None)
            if close is not None:
                close()
        for reg in registered:
            registry.unregister(reg)
        for sim in prelude.values():
            sim.close()
        raise
