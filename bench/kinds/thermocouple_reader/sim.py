"""The simulated thermocouple reader: a Keysight 34970A with a 34901A module reading the world's
unit temperature on RS-232, and under ``bench sim serve`` as a 34972A on its LAN SCPI socket."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bench.sim.factory import SimContext, SimInstrument, scpi_socket, serial_only
from bench.sim.thermocouple_reader import ThermocoupleReaderSim

if TYPE_CHECKING:  # pragma: no cover
    from bench.config import InstrumentConfig


def build(name: str, inst: "InstrumentConfig", ctx: SimContext) -> SimInstrument:
    from bench.sim.thermocouple_reader import KEYSIGHT_34970A

    dev = ThermocoupleReaderSim(ctx.clock, ctx.world, inst.sim.serial, tuple(inst.sim.settings.open_channels), inst.baudrate,
                                spec=KEYSIGHT_34970A, installed_types=inst.settings.tc_type, seed=inst.sim.seed)
    out = serial_only(name, dev, inst.sim.seed)
    if ctx.fixed_ports:  # other processes (PyVISA, a terminal) also reach it as a 34972A on its LAN SCPI socket
        scpi_socket(out, dev, inst.sim.settings.scpi_port)
    return out
