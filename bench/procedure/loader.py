"""Load, expand and validate a procedure: every error is one ``file:line:column: field: message`` line.

Loading has two stages, both before anything moves:

1. the document: schema, name, instruments, parameters (with CLI overrides), limits, interlocks;
2. expansion: blocks (``repeat``, ``for_each``, ``call``, ``rate_steps``) are unrolled and
   ``$parameters`` substituted, giving the flat list of action steps the runner executes; each
   action keeps the file:line of the YAML it came from (in a called file: that file's line).

Nothing in a procedure executes code: values are data, parameters are substituted as values.
"""

from __future__ import annotations

import itertools
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from bench.params import override_problem
from bench.errors import InputError, InputErrors, Location
from bench.inputs import PROCEDURE_ROOTS, confined_path
from bench.procedure.limits import check_step_limits
from bench.procedure.schema import BLOCK_TYPES, REQUIREMENTS, SCHEMA_ID, STEP_TYPES, FieldSpec
from bench.procedure.signals import DEFAULT_KINDS, STEP_COMMANDS, StreamSignals, signal_units
from bench.units import TEMPERATURE_DIFFERENCE, to_units
from bench.yamlsrc import MAX_FLOAT, Fields, Node, Source, load_yaml, parse_yaml

if TYPE_CHECKING:  # pragma: no cover
    from bench.procedure.estimate import Estimate, LabModel

NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_\-]*$")
VAR_RE = re.compile(r"^\$\{?([A-Za-z_][A-Za-z0-9_]*)\}?$")
INTERP_RE = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)\}")
MAX_STEPS = 100_000
"""Expansion limit: a procedure that unrolls into more actions than this is refused."""
MAX_CALL_DEPTH = 8


@dataclass
class Step:
    """One action step. ``params`` holds plain values in the schema's units (s, Hz, degC, ...)."""

    index: int
    type: str
    name: str
    params: dict[str, Any]
    location: Location
    path: str = ""
    """Position in the source tree, e.g. ``4.2.1`` (4th step, 2nd iteration/child, 1st action)."""
    context: str = ""
    """Loop variables in force, e.g. ``T=-29 degC``."""
    meta: dict[str, Any] = field(default_factory=dict)
    """Facts the expansion knows (e.g. the commanded rate of a rate-schedule window)."""


@dataclass
class Interlock:
    """A limit watched during the whole run: ``signal`` outside [minimum, maximum] aborts it.

    ``active``: ``always``, ``vacuum`` (between a completed pump_down and the next vent) or
    ``streaming`` (for ``stall``: while the board records). ``stall``: the longest gap (s)
    between frames of the streaming instrument ``signal`` names.
    """

    name: str
    signal: str
    minimum: float | None
    maximum: float | None
    active: str
    location: Location
    stall_s: float | None = None

    def beyond(self, value: float) -> bool:
        """Whether ``value`` (in the signal's units) lies outside [minimum, maximum]."""
        return (self.minimum is not None and value < self.minimum) or (self.maximum is not None and value > self.maximum)


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
    parameters: dict[str, Any] = field(default_factory=dict)
    limits: dict[str, dict[str, tuple[float | None, float | None, Location]]] = field(default_factory=dict)
    interlocks: list[Interlock] = field(default_factory=list)
    sources: dict[str, str] = field(default_factory=dict)
    """Text of every called procedure file and vibration profile, by path (the run file keeps them)."""
    unit_required_at: Location | None = None
    """Where the procedure (or a procedure it calls) says ``requires: {unit: true}``: ``bench run``
    then needs ``--unit``; None when no unit under test is required."""

    def estimate(self, lab: "LabModel | None" = None) -> "Estimate":
        """How long each step should take on the lab model ``lab`` (default: the model's own
        defaults); see :mod:`bench.procedure.estimate`."""
        from bench.procedure.estimate import estimate_procedure

        return estimate_procedure(self.steps, lab)

    def estimated_duration_s(self, lab: "LabModel | None" = None) -> float:
        """Estimated run time of the whole procedure (s; a lower bound if :meth:`estimate` says so)."""
        return self.estimate(lab).total_s


def load_procedure(path: str | Path, params: dict[str, str] | None = None, kinds: dict[str, str] | None = None,
                   config_limits: dict[str, dict[str, tuple]] | None = None,
                   signals: dict[str, StreamSignals] | None = None) -> Procedure:
    """Read, expand and validate a procedure file; raises :class:`InputErrors` listing every problem.

    ``params``: overrides ``NAME -> value text`` (``-p cold=-20degC``). ``kinds``: instrument name
    -> driver (from the lab config); by default the standard names are assumed (``tvac`` is a
    chamber, ...), which is what ``bench validate`` without ``--config`` checks against.
    ``config_limits``: instrument -> quantity -> (low, high) from the lab config; every step is
    checked against the defaults, these and the procedure's own ``limits:``. ``signals``: board
    name -> the signals and commands of its frame description (``LabConfig.signals()``); a board
    not in it has ours.
    """
    return _build(load_yaml(path, "procedure"), params or {}, kinds, config_limits or {}, signals or {})


