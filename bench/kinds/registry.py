"""The installed instrument kinds, found by entry point (group ``bench.instruments``).

As python-can finds its interfaces, bench finds kinds: every installed distribution may declare
entry points in the group ``bench.instruments``, each naming a :class:`~bench.kinds.record.Kind`
record (``dc_supply = "bench_dc_supply:KIND"``). bench's own five are declared the same way in its
pyproject.toml. Loading the records imports only the modules that hold them (data); drivers,
simulators and step handlers are imported by :func:`load` when first used.

A kind that cannot be loaded (an import error, not a ``Kind``, a name taken twice) does not stop
bench: it is left out and said in :attr:`Registry.problems`, which ``bench instruments kinds``
shows and every "unknown driver" message mentions.
"""

from __future__ import annotations

import importlib
import re
import threading
from typing import Any

from bench.kinds.record import Kind, Registry

GROUP = "bench.instruments"
"""The entry-point group of instrument kinds."""
NAME_RE = re.compile(r"[a-z][a-z0-9_]{0,39}")
"""A kind's name: lower case, digits and ``_`` (it is a config's ``driver:`` value)."""

_lock = threading.Lock()
_registry: Registry | None = None
_loaded: dict[str, Any] = {}


def registry() -> Registry:
    """The installed kinds (discovered once per process)."""
    global _registry
    if _registry is None:
        with _lock:
            if _registry is None:
                _registry = discover()
    return _registry


def kinds() -> dict[str, Kind]:
    """Kind name -> record, for every installed kind, in discovery order (bench's own first)."""
    return registry().kinds


def get(name: str) -> Kind | None:
    """The kind ``name``, or None when no installed package declares it."""
    return registry().kinds.get(name)


def standard_kinds() -> dict[str, str]:
    """Instrument name -> kind assumed where nothing says (no lab config; a run file that does not
    record an instrument's kind): each installed kind's ``standard_name`` (configs/sim.yaml's names)."""
    return {k.standard_name: k.name for k in registry().kinds.values() if k.standard_name}


def known() -> str:
    """The installed kinds' names for messages (``acs_board, stepper_bench, ...``), with what could
    not be loaded."""
    reg = registry()
    text = ", ".join(reg.kinds) or "none"
    if reg.problems:
        text += f"; not loaded: {', '.join(reg.problems)} (bench instruments kinds says why)"
    return text


def discover() -> Registry:
    """Read the entry points of group :data:`GROUP` and load each record."""
    from importlib.metadata import entry_points

    reg = Registry()
    names: dict[int, str] = {}  # a distribution's name parses its METADATA: once per distribution
    found = [(_dist_name(ep, names), ep) for ep in entry_points(group=GROUP)]
    for package, ep in sorted(found, key=lambda pe: (pe[0] != "bench", pe[0], pe[1].name)):
        key = f"{ep.name} ({package})"
        try:
            record = ep.load()
        except Exception as exc:  # noqa: BLE001 - a broken plug-in must not stop bench
            reg.problems[key] = f"{type(exc).__name__}: {exc}"
            continue
        why = _refuse(ep.name, record, reg)
        if why:
            reg.problems[key] = why
            continue
        reg.kinds[record.name] = _with_package(record, package)
    return reg


def _dist_name(ep: Any, names: dict[int, str]) -> str:
    """The name of the distribution that declares ``ep`` (``"?"`` if none), cached in ``names``."""
    dist = getattr(ep, "dist", None)
    if id(dist) not in names:
        names[id(dist)] = getattr(dist, "name", "") or "?"
    return names[id(dist)]


def _refuse(ep_name: str, record: Any, reg: Registry) -> str:
    if not isinstance(record, Kind):
        return f"{ep_name!r} names a {type(record).__name__}, not a bench.kinds.Kind"
    if record.name != ep_name:
        return f"entry point {ep_name!r} names kind {record.name!r} (they must be the same)"
    if not NAME_RE.fullmatch(record.name):
        return f"kind name {record.name!r}: expected lower-case letters, digits and '_' (at most 40)"
    if record.name in reg.kinds:
        return f"kind {record.name!r} is already declared by {reg.kinds[record.name].package}"
    return ""


def _with_package(record: Kind, package: str) -> Kind:
    from dataclasses import replace

    return replace(record, package=package)


def load(dotted: str) -> Any:
    """The object a dotted path ``"package.module:attribute"`` names (imported once, then cached)."""
    obj = _loaded.get(dotted)
    if obj is None:
        module, _, attr = dotted.partition(":")
        obj = importlib.import_module(module)
        for part in attr.split(".") if attr else ():
            obj = getattr(obj, part)
        _loaded[dotted] = obj
    return obj


def set_registry(reg: Registry | None) -> None:
    """Replace the discovered kinds (tests: a registry with a kind that is not installed); None
    discovers them again on next use."""
    global _registry
    with _lock:
        _registry = reg
