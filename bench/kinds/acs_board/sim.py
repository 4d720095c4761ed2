"""The simulated sensor board: our board's firmware behaviour on its frame description, with a
sensor model on the world, on a UART (``sim://NAME``) or in CAN frames (docs/acs-board-can.md)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from bench.model.imu_simple import SimpleImuModel
from bench.sim.acs_board import AcsBoardIdentity, AcsBoardSim
from bench.sim.factory import SimContext, SimInstrument, serial_only

if TYPE_CHECKING:  # pragma: no cover
    from bench.config import InstrumentConfig


def build(name: str, inst: "InstrumentConfig", ctx: SimContext) -> SimInstrument:
    s = inst.sim.settings
    rng = np.random.default_rng(inst.sim.seed)
    if s.sensor_spec is not None:
        from bench.sim.acs_board import board_model_from_spec

        model = board_model_from_spec(s.sensor_spec, rng)
    else:
        model = SimpleImuModel(s.model, rng)
    dev = AcsBoardSim(ctx.clock, ctx.world, model, AcsBoardIdentity(serial=inst.sim.serial), baudrate=inst.baudrate,
                      bit_fail_mask=s.bit_fail_mask, description=inst.settings.frames)
    if inst.sim.transport != "can":
        out = serial_only(name, dev, inst.sim.seed)
        out.power_input = dev.power  # another simulated instrument may power it (config powered_by)
        return out
    from bench.sim.can_serial_bridge import CanSerialBridge

    node = s.node_id
    channel = ctx.can_channel(s.can_channel, name)
    bridge = CanSerialBridge(dev, channel, node=node, seed=inst.sim.seed)
    return SimInstrument(name, bridge, url=f"can://virtual/{channel}?node={node}", closers=[bridge.close],
                         endpoints=[("can", f"python-can virtual channel {channel!r} (this process), node {node}")],
                         power_input=dev.power)