def parse_procedure(text: str, path: str = "<procedure>", params: dict[str, str] | None = None,
                    kinds: dict[str, str] | None = None, config_limits: dict[str, dict[str, tuple]] | None = None,
                    signals: dict[str, StreamSignals] | None = None) -> Procedure:
    return _build(parse_yaml(text, path, "procedure"), params or {}, kinds, config_limits or {}, signals or {})


# ---- document -----------------------------------------------------------------------------------
class _Doc:
    """What the top level of one procedure file says (before expansion)."""

    def __init__(self, src: Source, errors: list[InputError]):
        self.src = src
        top = Fields(src.root, "procedure", errors)
        self.schema = top.get("schema", str, required=True)
        if self.schema is not None and self.schema != SCHEMA_ID:
            errors.append(InputError(f"unsupported schema {self.schema!r}; this version of bench reads {SCHEMA_ID!r}", top.map["schema"].location, "schema"))
        self.name = top.get("name", str, required=True) or src.path.stem
        if "name" in top.map and isinstance(top.map["name"].value, str) and not NAME_RE.match(self.name):
            errors.append(InputError("expected a name of letters, digits, '_' or '-'", top.map["name"].location, "name"))
        self.title = top.get("title", str, default=self.name)
        self.description = top.get("description", str, default="")
        self.instruments: list[str] = []
        self.inst_locs: dict[str, Location] = {}
        inst_node = top.node_at("instruments")
        if inst_node is None:
            errors.append(InputError("missing required field in procedure", src.root.location, "instruments"))
        elif not isinstance(inst_node.value, list) or not all(isinstance(n.value, str) for n in inst_node.value):
            errors.append(InputError("expected a list of instrument names", inst_node.location, "instruments"))
        else:
            for n in inst_node.value:
                self.instruments.append(n.value)
                self.inst_locs[n.value] = n.location
        self.parameters: dict[str, Node] = {}
        pnode = top.node_at("parameters")
        if pnode is not None:
            if not isinstance(pnode.value, dict):
                errors.append(InputError("expected a mapping of parameter names to default values", pnode.location, "parameters"))
            else:
                for key, node in pnode.value.items():
                    if not NAME_RE.match(key) or "-" in key:
                        errors.append(InputError("expected a parameter name of letters, digits and '_'", pnode.key_locations[key], key))
                    self.parameters[key] = node
        self.limits_node = top.node_at("limits")
        self.interlocks_node = top.node_at("interlocks")
        self.unit_required_at = _requires(top.node_at("requires"), errors)
        self.steps_node = top.node_at("steps")
        if self.steps_node is None:
            errors.append(InputError("missing required field in procedure", src.root.location, "steps"))
        elif not isinstance(self.steps_node.value, list) or not self.steps_node.value:
            errors.append(InputError("expected a non-empty list of steps", self.steps_node.location, "steps"))
        top.check_unknown()


def _build(src: Source, overrides: dict[str, str], kinds: dict[str, str] | None, config_limits: dict[str, dict[str, tuple]],
           signals: dict[str, StreamSignals]) -> Procedure:
    errors: list[InputError] = []
    doc = _Doc(src, errors)
    kinds = dict(kinds) if kinds is not None else {n: DEFAULT_KINDS[n] for n in doc.instruments if n in DEFAULT_KINDS}
    for key in overrides:
        if key not in doc.parameters:
            known = ", ".join(doc.parameters) or "none"
            errors.append(InputError(f"no parameter {key!r} in {src.path} (parameters: {known})", None, f"-p {key}"))
    env: dict[str, Node] = {}
    for key, node in doc.parameters.items():
        if key in overrides:
            value = _override_value(overrides[key])
            problem = override_problem(key, node.plain(), value)
            if problem is not None:  # located at -p NAME, not at a step that uses it
                errors.append(problem)
                continue
        env[key] = _as_node(value, Location(f"-p {key}")) if key in overrides else node
    if any(e.field and e.field.startswith("-p ") for e in errors):
        raise InputErrors(errors)
    exp = _Expander(doc, kinds, errors, signals)
    if doc.steps_node is not None and isinstance(doc.steps_node.value, list):
        exp.expand(doc.steps_node.value, env, doc, prefix="", context="", depth=0)
    limits = _limits(doc.limits_node, kinds, errors)
    inode = exp._subst(doc.interlocks_node, env) if doc.interlocks_node is not None else None
    interlocks = _interlocks(inode, doc.instruments, kinds, errors, signals)
    if not errors:
        for site, run in itertools.groupby(exp.steps, key=lambda s: exp.called_from.get(s.index, "")):
            for e in check_step_limits(list(run), kinds, config_limits, limits):
                errors.append(InputError(f"{e.message} {site}", e.location, e.field) if site else e)
    if errors:
        raise InputErrors(errors)
    plain_params = {k: n.plain() for k, n in env.items()}
    return Procedure(doc.schema, doc.name, doc.title, doc.description, doc.instruments, exp.steps, src.path, src.text,
                     doc.inst_locs, plain_params, limits, interlocks, exp.sources,
                     unit_required_at=doc.unit_required_at or exp.unit_required_at)


