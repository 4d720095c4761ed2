"""How bench builds the simulated supply (the kind's ``sim.builder``): a DP832 on its RS-232 line,
each output a power source (``powered_by``), and under ``bench sim serve`` its LAN socket too."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bench.sim.factory import SimContext, SimInstrument, scpi_socket, serial_only
from bench_dc_supply.sim import Dp800Sim

if TYPE_CHECKING:  # pragma: no cover
    from bench.config import InstrumentConfig


def build(name: str, inst: "InstrumentConfig", ctx: SimContext) -> SimInstrument:
    dev = Dp800Sim(ctx.clock, serial=inst.sim.serial, baudrate=inst.baudrate)
    out = serial_only(name, dev, inst.sim.seed)
    out.power_outputs = {str(n): o for n, o in dev.outputs.items()}
    if ctx.fixed_ports:  # other processes (PyVISA, a terminal) also reach it on its LAN socket
        scpi_socket(out, dev, inst.sim.settings.scpi_port)
    return out
