"""The rate table in a replay: its drives' recorded CAN frames answered by one node on the
replay's bus (bench/replay/backends.py, ``CanReplayNode``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bench.replay.backends import CanReplayNode
from drivers.can_transport import parse_can_url

if TYPE_CHECKING:  # pragma: no cover
    from bench.config import InstrumentConfig
    from bench.replay.lab import ReplayContext


def wire(ctx: "ReplayContext", name: str, inst: "InstrumentConfig") -> str:
    node = inst.sim.settings.node_id if inst.sim is not None else 1
    channel = parse_can_url(ctx.prelude[name].url).channel if name in ctx.prelude else f"{ctx.tag}-{name}"
    b = CanReplayNode(name, ctx.links.get((name, ""), []), ctx.on_exhausted, channel, sync=ctx.inprocess)
    ctx.backends[(name, "")] = b
    return f"can://{'sync' if ctx.inprocess else 'virtual'}/{channel}?node={node}"