def _requires(node: Node | None, errors: list[InputError]) -> Location | None:
    """``requires: {unit: true}`` (schema :data:`REQUIREMENTS`): the location of the ``unit`` key
    when the procedure requires a unit under test, else None."""
    if node is None:
        return None
    f = Fields(node, "requires", errors)
    required = {key: f.get(key, bool, default=False) for key in REQUIREMENTS}
    f.check_unknown()
    return f.key_location("unit") if required["unit"] else None


def _as_node(value: Any, loc: Location) -> Node:
    """A plain value (from ``-p``) as a Node tree located at the option."""
    if isinstance(value, list):
        return Node([_as_node(v, loc) for v in value], loc)
    if isinstance(value, dict):
        return Node({str(k): _as_node(v, loc) for k, v in value.items()}, loc, {str(k): loc for k in value})
    return Node(value, loc)


def _override_value(text: str) -> Any:
    """A ``-p NAME=VALUE`` value: YAML scalar rules (numbers, booleans, lists), else the text."""
    try:
        value = yaml.safe_load(text)
    except (yaml.YAMLError, ValueError, RecursionError):  # ValueError: an integer of > 4300 digits
        return text
    ok = isinstance(value, (int, float, str, bool, list, dict)) and _plain_value(value, [1000])
    return value if ok else text


def _plain_value(value: Any, budget: list[int], depth: int = 0) -> bool:
    """Whether a ``-p`` value is plain data the schema can check: scalars (numbers within float
    range), lists and mappings of them, not nested deeper than 20 (which also stops a self-referring
    alias) and of at most ``budget`` values."""
    budget[0] -= 1
    if budget[0] < 0 or depth > 20:
        return False
    if isinstance(value, list):
        return all(_plain_value(v, budget, depth + 1) for v in value)
    if isinstance(value, dict):
        return all(_plain_value(v, budget, depth + 1) for v in value.values())
    if isinstance(value, int) and not isinstance(value, bool):
        return abs(value) <= MAX_FLOAT
    return isinstance(value, (str, float, bool, type(None)))


