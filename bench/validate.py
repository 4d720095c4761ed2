"""A procedure validated against a lab config: the one path ``validate``, ``plan``, ``run`` and
``soak`` take to their procedure (every problem located, exit 2 at the CLI)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from bench.errors import InputError, InputErrors, Location
from bench.procedure import Procedure, load_procedure
from bench.procedure.estimate import LabModel

if TYPE_CHECKING:  # pragma: no cover
    from bench.config import LabConfig  # imported when a config is given: it pulls in the world model


def load_checked(procedure_path: Path, config_path: Path | None, params: dict[str, str]) -> "tuple[Procedure, LabConfig | None]":
    """Load the config (if any) and the procedure validated against it; every problem located."""
    config = None
    if config_path is not None:
        from bench.config import load_config

        config = load_config(config_path)
    kinds = config.kinds() if config is not None else None
    limits = config.limits() if config is not None else None
    signals = config.signals() if config is not None else None
    procedure = load_procedure(procedure_path, params, kinds, limits, signals)
    if config is not None:
        missing = [n for n in procedure.instruments if n not in config.instruments]
        if missing:
            raise InputErrors([
                InputError(f"instrument {n!r} is not in config {config_path} (has: {', '.join(config.instruments)})",
                           procedure.instrument_locations.get(n, Location(str(procedure.path))), "instruments")
                for n in missing
            ])
    return procedure, config


def lab_model(config: "LabConfig | None") -> LabModel:
    """What the estimates of ``bench plan`` and ``bench validate`` know of the lab of ``config``: its
    ambient temperature, the chamber model of its world, its instrument drivers (without a config:
    the model's defaults and the standard instrument names)."""
    if config is None:
        return LabModel()
    return LabModel(ambient_c=config.world.ambient_temp_c, chamber=config.world.chamber, kinds=config.kinds())
