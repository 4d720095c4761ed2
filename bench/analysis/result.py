"""What every ``bench calibrate`` method returns: machine-readable results, human tables and the
calibration to write. The CLI (``bench/cli_analysis.py``) prints, serialises and writes these."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass
class ResultTable:
    """A human-readable table: ``title``, column ``headers`` (with units) and ``rows`` of cells."""

    title: str
    headers: list[str]
    rows: list[list[Any]]


@dataclass
class CalibrationResult:
    """Outcome of one calibration method.

    ``json``: the ``--json`` payload (plain lists, dicts, floats; shape documented per method in
    ``docs/analysis.md``); ``tables``: what the terminal and the report show; ``calibration``: the
    coefficients (with standard errors) written to the calibration YAML by ``-o``, or ``None`` when the
    method produces no calibration (e.g. ``noise``); ``notes``: warnings and remarks for the operator.
    """

    method: str
    json: dict[str, Any]
    tables: list[ResultTable] = field(default_factory=list)
    calibration: dict[str, Any] | None = None
    notes: list[str] = field(default_factory=list)
