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
from bench.config import LabConfig
from bench.errors import InputError
from bench.kinds import registry as kinds
from bench.lab import Lab, describe_lab, driver_kwargs, dryrun_transport, open_drivers
from bench.replay.backends import Backend, ReplaySerial
from bench.replay.recording import Exchange, Recording
from bench.sim import registry
from bench.sim.factory import SimInstrument, build_devices
from bench.sim.world import World

_ids = itertools.count()


@dataclass
class ReplayContext:
    """What a kind's replay wiring (``Kind.replay``, ``wire(ctx, name, inst) -> url``) works with:
    the recording ``rec`` and its exchanges per (instrument, link) ``links``, the virtual ``clock``,
    the recording's ``mode``, whether links are ``inprocess``, the simulators that answer the opening
    prelude (``prelude``), the replay's registry ``tag``, the ``backends`` made so far and each
    instrument's driver ``kwargs``; :meth:`serial` makes a backend on a serial link."""

    rec: Recording
    links: dict[tuple[str, str], list[Exchange]]
    clock: VirtualClock
    mode: str
    inprocess: bool
    prelude: dict[str, SimInstrument]
    tag: str
    on_exhausted: Callable[[str], None]
    backends: dict[tuple[str, str], Backend] = field(default_factory=dict)
    registered: list[str] = field(default_factory=list)
    kwargs: dict[str, dict[str, Any]] = field(default_factory=dict)

    def serial(self, name: str, link: str, sub: str, cls=ReplaySerial, **extra) -> str:
        """A backend of class ``cls`` answering ``name``'s ``link`` from the recording, registered as a
        ``sim://`` device (its serial sub-device ``sub`` answers the prelude when there is one)."""
        reg = f"{self.tag}.{name}" + (f".{sub}" if sub else "")
        pre = self.prelude[name].serial.get(sub) if name in self.prelude else None
        b = cls(f"{name} {link}".strip(), self.links.get((name, link), []), self.on_exhausted, self.clock, prelude=pre, **extra)
        self.backends[(name, link)] = b
        registry.register(reg, b)
        self.registered.append(reg)
        return f"sim://{reg}"


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


def open_replay_lab(config: LabConfig, names: list[str], rec: Recording, mode: str,
                    on_traffic: Callable[[str, str, str, bytes], None] | None, on_exhausted: Callable[[str], None]) -> ReplayLab:
    for name in names:
        if name not in config.instruments:
            raise InputError(f"instrument {name!r} used by the procedure is not in the recorded config (has: {', '.join(config.instruments)})")
    clock = VirtualClock()
    drivers = {n: config.instruments[n].driver for n in names}
    world = World(config.world)
    transport = dryrun_transport()
    prelude: dict[str, SimInstrument] = {}
    if not rec.prelude_recorded:
        try:
            prelude = build_devices(config, clock, names, world=World(config.world), transport=transport)
        except ValueError as exc:
            raise InputError(f"{rec.path}: the recording lacks the traffic of opening the instruments and {exc}") from None
    ctx = ReplayContext(rec, rec.links(drivers), clock, mode, transport == "inprocess", prelude,
                        f"replay{os.getpid()}-{next(_ids)}", on_exhausted,
                        kwargs={n: driver_kwargs(config.instruments[n]) for n in names})
    ports: dict[str, str] = {}
    try:
        for name in names:
            inst = config.instruments[name]
            ports[name] = kinds.load(inst.kind.replay)(ctx, name, inst) if inst.kind.replay else ctx.serial(name, "", "")
            if inst.kind.needs_clock:
                ctx.kwargs[name]["clock"] = clock
        instruments: dict[str, Any] = {}
        lab = Lab(clock, mode, instruments, ports, {}, {n: config.instruments[n].poll_interval_s for n in names},
                  world if mode == "sim" else None)
        describe_lab(lab, config, names)
        rl = ReplayLab(lab, ctx.backends, ctx.registered, prelude)
        if not prelude:
            rl.go_live()
        open_drivers(lab, config, names, ctx.kwargs, on_traffic)
        if prelude:
            rl.go_live()
        return rl
    except BaseException:
        for b in ctx.backends.values():
            close = getattr(b, "close", None)
            if close is not None:
                close()
        for reg in ctx.registered:
            registry.unregister(reg)
        for sim in prelude.values():
            sim.close()
        raise
