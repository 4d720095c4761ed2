"""Instrument kinds: one record per kind, found by entry point (docs/instruments.md).

:mod:`bench.kinds.record` defines the record (on :mod:`bench.kinds.frozen`), :mod:`bench.kinds.registry`
finds the installed ones (their entry points cached by :mod:`bench.kinds.entry_cache`),
:mod:`bench.record.by_kind` finds a run file's streams by kind and role. The five kinds bench ships
are packages of this one (``bench.kinds.acs_board`` ...), declared in bench's pyproject.toml like
any lab's own.
"""

from bench.kinds.record import (ROLES, Envelope, FaultDef, FieldSpec, Figure, Kind, Limit, RateSchedule, Signal, SimSpec,
                                StepDef, StepSpec, WAIT_TIMEOUT, instrument_field)

__all__ = ["ROLES", "Envelope", "FaultDef", "FieldSpec", "Figure", "Kind", "Limit", "RateSchedule", "Signal", "SimSpec",
           "StepDef", "StepSpec", "WAIT_TIMEOUT", "instrument_field"]
