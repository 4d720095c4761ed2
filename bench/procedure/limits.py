"""Safety limits of the hardware, checked on every step before a run starts.

Three layers, the narrowest wins: the defaults below (what the instrument class can take), the
lab config's ``limits:`` per instrument (this lab's hardware), and the procedure's ``limits:``
(this test). A set point, rate, acceleration or tilt outside them is an input error located at
the step, so nothing moves.
"""

from __future__ import annotations

import math
from typing import Any

from bench.errors import InputError
from bench.kinds import registry
from bench.procedure.schema import kind_step
from bench.units import to_units
from bench.yamlsrc import Node


def limit_units(kind: str) -> dict[str, str]:
    """Limited quantity -> units of kind ``kind`` (its record's ``limits``; empty for an unknown kind)."""
    k = registry.get(kind)
    return {lim.quantity: lim.units for lim in k.limits} if k is not None else {}


LIMIT_REL_TOL = 1e-9
"""Relative tolerance of every limit check: a value within this fraction of a limit (or within
:data:`LIMIT_ABS_TOL` of a limit at or near 0) is at the limit, not beyond it. Unit conversion is
not exact in binary floating point: ``122 degF`` is 50.000000000000014 degC, and must pass a 50 degC
limit as ``50 degC`` does. Far below any instrument's resolution (a 100 degC limit: 1e-7 degC)."""
LIMIT_ABS_TOL = 1e-12
"""Absolute tolerance of every limit check, in the limit's units (for limits at 0)."""


def outside_limits(value: float, lo: float | None, hi: float | None) -> bool:
    """True when ``value`` is below ``lo`` or above ``hi`` (None: open end) by more than the
    rounding of a unit conversion (:data:`LIMIT_REL_TOL`): the one comparison of a value with its
    limits, for the steps of a procedure and the config's safe values alike."""
    def beyond(v: float, bound: float) -> bool:
        return not math.isclose(v, bound, rel_tol=LIMIT_REL_TOL, abs_tol=LIMIT_ABS_TOL)

    return (lo is not None and value < lo and beyond(value, lo)) or (hi is not None and value > hi and beyond(value, hi))


def default_limits(kind: str) -> dict[str, tuple[float | None, float | None]]:
    """Limited quantity -> the (low, high) the instrument class can take, as its kind declares."""
    k = registry.get(kind)
    return {lim.quantity: lim.default for lim in k.limits if lim.default != (None, None)} if k is not None else {}


def step_limits(stype: str) -> list[tuple[str, str, str]]:
    """(field, kind, limited quantity) of each field of step type ``stype`` its kind limits."""
    found = kind_step(stype)
    if found is None:
        return []
    kind, d = found
    return [(fname, kind.name, q) for fname, q in d.limits]


def parse_limit(node: Node, units: str, name: str, errors: list[InputError], magnitude: str = "") -> tuple[float | None, float | None] | None:
    """``[lo, hi]`` (``null`` for an open end) or, for a quantity with a ``magnitude`` (``signed``:
    -v..v, ``positive``: 0..v; ``Limit.magnitude``), a single value."""
    try:
        if isinstance(node.value, list):
            if len(node.value) != 2:
                raise InputError(f"expected [low, high] such as [-29 degC, 66 degC], got {len(node.value)} values", node.location, name)
            lo, hi = (None if n.value is None else to_units(n.value, units, n.location, name) for n in node.value)
            if lo is not None and hi is not None and lo > hi:
                raise InputError(f"low limit {lo:g} is above high limit {hi:g}", node.location, name)
            return lo, hi
        if magnitude:
            v = abs(to_units(node.value, units, node.location, name))
            return (-v, v) if magnitude == "signed" else (0.0, v)
        raise InputError(f"expected [low, high] for {name} (null for an open end)", node.location, name)
    except InputError as exc:
        errors.append(exc)
        return None


def parse_limits_block(node: Node, kind: str, what: str, errors: list[InputError]) -> dict[str, tuple]:
    """A ``{quantity: limit, ...}`` mapping for an instrument with driver ``kind`` (lab config or
    procedure); quantity -> (low, high, location). Problems are appended to ``errors``."""
    k = registry.get(kind)
    if k is None or not k.limits:
        with_limits = [n for n, kk in registry.kinds().items() if kk.limits]
        errors.append(InputError(f"no limits can be set for {what} (limits exist for: {', '.join(with_limits)})", node.location, "limits"))
        return {}
    units = {lim.quantity: lim for lim in k.limits}
    if not isinstance(node.value, dict):
        errors.append(InputError("expected a mapping of quantities to limits", node.location, "limits"))
        return {}
    out: dict[str, tuple] = {}
    for q, qnode in node.value.items():
        if q not in units:
            errors.append(InputError(f"unknown limit {q!r} for {what} (expected one of: {', '.join(units)})", node.key_locations[q], q))
            continue
        lim = parse_limit(qnode, units[q].units, q, errors, units[q].magnitude)
        if lim is not None:
            out[q] = (*lim, qnode.location)
    return out


def effective_limits(kind: str, *layers: dict[str, tuple[Any, ...]]) -> dict[str, tuple[float | None, float | None, str]]:
    """Intersection of the default limits of ``kind`` with each layer (quantity -> (lo, hi, ...)).

    Returns quantity -> (lo, hi, source) where source names the layer that set the binding bound.
    """
    out: dict[str, tuple[float | None, float | None, str]] = {q: (lo, hi, f"{kind} default") for q, (lo, hi) in default_limits(kind).items()}
    for layer_name, layer in zip(("lab config", "procedure"), layers):
        for q, bounds in layer.items():
            lo, hi = bounds[0], bounds[1]
            cur_lo, cur_hi, src = out.get(q, (None, None, ""))
            new_lo = cur_lo if lo is None or (cur_lo is not None and cur_lo >= lo) else lo
            new_hi = cur_hi if hi is None or (cur_hi is not None and cur_hi <= hi) else hi
            out[q] = (new_lo, new_hi, layer_name if (new_lo, new_hi) != (cur_lo, cur_hi) else src)
    return out


def check_step_limits(steps, kinds: dict[str, str], config_limits: dict[str, dict[str, tuple[Any, ...]]],
                      procedure_limits: dict[str, dict[str, tuple[Any, ...]]]) -> list[InputError]:
    """One located error per step value outside the effective limits of its instrument."""
    errors: list[InputError] = []
    cache: dict[str, dict[str, tuple[float | None, float | None, str]]] = {}
    for step in steps:
        for fname, kind, quantity in step_limits(step.type):
            if fname not in step.params:
                continue
            inst = step.params.get("instrument", "")
            if kinds.get(inst, kind) != kind:
                continue
            if inst not in cache:
                cache[inst] = effective_limits(kind, config_limits.get(inst, {}), procedure_limits.get(inst, {}))
            bounds = cache[inst].get(quantity)
            if bounds is None:
                continue
            lo, hi, src = bounds
            v = float(step.params[fname])
            units = limit_units(kind)[quantity]
            if outside_limits(v, lo, hi):
                rng = f"{'-inf' if lo is None else f'{lo:g}'}..{'inf' if hi is None else f'{hi:g}'} {units}"
                errors.append(InputError(f"step {step.path} ({step.type}): {v:g} {units} is outside the {inst} {quantity} limits {rng} ({src})",
                                         step.location, fname))
    return errors


