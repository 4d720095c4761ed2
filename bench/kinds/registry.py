"""The installed instrument kinds, found by entry point (group ``bench.instruments``).

As python-can finds its interfaces, bench finds kinds: every installed distribution may declare
entry points in the group ``bench.instruments``, each naming a :class:`~bench.kinds.record.Kind`
record (``dc_supply = "bench_dc_supply:KIND"``). bench's own five are declared the same way in its
pyproject.toml. What the distributions declare is read once and cached on disk until something is
installed or removed (:mod:`bench.kinds.entry_cache`). Loading the records imports only the modules
that hold them (data); drivers, simulators and step handlers are imported by :func:`load` when
first used.

A kind that cannot be loaded (an import error, not a ``Kind``, a name taken twice) does not stop
bench: it is left out and said in :attr:`Registry.problems`, which ``bench instruments kinds``
shows and every "unknown driver" message mentions.
"""

from __future__ import annotations

import importlib
import re
import threading
from typing import Any

from bench.kinds import entry_cache
from bench.kinds.entry_cache import Entry
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
                _registry = discover(entry_cache.entries(GROUP))
    return _registry


def rediscover() -> Registry:
    """The installed kinds read afresh from every distribution's metadata (the entry-point cache
    rewritten: :mod:`bench.kinds.entry_cache`), for this process from now on."""
    global _registry
    reg = discover(entry_cache.entries(GROUP, fresh=True))
    with _lock:
        _registry = reg
    return reg


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


def discover(found: list[Entry] | None = None) -> Registry:
    """Load the record of each entry point of group :data:`GROUP`: ``found`` (distribution, name,
    value), default read from the installed distributions' metadata."""
    if found is None:
        found = entry_cache.scan(GROUP)[0]
    reg = Registry()
    for package, name, value in sorted(found, key=lambda e: (e[0] != "bench", e[0], e[1])):
        key = f"{name} ({package})"
        try:
            record = _load_entry(value)
        except Exception as exc:  # noqa: BLE001 - a broken plug-in must not stop bench
            reg.problems[key] = f"{type(exc).__name__}: {exc}"
            continue
        why = _refuse(name, record, reg)
        if why:
            reg.problems[key] = why
            continue
        reg.kinds[record.name] = _with_package(record, package)
    return reg


_ENTRY_RE = re.compile(r"\s*([\w.]+)\s*(?::\s*([\w.]+)\s*)?(?:\[.*\]\s*)?")
"""An entry point's value: ``module``, ``module:attr.attr``, optionally ``[extras]`` (ignored), as
``importlib.metadata.EntryPoint.load`` reads it."""


def _load_entry(value: str) -> Any:
    """The object an entry point's value names (imported as ``EntryPoint.load`` would)."""
    m = _ENTRY_RE.fullmatch(value)
    if m is None:
        raise ValueError(f"entry point value {value!r} is not 'module:attribute'")
    return load(f"{m[1]}:{m[2] or ''}")


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
    return record.replace(package=package)


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
