"""The simulated chamber: a Watlow F4 controller (Modbus TCP, in-process stream or RTU) and a
Pfeiffer TPG 261 gauge on a serial link, both on the world's chamber (docs/tvac.md)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bench.sim.factory import LOCALHOST, SimContext, SimInstrument, serial_url
from bench.sim.serial_faults import FaultySerialLink

if TYPE_CHECKING:  # pragma: no cover
    from bench.config import InstrumentConfig


def build(name: str, inst: "InstrumentConfig", ctx: SimContext) -> SimInstrument:
    from bench.sim.tpg261 import Tpg261Sim
    from bench.sim.watlow_f4_server import WatlowF4Server

    clock, world, seed = ctx.clock, ctx.world, inst.sim.seed
    gauge = Tpg261Sim(clock, world.chamber, baudrate=inst.settings.gauge_baudrate)
    if inst.sim.transport == "rtu":  # the controller on its own serial link: sim://NAME, or a pty when served
        from bench.sim.watlow_f4_rtu import WatlowF4RtuSim

        rtu = WatlowF4RtuSim(clock, world.chamber, baudrate=inst.baudrate)
        scheme = "modbus-rtu+stream" if ctx.inprocess else "modbus-rtu"  # the stream client reads without polling the wall clock
        return SimInstrument(name, rtu, serial={"": FaultySerialLink(rtu, seed), "gauge": FaultySerialLink(gauge, seed)},
                             url=f"{scheme}://{serial_url(name, '')}", url_kwargs={"gauge_url": "gauge"})
    if ctx.inprocess:  # the same Modbus TCP ADUs on an in-process stream, answered in the caller's thread
        from bench.sim.watlow_f4_stream import WatlowF4StreamSim

        stream = WatlowF4StreamSim(clock, world.chamber)
        return SimInstrument(name, stream, serial={"": FaultySerialLink(stream, seed), "gauge": FaultySerialLink(gauge, seed)},
                             url=f"modbus-tcp+stream://{serial_url(name, '')}", url_kwargs={"gauge_url": "gauge"},
                             endpoints=[("modbus-tcp", f"in-process stream {serial_url(name, '')} (unit id 1)")])
    server = WatlowF4Server(clock, world.chamber)
    port = server.start(LOCALHOST, inst.sim.settings.modbus_port if ctx.fixed_ports else 0)
    url = f"modbus-tcp://{LOCALHOST}:{port}"
    return SimInstrument(name, server, serial={"gauge": FaultySerialLink(gauge, seed)}, url=url, url_kwargs={"gauge_url": "gauge"},
                         endpoints=[("modbus-tcp", f"{LOCALHOST}:{port} (unit id 1)")], closers=[server.stop])
