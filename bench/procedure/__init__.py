"""Procedures as data: schema, loading with located errors, expansion of blocks, limits, duration estimate."""

from bench.procedure.loader import Interlock, Procedure, Step, load_procedure, parse_procedure
from bench.procedure.schema import BLOCK_TYPES, SCHEMA_ID, step_types

__all__ = ["Interlock", "Procedure", "Step", "load_procedure", "parse_procedure", "SCHEMA_ID", "step_types", "BLOCK_TYPES"]
