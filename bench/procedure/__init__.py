"""Procedures as data: schema, loading with located errors, duration estimate."""

from bench.procedure.loader import Procedure, Step, load_procedure, parse_procedure
from bench.procedure.schema import SCHEMA_ID, STEP_TYPES

__all__ = ["Procedure", "Step", "load_procedure", "parse_procedure", "SCHEMA_ID", "STEP_TYPES"]
