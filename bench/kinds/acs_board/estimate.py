"""The board's steps in the duration estimate: switching its sensors changes the die's self-heating
(procedure layer; bench/procedure/estimate.py)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bench.procedure.estimate import EstimateContext, StepEstimate

if TYPE_CHECKING:  # pragma: no cover
    from bench.procedure.loader import Step


def power(s: "Step", ctx: EstimateContext) -> StepEstimate:
    ctx.chamber().power_changed_at = ctx.t
    return StepEstimate(0.0)