# ---- expansion ----------------------------------------------------------------------------------
class _Expander:
    def __init__(self, doc: _Doc, kinds: dict[str, str], errors: list[InputError], signals: dict[str, StreamSignals]):
        self.root = doc
        self.kinds = kinds
        self.signals = signals
        self.errors = errors
        self.steps: list[Step] = []
        self.sources: dict[str, str] = {}
        self._call_stack: list[Path] = [doc.src.path.resolve()]
        self._too_many = False
        self._sites: list[Location] = []  # the call steps being expanded, outermost first
        self.called_from: dict[int, str] = {}
        """Step index -> ``(called from FILE:LINE:COL)`` of every call it was expanded through."""
        self.unit_required_at: Location | None = None
        """The first called procedure's ``requires: {unit: true}``, if any requires a unit."""

    def expand(self, nodes: list[Node], env: dict[str, Node], doc: _Doc, prefix: str, context: str, depth: int) -> None:
        for i, node in enumerate(nodes):
            if self._too_many:
                return
            path = f"{prefix}{i + 1}"
            self._one(node, env, doc, path, context, depth)

    def _one(self, node: Node, env: dict[str, Node], doc: _Doc, path: str, context: str, depth: int) -> None:
        where = f"step {path}"
        if not isinstance(node.value, dict) or len(node.value) != 1:
            self.errors.append(InputError(f"{where}: expected a one-key mapping such as '- wait: {{duration: 10 s}}' "
                                          f"(step types: {', '.join([*STEP_TYPES, *BLOCK_TYPES])})", node.location))
            return
        (stype, body), = node.value.items()
        key_loc = node.key_locations[stype]
        if stype in BLOCK_TYPES:
            getattr(self, f"_block_{stype}")(body, env, doc, path, context, depth, key_loc)
            return
        spec = STEP_TYPES.get(stype)
        if spec is None:
            self.errors.append(InputError(f"{where}: unknown step type {stype!r} (expected one of: {', '.join([*STEP_TYPES, *BLOCK_TYPES])})", key_loc, stype))
            return
        body = self._subst(body, env)
        if body is None:
            return
        if spec.scalar_field and not isinstance(body.value, (dict, list)):
            body = Node({spec.scalar_field: body}, body.location, {spec.scalar_field: body.location})
        self.action(stype, body, doc, path, context, key_loc)

    def action(self, stype: str, body: Node, doc: _Doc, path: str, context: str, key_loc: Location,
               meta: dict[str, Any] | None = None) -> Step | None:
        spec = STEP_TYPES[stype]
        before = len(self.errors)
        f = Fields(body, f"step {path} ({stype})", self.errors)
        params: dict[str, Any] = {}
        signal_u = None
        if "signal" in spec.fields and isinstance(f.map.get("signal") and f.map["signal"].value, str):
            signal_u = self._signal_units(f.map["signal"], doc)
        for fname, fspec in spec.fields.items():
            units = fspec.units
            if fspec.kind == "quantity" and not units:
                units = _signal_field_units(fname, signal_u, f.map.get("statistic"))
                if units is None:
                    f.node_at(fname)
                    continue
            value = self._field(f, fname, fspec, units, doc)
            if value is not None:
                params[fname] = value
        name = f.get("name", str, default=stype)
        f.check_unknown()
        self._check_board_commands(stype, params, f, key_loc)
        if len(self.errors) > before:
            return None
        if len(self.steps) >= MAX_STEPS:
            self._too_many = True
            self.errors.append(InputError(f"the procedure expands into more than {MAX_STEPS} steps", key_loc))
            return None
        step = Step(len(self.steps), stype, name, params, key_loc, path, context, dict(meta or {}))
        if self._sites:
            self.called_from[step.index] = _called_from(self._sites)
        self.steps.append(step)
        return step

    def _check_board_commands(self, stype: str, params: dict[str, Any], f: Fields, key_loc: Location) -> None:
        """A board step whose handler sends a command the board's frame description does not have
        (``bit`` on a board without RUN_BIT): refused here, before anything moves."""
        stream = self.signals.get(params.get("instrument", ""))
        if stream is None:
            return
        needs = [(k, c) for k in ([stype] if stype != "configure" else [p for p in params if p in STEP_COMMANDS])
                 for c in STEP_COMMANDS.get(k, ()) if c not in stream.commands]
        for key, command in needs:
            where = f.key_location(key) if stype == "configure" else key_loc
            self.errors.append(InputError(f"board {params['instrument']!r} (frame description {stream.description!r}) has no "
                                          f"{command} command, which {stype if stype != 'configure' else f'configure {key}'} sends "
                                          f"(its commands: {', '.join(sorted(stream.commands))})", where, key))

    # ---- substitution -------------------------------------------------------------------------
    def _subst(self, node: Node, env: dict[str, Node]) -> Node | None:
        """``node`` with ``$var`` values replaced and ``${var}`` interpolated in text (deep)."""
        v = node.value
        if isinstance(v, str):
            m = VAR_RE.match(v.strip())
            if m:
                ref = env.get(m.group(1))
                if ref is None:
                    self.errors.append(InputError(f"unknown parameter or loop variable ${m.group(1)} (known: {', '.join(sorted(env)) or 'none'})", node.location))
                    return None
                return Node(ref.value, node.location, ref.key_locations)
            if "${" in v:
                missing = [name for name in INTERP_RE.findall(v) if name not in env]
                if missing:
                    self.errors.append(InputError(f"unknown parameter or loop variable ${{{missing[0]}}} (known: {', '.join(sorted(env)) or 'none'})", node.location))
                    return None
                return Node(INTERP_RE.sub(lambda mm: _text(env[mm.group(1)].plain()), v), node.location)
            return node
        if isinstance(v, list):
            items = [self._subst(n, env) for n in v]
            return None if any(i is None for i in items) else Node(items, node.location, node.key_locations)
        if isinstance(v, dict):
            out = {}
            for k, n in v.items():
                s = self._subst(n, env)
                if s is None:
                    return None
                out[k] = s
            return Node(out, node.location, node.key_locations)
        return node

    # ---- fields -------------------------------------------------------------------------------
    def _field(self, f: Fields, fname: str, spec: FieldSpec, units: str, doc: _Doc) -> Any:
        node = f.node_at(fname)
        if node is None:
            if spec.required:
                self.errors.append(InputError(f"missing required field in {f.what}", f.node.location, fname))
            return spec.default
        loc, v = node.location, node.value
        if spec.kind == "instrument":
            return self._instrument(node, fname, spec, doc)
        if spec.kind == "signal":
            return v if self._signal_units(node, doc) is not None else None
        if spec.kind == "vibration":
            return self._vibration(node, fname, doc)
        if spec.kind == "bool":
            if not isinstance(v, bool):
                self.errors.append(InputError(f"expected true or false, got {v!r}", loc, fname))
                return None
            return v
        if spec.kind in ("str", "choice"):
            if not isinstance(v, str):
                self.errors.append(InputError(f"expected text, got {v!r}", loc, fname))
                return None
            if spec.kind == "choice" and v not in spec.choices:
                self.errors.append(InputError(f"expected one of {', '.join(spec.choices)}, got {v!r}", loc, fname))
                return None
            return v
        if spec.kind == "int":
            if isinstance(v, bool) or not isinstance(v, int):
                self.errors.append(InputError(f"expected an integer, got {v!r}", loc, fname))
                return None
            value: float = v
        else:
            try:
                value = to_units(v, units, loc, fname)
            except InputError as exc:
                self.errors.append(exc)
                return None
        if spec.minimum is not None and value < spec.minimum or spec.maximum is not None and value > spec.maximum:
            lo = "-inf" if spec.minimum is None else f"{spec.minimum:g}"
            hi = "inf" if spec.maximum is None else f"{spec.maximum:g}"
            self.errors.append(InputError(f"{value:g} {units} is outside the allowed range {lo}..{hi} {units}".replace("  ", " "), loc, fname))
            return None
        if spec.exclusive_minimum and spec.minimum is not None and value <= spec.minimum:
            self.errors.append(InputError(f"{value:g} {units} must be above {spec.minimum:g} {units}".replace("  ", " "), loc, fname))
            return None
        return value

    def _vibration(self, node: Node, fname: str, doc: _Doc) -> str | None:
        """A vibration profile file relative to the procedure, loaded now so its errors show at validation."""
        from bench.model.vibration import parse_vibration

        if not isinstance(node.value, str):
            self.errors.append(InputError("expected the path of a vibration file", node.location, fname))
            return None
        try:
            path = _resolve(doc, node.value, "vibration file", node.location, fname)
        except InputError as exc:
            self.errors.append(exc)
            return None
        if path is None:
            self.errors.append(InputError("expected a file name without NUL characters", node.location, fname))
            return None
        try:
            src = load_yaml(path, "vibration file")
            parse_vibration(src.text, str(path))
        except InputError as exc:
            self.errors.append(InputError(f"vibration profile: {exc.one_line()}", node.location, fname))
            return None
        self.sources[str(path)] = src.text  # kept in the run file: a replay reads it from there
        return str(path)

    def _instrument(self, node: Node, fname: str, spec: FieldSpec, doc: _Doc) -> str | None:
        v = node.value
        if not isinstance(v, str):
            self.errors.append(InputError("expected an instrument name", node.location, fname))
            return None
        if v not in doc.instruments:
            self.errors.append(InputError(f"instrument {v!r} is not in the procedure's instruments list ({', '.join(sorted(doc.instruments)) or 'empty'})", node.location, fname))
            return None
        if v not in self.root.instruments:
            self.errors.append(InputError(f"instrument {v!r} of a called procedure is not in the calling procedure's instruments list", node.location, fname))
            return None
        kind = self.kinds.get(v)
        if spec.instrument_kinds and kind is not None and kind not in spec.instrument_kinds:
            self.errors.append(InputError(f"instrument {v!r} is a {kind}; this step needs a {' or '.join(spec.instrument_kinds)}", node.location, fname))
            return None
        return v

    def _signal_units(self, node: Node, doc: _Doc) -> str | None:
        """Units of ``INSTRUMENT.COLUMN[.axis]``; records an error and returns None if unknown."""
        v = node.value
        if not isinstance(v, str) or "." not in v:
            self.errors.append(InputError(f"expected INSTRUMENT.COLUMN such as tvac.air_temp, got {v!r}", node.location, "signal"))
            return None
        inst = v.split(".", 1)[0]
        if inst not in doc.instruments:
            self.errors.append(InputError(f"instrument {inst!r} is not in the procedure's instruments list ({', '.join(sorted(doc.instruments))})", node.location, "signal"))
            return None
        try:
            return signal_units(v, self.kinds.get(inst), self.signals.get(inst))
        except KeyError as exc:
            self.errors.append(InputError(str(exc.args[0]), node.location, "signal"))
            return None

    # ---- blocks -------------------------------------------------------------------------------
    def _block_fields(self, body: Node, stype: str, path: str, env: dict[str, Node]) -> Fields | None:
        if not isinstance(body.value, dict):
            self.errors.append(InputError(f"step {path} ({stype}): expected a mapping of fields", body.location, stype))
            return None
        return Fields(body, f"step {path} ({stype})", self.errors)

    def _steps_of(self, f: Fields, path: str) -> list[Node] | None:
        node = f.node_at("steps")
        if node is None or not isinstance(node.value, list) or not node.value:
            self.errors.append(InputError(f"{f.what}: expected a non-empty list of steps", (node or f.node).location, "steps"))
            return None
        return node.value

    def _block_repeat(self, body, env, doc, path, context, depth, key_loc) -> None:
        f = self._block_fields(body, "repeat", path, env)
        if f is None:
            return
        cnode = f.node_at("count")
        count = None
        if cnode is None:
            self.errors.append(InputError(f"missing required field in {f.what}", body.location, "count"))
        else:
            c = self._subst(cnode, env)
            if c is not None:
                if isinstance(c.value, bool) or not isinstance(c.value, int) or not 1 <= c.value <= 10_000:
                    self.errors.append(InputError(f"expected a whole number of repetitions 1..10000, got {c.value!r}", c.location, "count"))
                else:
                    count = c.value
        steps = self._steps_of(f, path)
        f.check_unknown()
        if count is None or steps is None:
            return
        for k in range(count):
            inner = dict(env, iteration=Node(k + 1, key_loc))
            self.expand(steps, inner, doc, f"{path}.{k + 1}.", _ctx(context, f"iteration={k + 1}"), depth)

    def _block_for_each(self, body, env, doc, path, context, depth, key_loc) -> None:
        f = self._block_fields(body, "for_each", path, env)
        if f is None:
            return
        var = f.get("var", str, required=True)
        if var is not None and (not NAME_RE.match(var) or "-" in var):
            self.errors.append(InputError("expected a variable name of letters, digits and '_'", f.map["var"].location, "var"))
            var = None
        vnode = f.node_at("values")
        values = None
        if vnode is None:
            self.errors.append(InputError(f"missing required field in {f.what}", body.location, "values"))
        else:
            vs = self._subst(vnode, env)
            if vs is not None:
                if not isinstance(vs.value, list) or not vs.value:
                    self.errors.append(InputError("expected a non-empty list of values", vs.location, "values"))
                else:
                    values = vs.value
        steps = self._steps_of(f, path)
        f.check_unknown()
        if var is None or values is None or steps is None:
            return
        for k, value in enumerate(values):
            inner = dict(env, **{var: value})
            self.expand(steps, inner, doc, f"{path}.{k + 1}.", _ctx(context, f"{var}={_text(value.plain())}"), depth)

    def _block_call(self, body, env, doc, path, context, depth, key_loc) -> None:
        before = len(self.errors)
        self._sites.append(key_loc)
        try:
            self._call(body, env, doc, path, context, depth, key_loc)
        finally:
            self._sites.pop()
        # a problem found in the called file may come from this call (its args): name the call too
        self.errors[before:] = [e if e.location is None or str(e.location.file) == str(doc.src.path)
                                else InputError(f"{e.message} {_called_from([key_loc])}", e.location, e.field)
                                for e in self.errors[before:]]

    def _call(self, body, env, doc, path, context, depth, key_loc) -> None:
        f = self._block_fields(body, "call", path, env)
        if f is None:
            return
        rel = f.get("procedure", str, required=True)
        anode = f.node_at("args")
        f.check_unknown()
        if rel is None:
            return
        ploc = f.map["procedure"].location
        try:
            target = _resolve(doc, rel, "procedure", ploc, "procedure")
        except InputError as exc:
            self.errors.append(exc)
            return
        if target is None:
            self.errors.append(InputError("expected a file name without NUL characters", ploc, "procedure"))
            return
        if target in self._call_stack or depth >= MAX_CALL_DEPTH:
            self.errors.append(InputError(f"call of {rel} would recurse ({' -> '.join(p.name for p in self._call_stack)} -> {target.name})", ploc, "procedure"))
            return
        try:
            sub_src = load_yaml(target, "procedure")
        except InputError as exc:
            self.errors.append(InputError(f"called procedure: {exc.one_line()}", ploc, "procedure"))
            return
        sub = _Doc(sub_src, self.errors)
        self.sources[str(target)] = sub_src.text
        self.unit_required_at = self.unit_required_at or sub.unit_required_at
        args: dict[str, Node] = {}
        if anode is not None:
            a = self._subst(anode, env)
            if a is None:
                return
            if not isinstance(a.value, dict):
                self.errors.append(InputError("expected a mapping of parameter names to values", a.location, "args"))
                return
            for k, n in a.value.items():
                if k not in sub.parameters:
                    self.errors.append(InputError(f"{target.name} has no parameter {k!r} (parameters: {', '.join(sub.parameters) or 'none'})", a.key_locations[k], k))
                else:
                    args[k] = n
        inner = {**sub.parameters, **args}
        if sub.steps_node is None or not isinstance(sub.steps_node.value, list):
            return
        self._call_stack.append(target)
        try:
            self.expand(sub.steps_node.value, inner, sub, f"{path}.", _ctx(context, f"call {sub.name}"), depth + 1)
        finally:
            self._call_stack.pop()

    def _block_rate_steps(self, body, env, doc, path, context, depth, key_loc) -> None:
        """Expand a rate schedule: per rate (and its negative with ``alternate``), command the
        rate, settle, record ``dwell`` as window ``{prefix}{rate}``; zero-rate references before
        and after with ``zero_reference``; the table or bench stopped at the end."""
        b = self._subst(body, env)
        if b is None:
            return
        f = self._block_fields(b, "rate_steps", path, env)
        if f is None:
            return
        inst = self._instrument(f.map["instrument"], "instrument", FieldSpec("instrument"), doc) if "instrument" in f.map else None
        f.node_at("instrument")
        if "instrument" not in f.map:
            self.errors.append(InputError(f"missing required field in {f.what}", b.location, "instrument"))
        kind = self.kinds.get(inst or "", "")
        if inst is not None and kind not in ("rate_table", "stepper_bench", ""):
            self.errors.append(InputError(f"instrument {inst!r} is a {kind}; a rate schedule needs a rate_table or a stepper_bench", f.map["instrument"].location, "instrument"))
            inst = None
        board = f.get("record", str, required=True)
        if board is not None and board not in doc.instruments:
            self.errors.append(InputError(f"instrument {board!r} is not in the procedure's instruments list", f.map["record"].location, "record"))
            board = None
        rates = self._rates(f)
        q = {}
        for key, default in (("settle", 0.0), ("dwell", None), ("accel", -1.0)):
            n = f.node_at(key)
            if n is None:
                if default is None:
                    self.errors.append(InputError(f"missing required field in {f.what}", b.location, key))
                q[key] = default
                continue
            try:
                q[key] = to_units(n.value, "deg/s**2" if key == "accel" else "s", n.location, key)
            except InputError as exc:
                self.errors.append(exc)
                q[key] = None
        long_dwell = None
        if (n := f.node_at("long_dwell")) is not None:
            lf = Fields(n, "long_dwell", self.errors)
            below = lf.node_at("below")
            dwell = lf.node_at("dwell")
            lf.check_unknown()
            try:
                if below is None or dwell is None:
                    raise InputError("expected {below: RATE, dwell: DURATION}", n.location, "long_dwell")
                long_dwell = (to_units(below.value, "deg/s", below.location, "below"), to_units(dwell.value, "s", dwell.location, "dwell"))
            except InputError as exc:
                self.errors.append(exc)
        alternate = f.get("alternate", bool, default=False)
        zero_ref = f.get("zero_reference", bool, default=False)
        prefix = f.get("window", str, default="rate_")
        axis = f.get("axis", str, default="z")
        if axis not in ("x", "y", "z"):
            self.errors.append(InputError(f"expected the sensor axis on the turning axis: x, y or z, got {axis!r}", f.map["axis"].location, "axis"))
        f.check_unknown()
        if inst is None or board is None or rates is None or any(q[k] is None for k in ("settle", "dwell", "accel")):
            return
        sched: list[float] = []
        for r in rates:
            sched += [r, -r] if alternate and r != 0 else [r]
        turn = "table_rate" if kind != "stepper_bench" else "bench_rate"
        stop = ("table_stop", {"instrument": inst}) if turn == "table_rate" else ("bench_rate", {"instrument": inst, "rate": 0.0})
        loc = key_loc
        k = 0

        def act(stype: str, fields: dict[str, Any], meta: dict[str, Any] | None = None) -> None:
            nonlocal k
            k += 1
            node = Node({key: Node(val, loc) for key, val in fields.items()}, loc, {key: loc for key in fields})
            self.action(stype, node, doc, f"{path}.{k}", context, loc, meta)

        def reference(tag: str) -> None:
            act(stop[0], stop[1])
            act("record", {"instrument": board, "duration": q["dwell"], "window": f"{prefix}zero_{tag}", "name": f"zero-rate reference ({tag})"},
                {"rate_dps": 0.0, "axis": axis, "reference": tag})

        if zero_ref:
            reference("before")
        for r in sched:
            dwell = long_dwell[1] if long_dwell is not None and abs(r) < long_dwell[0] else q["dwell"]
            fields: dict[str, Any] = {"instrument": inst, "rate": r, "settle": q["settle"], "name": f"rate {r:+g} deg/s"}
            if turn == "table_rate" and q["accel"] >= 0:
                fields["accel"] = q["accel"]
            act(turn, fields)
            act("record", {"instrument": board, "duration": dwell, "window": f"{prefix}{r:+g}", "name": f"record at {r:+g} deg/s"},
                {"rate_dps": r, "axis": axis})
        if zero_ref:
            reference("after")
        else:
            act(stop[0], stop[1])

    def _rates(self, f: Fields) -> list[float] | None:
        n = f.node_at("rates")
        if n is None:
            self.errors.append(InputError(f"missing required field in {f.what}", f.node.location, "rates"))
            return None
        if isinstance(n.value, list):
            out = []
            for item in n.value:
                try:
                    out.append(to_units(item.value, "deg/s", item.location, "rates"))
                except InputError as exc:
                    self.errors.append(exc)
                    return None
            if not out:
                self.errors.append(InputError("expected at least one rate", n.location, "rates"))
                return None
            return out
        if isinstance(n.value, dict):
            rf = Fields(n, "rates", self.errors)
            try:
                start = to_units(rf.node_at("from").value, "deg/s", rf.map["from"].location, "from") if "from" in rf.map else None
                stop = to_units(rf.node_at("to").value, "deg/s", rf.map["to"].location, "to") if "to" in rf.map else None
            except InputError as exc:
                self.errors.append(exc)
                return None
            count = rf.get("count", int, required=True)
            spacing = rf.get("spacing", str, default="linear")
            rf.check_unknown()
            if start is None or stop is None:
                self.errors.append(InputError("expected {from: RATE, to: RATE, count: N, spacing: linear|log}", n.location, "rates"))
                return None
            if count is None or not 1 <= count <= 1000:
                self.errors.append(InputError("expected a count 1..1000", n.location, "count"))
                return None
            if spacing not in ("linear", "log"):
                self.errors.append(InputError(f"expected spacing linear or log, got {spacing!r}", rf.map["spacing"].location, "spacing"))
                return None
            if spacing == "log":
                if start <= 0 or stop <= 0:
                    self.errors.append(InputError("log spacing needs positive rates", n.location, "rates"))
                    return None
                return [start * (stop / start) ** (i / max(count - 1, 1)) for i in range(count)]
            return [start + (stop - start) * i / max(count - 1, 1) for i in range(count)]
        self.errors.append(InputError("expected a list of rates or {from, to, count, spacing}", n.location, "rates"))
        return None


