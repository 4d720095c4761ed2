"""How long the chamber's steps take, from the chamber model (:mod:`bench.model.chamber`;
procedure layer, for ``bench plan`` and the ETA): the air's slew or ramp and approach, the
pump-down and vent laws, each at the pressure the chamber is at."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bench.model.chamber import pump_down_time_s, vent_time_s
from bench.procedure.estimate import EstimateContext, StepEstimate, capped

if TYPE_CHECKING:  # pragma: no cover
    from bench.procedure.loader import Step


def set_temperature(s: "Step", ctx: EstimateContext) -> StepEstimate:
    p = s.params
    c = ctx.chamber(p["instrument"])
    c.set_point(ctx.t, float(p["set_point"]), float(p.get("ramp") or 0.0))
    if p.get("wait"):
        return capped(c.reach_s(ctx.t, float(p.get("band", 1.0))), p, "chamber ramp and approach (chamber model)")
    return StepEstimate(0.0)


def pump_down(s: "Step", ctx: EstimateContext) -> StepEstimate:
    p = s.params
    c = ctx.chamber(p["instrument"])
    e = capped(pump_down_time_s(c.p, float(p["pressure"]), c.pressure_torr), p, "pump-down law (chamber model)")
    c.pressure_torr = min(c.pressure_torr, float(p["pressure"]))
    return e


def vent(s: "Step", ctx: EstimateContext) -> StepEstimate:
    p = s.params
    c = ctx.chamber(p["instrument"])
    e = capped(vent_time_s(c.p, float(p.get("pressure", 700.0)), c.pressure_torr), p, "vent law (chamber model)")
    c.pressure_torr = max(c.pressure_torr, float(p.get("pressure", 700.0)))
    return e
