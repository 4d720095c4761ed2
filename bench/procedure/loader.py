"""Load and validate a procedure: every error is one ``file:line:column: field: message`` line."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.errors import InputError, InputErrors, Location
from bench.procedure.schema import SCHEMA_ID, STEP_TYPES, FieldSpec
from bench.units import to_units
from bench.yamlsrc import Fields, Node, Source, load_yaml, parse_yaml

NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_\-]*$")


@dataclass
class Step:
    """One validated step. ``params`` holds plain values in the schema's units (s, Hz, ...)."""

    index: int
    type: str
    name: str
    params: dict[str, Any]
    location: Location

    def estimated_duration_s(self) -> float:
        """Time the step should take (s); 0 for instantaneous steps."""
        return float(self.params.get("duration", 0.0)) if self.type in ("record", "wait") else 0.0


@dataclass
class Procedure:
    schema: str
    name: str
    title: str
    description: str
    instruments: list[str]
    steps: list[Step]
    path: Path
    text: str
    instrument_locations: dict[str, Location] = field(default_factory=dict)

    def estimated_duration_s(self) -> float:
        return sum(s.estimated_duration_s() for s in self.steps)


def load_procedure(path: str | Path) -> Procedure:
    """Read and validate a procedure file; raises :class:`InputErrors` listing every problem."""
    return _build(load_yaml(path, "procedure"))


def parse_procedure(text: str, path: str = "<procedure>") -> Procedure:
    return _build(parse_yaml(text, path, "procedure"))


def _build(src: Source) -> Procedure:
    errors: list[InputError] = []
    top = Fields(src.root, "procedure", errors)
    schema = top.get("schema", str, required=True)
    if schema is not None and schema != SCHEMA_ID:
        errors.append(InputError(f"unsupported schema {schema!r}; this version of bench reads {SCHEMA_ID!r}", top.map["schema"].location, "schema"))
    name = top.get("name", str, required=True) or src.path.stem
    if "name" in top.map and isinstance(top.map["name"].value, str) and not NAME_RE.match(name):
        errors.append(InputError("expected a name of letters, digits, '_' or '-'", top.map["name"].location, "name"))
    title = top.get("title", str, default=name)
    description = top.get("description", str, default="")
    instruments: list[str] = []
    inst_locs: dict[str, Location] = {}
    inst_node = top.node_at("instruments")
    if inst_node is None:
        errors.append(InputError("missing required field in procedure", src.root.location, "instruments"))
    elif not isinstance(inst_node.value, list) or not all(isinstance(n.value, str) for n in inst_node.value):
        errors.append(InputError("expected a list of instrument names", inst_node.location, "instruments"))
    else:
        for n in inst_node.value:
            instruments.append(n.value)
            inst_locs[n.value] = n.location
    steps: list[Step] = []
    steps_node = top.node_at("steps")
    if steps_node is None:
        errors.append(InputError("missing required field in procedure", src.root.location, "steps"))
    elif not isinstance(steps_node.value, list) or not steps_node.value:
        errors.append(InputError("expected a non-empty list of steps", steps_node.location, "steps"))
    else:
        for i, node in enumerate(steps_node.value):
            step = _step(i, node, set(instruments), errors)
            if step is not None:
                steps.append(step)
    top.check_unknown()
    if errors:
        raise InputErrors(errors)
    return Procedure(schema, name, title, description, instruments, steps, src.path, src.text, inst_locs)


def _step(index: int, node: Node, instruments: set[str], errors: list[InputError]) -> Step | None:
    where = f"step {index + 1}"
    if not isinstance(node.value, dict) or len(node.value) != 1:
        errors.append(InputError(f"{where}: expected a one-key mapping such as '- wait: {{duration: 10 s}}' (step types: {', '.join(STEP_TYPES)})", node.location))
        return None
    (stype, body), = node.value.items()
    key_loc = node.key_locations[stype]
    spec = STEP_TYPES.get(stype)
    if spec is None:
        errors.append(InputError(f"{where}: unknown step type {stype!r} (expected one of: {', '.join(STEP_TYPES)})", key_loc, stype))
        return None
    if spec.scalar_field and not isinstance(body.value, (dict, list)):
        body = Node({spec.scalar_field: body}, body.location, {spec.scalar_field: body.location})
    before = len(errors)
    f = Fields(body, f"{where} ({stype})", errors)
    params: dict[str, Any] = {}
    for fname, fspec in spec.fields.items():
        value = _field(f, fname, fspec, instruments, errors)
        if value is not None:
            params[fname] = value
    name = f.get("name", str, default=stype)
    f.check_unknown()
    if len(errors) > before:
        return None
    return Step(index, stype, name, params, key_loc)


def _field(f: Fields, fname: str, spec: FieldSpec, instruments: set[str], errors: list[InputError]) -> Any:
    node = f.node_at(fname)
    if node is None:
        if spec.required:
            errors.append(InputError(f"missing required field in {f.what}", f.node.location, fname))
        return spec.default
    loc = node.location
    v = node.value
    if spec.kind == "instrument":
        if not isinstance(v, str):
            errors.append(InputError("expected an instrument name", loc, fname))
            return None
        if v not in instruments:
            errors.append(InputError(f"instrument {v!r} is not in the procedure's instruments list ({', '.join(sorted(instruments)) or 'empty'})", loc, fname))
            return None
        return v
    if spec.kind == "bool":
        if not isinstance(v, bool):
            errors.append(InputError(f"expected true or false, got {v!r}", loc, fname))
            return None
        return v
    if spec.kind == "str":
        if not isinstance(v, str):
            errors.append(InputError(f"expected text, got {v!r}", loc, fname))
            return None
        return v
    if spec.kind == "int":
        if isinstance(v, bool) or not isinstance(v, int):
            errors.append(InputError(f"expected an integer, got {v!r}", loc, fname))
            return None
        value: float = v
    else:  # quantity
        try:
            value = to_units(v, spec.units, loc, fname)
        except InputError as exc:
            errors.append(exc)
            return None
    if spec.minimum is not None and value < spec.minimum or spec.maximum is not None and value > spec.maximum:
        lo = "-inf" if spec.minimum is None else f"{spec.minimum:g}"
        hi = "inf" if spec.maximum is None else f"{spec.maximum:g}"
        errors.append(InputError(f"{value:g} {spec.units} is outside the allowed range {lo}..{hi} {spec.units}".replace("  ", " "), loc, fname))
        return None
    return value