def _resolve(doc: _Doc, rel: str, what: str, loc: Location, fname: str) -> Path | None:
    """``rel`` relative to the directory of ``doc``'s file, absolute; None for a name no file can have.
    :class:`InputError` at ``loc`` when it leaves the procedure's directory tree, the ``configs/``
    next to that directory (a lab's procedures/ beside its configs/) and the project's ``procedures/``
    and ``configs/`` (bench/inputs.py)."""
    if "\0" in rel:
        return None
    base = doc.src.path.parent
    return confined_path(rel, base=base, roots=(*PROCEDURE_ROOTS, base.parent / "configs"), what=what,
                         where="the procedure's directory, the configs/ beside it and the project's procedures/ and configs/",
                         location=loc, field=fname)


def _called_from(sites: list[Location]) -> str:
    return " ".join(f"(called from {s})" for s in reversed(sites))


def _ctx(context: str, more: str) -> str:
    return f"{context}, {more}" if context else more


def _text(value: Any) -> str:
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return str(value)


def _signal_field_units(fname: str, signal_u: str | None, stat_node: Node | None) -> str | None:
    """Units of a band/limit field of a signal step: the signal's units, as a difference where a
    difference is meant (band, std, rms, max_difference of a temperature), per s for slopes."""
    if signal_u is None:
        return None
    stat = stat_node.value if stat_node is not None else None
    if stat == "scale_factor_error":
        return ""
    if stat == "count":
        return ""
    base = signal_u
    diff = fname in ("band", "max_difference") or stat in ("std", "slope")
    if base == "degC" and diff:
        base = TEMPERATURE_DIFFERENCE
    if stat == "slope":
        return f"({base})/s" if base else "1/s"
    return base


