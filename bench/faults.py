"""Random and scheduled fault injection into a dry-run, through the simulators' fault hooks.

``bench run ... --sim --inject-faults SPEC`` and ``bench soak`` use this module. A fault *class*
(:data:`FAULT_CLASSES`) names one thing that goes wrong on a real bench (a serial cable pulled, a
Modbus timeout, a runaway chamber, a full disk...) and how to make the simulated lab do it; the
runner meets the fault exactly as on hardware (same drivers, same bytes), and its documented
reaction (``docs/reliability.md``) follows.

SPEC (``docs/reliability.md``, "Fault injection"): comma-separated items

* ``rate=R`` faults per hour of run time (Poisson arrivals; ``R/h`` also accepted), default 0;
* ``seed=S`` for the arrival times, the classes drawn and their parameters, default 0;
* ``classes=A+B+...`` the classes to draw from (default: every class that applies to the
  procedure's instruments), or a *severity* ``transient`` / ``hazard``;
* ``NAME@TIME[/DURATION]`` one fault of class NAME at run time TIME (``120 s``, ``2min``, a bare
  number in s), lasting DURATION (transient classes; default: random in the class's range).

Example: ``--inject-faults rate=6/h,seed=3,classes=transient`` or
``--inject-faults serial_unplug@300s/5s,chamber_runaway@2h``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from bench.errors import InputError
from bench.kinds.record import LINK_WORDS

if TYPE_CHECKING:  # pragma: no cover
    from bench.lab import Lab
    from bench.record import RunRecorder

Clear = Callable[[], None]


@dataclass(frozen=True)
class FaultClass:
    """One kind of fault. ``severity``: ``transient`` (the documented reaction is to reconnect and
    continue, unless the gap breaks the procedure's own data requirements such as a stall limit) or
    ``hazard`` (the documented reaction is an abort to the safe state). ``kinds``: driver kinds of
    the instruments it can hit (``recorder`` for the run file). ``duration_s``: range of the random
    duration of a transient fault (None: it lasts until the run ends). ``explains``: words of which
    an abort reason must contain one (with the instrument's name) to count as caused by it."""

    name: str
    severity: str
    kinds: tuple[str, ...]
    description: str
    duration_s: tuple[float, float] | None
    explains: tuple[str, ...]
    start: Callable[["FaultTarget", np.random.Generator, float | None], Clear | None]


@dataclass
class FaultTarget:
    """What a fault acts on: instrument ``name`` of ``lab`` (its simulator in ``lab.sims``), the
    run's ``recorder``."""

    name: str
    lab: "Lab"
    recorder: "RunRecorder"

    @property
    def sim(self) -> Any:
        return self.lab.sims[self.name]


def _link(target: FaultTarget, sub: str = ""):
    return target.sim.serial[sub]


def serial_fault(fault: str, sub: str = "", **params) -> Callable[[FaultTarget, np.random.Generator, float | None], Clear | None]:
    """A fault class's start: inject ``fault`` into the target's serial link ``sub`` (``""``: its own;
    a chamber's ``gauge``); ``params`` values may be functions of the class's random generator."""
    def start(t: FaultTarget, rng: np.random.Generator, duration: float | None) -> Clear | None:
        link = _link(t, sub)
        extra = {k: (v(rng) if callable(v) else v) for k, v in params.items()}
        link.inject(fault, duration_s=duration, **extra)  # the link ends it on the run's clock
        return None
    return start


def device_fault(fault: str, on: Callable[[FaultTarget], Any] = lambda t: t.sim.device, **params) -> Callable[..., Clear | None]:
    """A fault class's start: the target's simulator ``inject``s ``fault`` (cleared after a transient
    class's duration)."""
    def start(t: FaultTarget, rng: np.random.Generator, duration: float | None) -> Clear | None:
        dev = on(t)
        dev.inject(fault, **{k: (v(rng) if callable(v) else v) for k, v in params.items()})
        return dev.clear_faults if duration is not None else None
    return start


def _disk_full(t: FaultTarget, rng: np.random.Generator, duration: float | None) -> Clear | None:
    rec = t.recorder
    # the disk has filled up to just short of what the recorder needs for its next write plus the
    # reserve it keeps for finalising: it must refuse new rows and still keep every row it accepted
    rec.free_bytes = lambda d: rec.space_needed() - 1
    return None


_CORE: list[tuple[float, FaultClass]] = [
    (1, FaultClass("serial_unplug", "transient", (), "serial cable pulled and plugged back in", (1.0, 8.0),
                   LINK_WORDS, serial_fault("disconnect"))),
    (2, FaultClass("serial_noise", "transient", (), "a burst of line noise (16-256 random bytes), once", None,
                   LINK_WORDS + ("garbled", "CRC"), serial_fault("garbage", count=lambda r: int(r.integers(16, 257))))),
    (3, FaultClass("serial_corrupt", "transient", (), "bit errors on the line (p = 1e-3 per byte)", (2.0, 20.0),
                   LINK_WORDS + ("garbled", "CRC"), serial_fault("corrupt", p=1e-3))),
    (10, FaultClass("stream_stall", "transient", (), "the device hangs: receives but sends nothing", (1.0, 20.0),
                    LINK_WORDS, serial_fault("stall"))),
    (15, FaultClass("disk_full", "hazard", ("recorder",), "the disk holding the run file fills up", None,
                    ("disk", "recorder", "run file", "writing"), _disk_full)),
]
"""The core's fault classes (rank, class): a serial link's (each kind names those it suffers,
``Kind.serial_faults``) and the recorder's. The kinds add their own (``Kind.faults``)."""


def fault_classes() -> dict[str, FaultClass]:
    """Every fault class, by name, in one order (the ranks: a seeded soak draws the same classes
    whatever is installed besides): the core's and every installed kind's. Durations in s of run time."""
    from dataclasses import replace

    from bench.kinds import registry

    ranked: list[tuple[float, str, FaultClass]] = []
    installed = registry.kinds().values()
    for rank, cls in _CORE:
        kinds = cls.kinds or tuple(k.name for k in installed if cls.name in k.serial_faults)
        ranked.append((rank, cls.name, replace(cls, kinds=kinds)))
    for k in installed:
        for d in k.faults:
            start = (lambda path: lambda t, rng, duration: registry.load(path)(t, rng, duration))(d.start)
            ranked.append((d.rank, d.name, FaultClass(d.name, d.severity, (k.name,), d.description, d.duration_s, d.explains, start)))
    return {cls.name: cls for _, _, cls in sorted(ranked, key=lambda r: (r[0], r[1]))}


def __getattr__(name: str):  # noqa: ANN202 - the module's lazy constant
    if name == "FAULT_CLASSES":
        return fault_classes()
    raise AttributeError(name)


@dataclass
class ScheduledFault:
    """Fault ``cls`` on instrument ``target`` at run time ``t_s`` for ``duration_s`` (None: to the end)."""

    t_s: float
    cls: FaultClass
    target: str
    duration_s: float | None
    seed: int
    injected: bool = False
    cleared: bool = False
    clear: Clear | None = None
    error: str = ""


@dataclass
class FaultSpec:
    """A parsed ``--inject-faults`` SPEC (see the module docstring)."""

    rate_per_h: float = 0.0
    seed: int = 0
    classes: list[str] = field(default_factory=list)
    at: list[tuple[float, str, float | None]] = field(default_factory=list)
    """Explicit faults: (run time s, class name, duration s or None for the class's random one)."""


def parse_fault_spec(text: str, where: str = "--inject-faults") -> FaultSpec:
    """Parse SPEC; :class:`InputError` (field ``where``) says what was expected."""
    from bench.units import to_units

    spec = FaultSpec()
    classes = fault_classes()
    known = ", ".join(classes)
    items = [i.strip() for i in text.split(",") if i.strip()]
    if not items:
        raise InputError("empty fault spec; expected e.g. 'rate=3/h,seed=1' or 'serial_unplug@300s'", field=where)
    for item in items:
        if "@" in item:
            name, _, when = item.partition("@")
            name = name.strip()
            if name not in classes:
                raise InputError(f"unknown fault class {name!r} (known: {known})", field=where)
            when, _, lasting = when.partition("/")
            try:
                t = to_units(when.strip(), "s", field=where)
                d = to_units(lasting.strip(), "s", field=where) if lasting.strip() else None
            except InputError as exc:
                raise InputError(f"{item!r}: expected NAME@TIME[/DURATION] such as serial_unplug@300s/5s ({exc.message})",
                                 field=where) from None
            if not (math.isfinite(t) and t >= 0) or (d is not None and not (math.isfinite(d) and d >= 0)):
                raise InputError(f"{item!r}: times must be >= 0 s", field=where)
            if d is not None and classes[name].duration_s is None:
                raise InputError(f"{item!r}: {name} has no duration (it happens once or lasts to the end of the run)", field=where)
            spec.at.append((t, name, d))
            continue
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep:
            raise InputError(f"{item!r}: expected key=value (rate, seed, classes) or NAME@TIME", field=where)
        if key == "rate":
            m = re.fullmatch(r"([0-9.eE+-]+)\s*(/\s*h)?", value)
            try:
                spec.rate_per_h = float(m.group(1)) if m else float("nan")
            except ValueError:
                spec.rate_per_h = float("nan")
            if not (math.isfinite(spec.rate_per_h) and spec.rate_per_h >= 0):
                raise InputError(f"rate: expected faults per hour such as 3/h, got {value!r}", field=where)
        elif key == "seed":
            try:
                spec.seed = int(value)
            except ValueError:
                raise InputError(f"seed: expected an integer, got {value!r}", field=where) from None
        elif key == "classes":
            for name in [n.strip() for n in value.split("+") if n.strip()]:
                if name in ("transient", "hazard"):
                    spec.classes.extend(c.name for c in classes.values() if c.severity == name)
                elif name in classes:
                    spec.classes.append(name)
                else:
                    raise InputError(f"unknown fault class {name!r} (known: transient, hazard, {known})", field=where)
        else:
            raise InputError(f"unknown key {key!r} (expected rate, seed, classes or NAME@TIME)", field=where)
    return spec


def targets_for(cls: FaultClass, kinds: dict[str, str]) -> list[str]:
    """Instrument names (or ``recorder``) a fault of ``cls`` can hit in a lab of ``kinds``."""
    if "recorder" in cls.kinds:
        return ["recorder"]
    return sorted(n for n, k in kinds.items() if k in cls.kinds)


def plan_faults(spec: FaultSpec, kinds: dict[str, str], duration_s: float, *, t0_s: float = 0.0,
                rng: np.random.Generator | None = None) -> list[ScheduledFault]:
    """The faults to inject into a run of ``duration_s`` (s) on instruments ``kinds`` (name -> driver).

    Random arrivals (Poisson, ``spec.rate_per_h``) fall in [t0_s, t0_s + duration_s) of a longer
    timeline (a soak) and are returned in run time; only classes with a target in this lab are drawn.
    """
    rng = rng if rng is not None else np.random.default_rng(spec.seed)
    classes = fault_classes()
    out: list[ScheduledFault] = []
    for t, name, duration in spec.at:
        f = _schedule(classes[name], t, kinds, rng, explicit=True)
        if f is not None and duration is not None:
            f.duration_s = duration
        out.append(f)
    names = spec.classes or list(classes)
    usable = [classes[n] for n in dict.fromkeys(names) if targets_for(classes[n], kinds)]
    if spec.rate_per_h > 0 and usable and duration_s > 0:
        t = rng.exponential(3600.0 / spec.rate_per_h)
        while t < duration_s:
            cls = usable[int(rng.integers(len(usable)))]
            out.append(_schedule(cls, t, kinds, rng))
            t += rng.exponential(3600.0 / spec.rate_per_h)
    return sorted((f for f in out if f is not None), key=lambda f: f.t_s)


def _schedule(cls: FaultClass, t: float, kinds: dict[str, str], rng: np.random.Generator, explicit: bool = False) -> ScheduledFault | None:
    targets = targets_for(cls, kinds)
    if not targets:
        if explicit:
            raise InputError(f"fault class {cls.name!r} hits {', '.join(cls.kinds)}, which this procedure does not use",
                             field="--inject-faults")
        return None
    target = targets[int(rng.integers(len(targets)))]
    duration = None if cls.duration_s is None else float(rng.uniform(*cls.duration_s))
    return ScheduledFault(float(t), cls, target, duration, int(rng.integers(2**31)))


class FaultInjector:
    """A progress sink that injects scheduled faults when the run reaches their time and ends
    transient ones after their duration; every other call goes to ``inner``.

    The runner reports run time to its progress sink at every drain period and at every
    reconnection attempt, so faults start and end within one drain period (5 s in a dry-run) of
    their scheduled time. Each injection is recorded as an event ``fault_injected`` (source: the
    target) so the run file says what was done to it.
    """

    def __init__(self, inner: Any, faults: list[ScheduledFault], lab: "Lab", recorder: "RunRecorder"):
        self.inner = inner
        self.faults = sorted(faults, key=lambda f: f.t_s)
        self.lab = lab
        self.recorder = recorder

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def start(self, procedure, total_s):
        self.inner.start(procedure, total_s)

    def step(self, n, total, step):
        self.inner.step(n, total, step)

    def stop(self, run_time_s):
        self.inner.stop(run_time_s)

    def message(self, text):
        self.inner.message(text)

    def advance(self, run_time_s: float, readings: str = "") -> None:
        self.apply(run_time_s)
        self.inner.advance(run_time_s, readings)

    def apply(self, run_time_s: float) -> None:
        """Start the faults due at ``run_time_s`` (s) and clear the transient ones that are over."""
        for f in self.faults:
            if not f.injected and run_time_s + 1e-9 >= f.t_s:
                self._inject(f, run_time_s)
            if f.injected and not f.cleared and f.clear is not None and f.duration_s is not None \
                    and run_time_s + 1e-9 >= f.t_s + f.duration_s:
                f.cleared = True
                try:
                    f.clear()
                except Exception as exc:  # noqa: BLE001 - a simulator that cannot clear keeps the fault
                    f.error = f"clear failed: {exc}"

    def _inject(self, f: ScheduledFault, now: float) -> None:
        f.injected = True
        f.t_s = now
        try:
            f.clear = f.cls.start(FaultTarget(f.target, self.lab, self.recorder), np.random.default_rng(f.seed), f.duration_s)
        except Exception as exc:  # noqa: BLE001 - e.g. a hook the simulator lacks: record, go on
            f.error = f"{type(exc).__name__}: {exc}"
        dur = (" until the run ends" if f.cls.severity == "hazard" else "") if f.duration_s is None else f" for {f.duration_s:.1f} s"
        msg = f"injected {f.cls.name} ({f.cls.description}){dur}" + (f"; FAILED: {f.error}" if f.error else "")
        try:
            self.recorder.event("fault_injected", f.target, msg, t_s=now)
        except Exception:  # noqa: BLE001 - e.g. disk_full refusing the write: the run finds out itself
            pass
        self.inner.message(f"{f.target}: {msg}")
