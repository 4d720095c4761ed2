"""The parameters of the simulated world: room, site and chamber (units in the names).

Read by the lab config (``world:``) and the procedure layer's estimates; the simulated world
(:class:`bench.sim.world.World`) runs on them. Defaults and their sources: bench/sim/world.py.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from bench.model.chamber import ChamberParams
from bench.params import dataclass_from_dict


@dataclass
class WorldParams:
    """Parameters of the world (units in the names)."""

    ambient_temp_c: float = 20.0
    latitude_deg: float = 36.4
    field_ut: list[float] = field(default_factory=lambda: [23.6, 0.0, -42.0])
    chamber: ChamberParams = field(default_factory=ChamberParams)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "WorldParams":
        """Build from a mapping; unknown keys raise ``KeyError`` naming them."""
        return dataclass_from_dict(cls, data)
