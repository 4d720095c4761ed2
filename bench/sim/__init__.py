"""Simulated instruments and the simulated world they share (see docs/simulation.md).

Simulators import no analysis, runner, recorder or CLI (pyproject.toml import contracts).
"""
