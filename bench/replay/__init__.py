"""Replay of recorded runs (``bench replay``): see docs/replay.md.

``replay`` and ``ReplayResult`` are imported on first use (PEP 562), so that ``bench.replay.cli``
(the parser of every ``bench`` command) does not import the runner and the drivers.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from bench.replay.run import ReplayResult, replay

__all__ = ["ReplayResult", "replay"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        import importlib

        return getattr(importlib.import_module("bench.replay.run"), name)
    raise AttributeError(f"module 'bench.replay' has no attribute {name!r}")
