"""The simulated stepper bench: GRBL 1.1h's state machine and planner turning the world's stage
(docs/stepper-bench.md)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bench.sim.factory import SimContext, SimInstrument, serial_only
from bench.sim.stepper_bench import StepperBenchSim, bench_eeprom

if TYPE_CHECKING:  # pragma: no cover
    from bench.config import InstrumentConfig


def build(name: str, inst: "InstrumentConfig", ctx: SimContext) -> SimInstrument:
    g = inst.sim.settings
    ctx.world.stage.periodic_errors = tuple(e for e in g.periodic_errors if e.amplitude)
    eeprom = None if g.eeprom == "blank" else bench_eeprom(g.steps_per_deg, g.max_rate_dps * 60.0, g.acceleration_dps2,
                                                           g.axis, g.build_info)
    return serial_only(name, StepperBenchSim(ctx.clock, ctx.world.stage, eeprom, axis=g.axis, pins=g.pins,
                                             dtr_reset_s=g.dtr_reset_s, baudrate=inst.baudrate,
                                             true_steps_per_deg=g.true_steps_per_deg))
