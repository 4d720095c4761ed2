"""The one runner: interprets procedure steps; the only code that touches instruments, clock and recorder."""

from bench.runner.engine import RunResult, Runner, StepOutcome

__all__ = ["RunResult", "Runner", "StepOutcome"]
