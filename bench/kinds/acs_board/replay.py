"""The sensor board in a replay: its recorded command bytes answered, its data frames re-encoded
from the recorded rows (bench/replay/backends.py, ``AcsBoardReplay``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bench.replay.backends import AcsBoardReplay

if TYPE_CHECKING:  # pragma: no cover
    from bench.config import InstrumentConfig
    from bench.replay.lab import ReplayContext


def wire(ctx: "ReplayContext", name: str, inst: "InstrumentConfig") -> str:
    return ctx.serial(name, "", "", AcsBoardReplay, stream=ctx.rec.stream(name), description=inst.settings.frames)
