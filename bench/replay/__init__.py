"""Replay of recorded runs (``bench replay``): see docs/replay.md."""

from bench.replay.run import ReplayResult, replay

__all__ = ["ReplayResult", "replay"]
