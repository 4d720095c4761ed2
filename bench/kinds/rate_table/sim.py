"""The simulated rate table: two CiA 402 drives (rotation and tilt) on a CAN bus — a synchronous
in-process one in a dry-run, a python-can virtual bus with ``socket``, plus an SLCAN adapter on a
pty under ``bench sim serve`` (docs/rate-table.md)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bench.sim.factory import SimContext, SimInstrument
from bench.sim.serial_faults import FaultySerialLink

if TYPE_CHECKING:  # pragma: no cover
    from bench.config import InstrumentConfig


def build(name: str, inst: "InstrumentConfig", ctx: SimContext) -> SimInstrument:
    from bench.sim.rate_table import RateTableSim

    s = inst.sim.settings
    node = s.node_id
    world = ctx.world
    if s.eccentricity is not None:
        world.table.rotation.eccentricity = s.eccentricity  # the rotation axis's worm gear
    channel = ctx.can_channel(s.can_channel, name)
    if ctx.inprocess:  # frames delivered in the sender's thread: no notifier threads, no queues
        from drivers.can_transport import SyncBus

        bus, interface, what = SyncBus(channel), "sync", "synchronous in-process CAN channel"
    else:
        bus, interface, what = channel, "virtual", "python-can virtual channel"
    sim = RateTableSim(ctx.clock, world.table.rotation, world.table.tilt, node_id=node, serial=inst.sim.serial, bus=bus)
    out = SimInstrument(name, sim, url=f"can://{interface}/{channel}?node={node}", closers=[sim.close],
                        endpoints=[("can", f"{what} {channel!r} (this process), nodes {node} rotation, {node + 1} tilt")])
    if ctx.fixed_ports:
        # other processes reach the bus through a simulated SLCAN USB-CAN adapter on a pseudo-terminal
        from bench.sim.slcan_gateway import SlcanGatewaySim

        gateway = SlcanGatewaySim(channel)
        out.serial["slcan"] = FaultySerialLink(gateway, inst.sim.seed)
        out.closers.insert(0, gateway.close)
    return out