def _limits(node: Node | None, kinds: dict[str, str], errors: list[InputError]) -> dict[str, dict[str, tuple[float | None, float | None, Location]]]:
    """``limits: {tvac: {set_point: [-29 degC, 66 degC]}, rate_table: {rate: 10 deg/s}}`` (a single
    value is a symmetric magnitude limit)."""
    from bench.procedure.limits import parse_limits_block

    out: dict[str, dict[str, tuple[float | None, float | None, Location]]] = {}
    if node is None:
        return out
    if not isinstance(node.value, dict):
        errors.append(InputError("expected a mapping of instrument names to limits", node.location, "limits"))
        return out
    for inst, lnode in node.value.items():
        block = parse_limits_block(lnode, kinds.get(inst, inst), f"instrument {inst!r}", errors)
        if block:
            out[inst] = block
    return out


def _interlocks(node: Node | None, instruments: list[str], kinds: dict[str, str], errors: list[InputError],
                signals: dict[str, StreamSignals]) -> list[Interlock]:
    """``interlocks: [{signal: thermocouples.ch101, max: 70 degC}, {stall: acs_board, max_gap: 2 s}, ...]``."""
    out: list[Interlock] = []
    if node is None:
        return out
    if not isinstance(node.value, list):
        errors.append(InputError("expected a list of interlocks", node.location, "interlocks"))
        return out
    for i, n in enumerate(node.value):
        f = Fields(n, f"interlock {i + 1}", errors)
        name = f.get("name", str, default="")
        active = f.get("active", str, default="always")
        if active not in ("always", "vacuum", "streaming"):
            errors.append(InputError(f"expected active: always, vacuum or streaming, got {active!r}", f.map["active"].location, "active"))
        if "stall" in f.map:
            inst = f.get("stall", str)
            gap = None
            if (g := f.node_at("max_gap")) is not None:
                try:
                    gap = to_units(g.value, "s", g.location, "max_gap")
                except InputError as exc:
                    errors.append(exc)
            else:
                errors.append(InputError("a stall interlock needs max_gap (longest gap between frames)", n.location, "max_gap"))
            if inst is not None and inst not in instruments:
                errors.append(InputError(f"instrument {inst!r} is not in the procedure's instruments list", f.map["stall"].location, "stall"))
            f.check_unknown()
            if inst is not None and gap is not None:
                out.append(Interlock(name or f"{inst} stream stalled", inst, None, gap, "streaming", n.location, gap))
            continue
        sig = f.get("signal", str, required=True)
        units = None
        if sig is not None:
            inst = sig.split(".", 1)[0]
            if inst not in instruments:
                errors.append(InputError(f"instrument {inst!r} is not in the procedure's instruments list", f.map["signal"].location, "signal"))
            else:
                try:
                    units = signal_units(sig, kinds.get(inst), signals.get(inst))
                except KeyError as exc:
                    errors.append(InputError(str(exc.args[0]), f.map["signal"].location, "signal"))
        lo = hi = None
        for key in ("min", "max"):
            if (q := f.node_at(key)) is not None and units is not None:
                try:
                    v = to_units(q.value, units, q.location, key)
                except InputError as exc:
                    errors.append(exc)
                    continue
                lo, hi = (v, hi) if key == "min" else (lo, v)
        f.check_unknown()
        if sig is not None and units is not None:
            if lo is None and hi is None:
                errors.append(InputError("an interlock needs min and/or max", n.location, "max"))
                continue
            out.append(Interlock(name or f"{sig} limit", sig, lo, hi, active, n.location))
    return out

