"""The rate table's ``sim:`` keys: the CAN node of its rotation drive (tilt: the next), the
simulated bus's channel and the worm gear's eccentricity (docs/rate-table.md)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from bench.model.eccentricity import Eccentricity
from bench.yamlsrc import Fields

if TYPE_CHECKING:  # pragma: no cover
    from bench.config import ConfigContext


@dataclass
class TableSimSettings:
    can_channel: str = ""
    node_id: int = 1
    """CAN node id of the rotation axis (tilt: node_id + 1)."""
    eccentricity: Eccentricity | None = None
    """The rotation axis's worm-gear eccentricity (a true-rate error periodic in the angle)."""


def sim_settings(f: Fields, ctx: "ConfigContext") -> TableSimSettings:
    s = TableSimSettings()
    s.can_channel, s.node_id = ctx.can_node(f, 1)
    if (n := f.node_at("eccentricity")) is not None:
        s.eccentricity = ctx.periodic_error(n, "eccentricity", None)
    return s
