"""The rate table's steps in the duration estimate: acceleration-limited trapezoids at the step's
or the drive's profile rate and acceleration (:mod:`bench.model.rate_table`; procedure layer)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bench.model.rate_table import TableParams, move_time_s
from bench.procedure.estimate import EstimateContext, StepEstimate

if TYPE_CHECKING:  # pragma: no cover
    from bench.procedure.loader import Step


class _Table:
    """One rate table as the estimate follows it: rate (deg/s), angle (deg, None once turned at a
    rate), tilt (deg), and the profile velocity and acceleration in force on each axis."""

    def __init__(self, p: TableParams):
        self.rate = 0.0
        self.angle: float | None = 0.0
        self.tilt = 0.0
        self.velocity = {"rotation": p.profile_velocity_dps, "tilt": p.profile_velocity_dps}
        self.accel = {"rotation": p.profile_accel_dps2, "tilt": p.profile_accel_dps2}


def table_step(s: "Step", ctx: EstimateContext) -> StepEstimate:
    """Any of the table's steps, following the table ``s`` names from where the previous ones left it."""
    return _table_step(s, ctx.state(f"rate_table:{s.params['instrument']}", lambda: _Table(ctx.lab.table)))


def _table_step(s: "Step", tb: _Table) -> StepEstimate:
    p = s.params
    axis = "tilt" if s.type == "table_tilt" else "rotation"
    if p.get("accel"):
        tb.accel[axis] = float(p["accel"])
    if s.type == "table_move" and p.get("rate"):
        tb.velocity[axis] = abs(float(p["rate"]))
    accel = tb.accel[axis]
    if s.type == "table_rate":
        rate = float(p["rate"])
        d = abs(rate - tb.rate) / accel + float(p.get("settle", 0.0))
        if rate != 0 or tb.rate != 0:
            tb.angle = None  # turned: the angle is no longer known
        tb.rate = rate
        return StepEstimate(d, basis="acceleration to the rate (table model), then settle")
    if s.type == "table_stop":
        d, tb.rate = abs(tb.rate) / accel, 0.0
        return StepEstimate(d, basis="braking (table model)")
    if s.type == "table_tilt":
        d = move_time_s(float(p["angle"]) - tb.tilt, tb.velocity[axis], accel)
        tb.tilt = float(p["angle"])
        return StepEstimate(d, basis="tilt move (table model)")
    brake = abs(tb.rate) / accel
    target = float(p["angle"])
    known = tb.angle
    tb.rate, tb.angle = 0.0, target
    if known is None:
        return StepEstimate(brake, lower_bound=True, basis="move from an unknown angle: braking, at least")
    return StepEstimate(brake + move_time_s(target - known, tb.velocity[axis], accel), basis="move (table model)")
