"""One simulated instrument powering another: a supply's output and a unit's power terminals.

The lab config says which output powers what (``powered_by: {instrument: psu, output: 1}``, any
kinds); :func:`wire_power` connects the two simulators when both are built. The protocol names no
kind, and is event-driven (both sides run on the one clock of the simulated lab):

* a **source** (a supply's output) tells its load every change of its voltage when it happens
  (:meth:`PowerLoad.supply_changed`), answers :meth:`PowerSource.volts_at`, and is told when the
  load's demand changes (:meth:`PowerSource.load_changed`: it checks its current limit and
  protection then);
* a **load** (a unit under test) says what it draws (:meth:`PowerLoad.current_a`, at a run time
  and a voltage) and runs only while its source powers it within its range (:class:`PowerInput`
  keeps the book: powered spells, the reset at each power-on).

A load not connected to any source is powered, as every simulator was before sources existed.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Callable, Protocol

if TYPE_CHECKING:  # pragma: no cover
    from bench.config import LabConfig
    from bench.sim.factory import SimInstrument


class PowerSource(Protocol):
    def volts_at(self, t: float) -> float:
        """Voltage at the output's terminals at run time ``t`` (s), V (0 when off or tripped)."""

    def attach(self, load: "PowerLoad") -> None:
        """From now on ``load`` draws from this output."""

    def load_changed(self, t: float) -> None:
        """The load's demand changed at run time ``t`` (it switched something on or off)."""


class PowerLoad(Protocol):
    def current_a(self, t: float, volts: float) -> float:
        """Current drawn at run time ``t`` (s) when fed ``volts`` (V), A."""

    def connect(self, source: PowerSource) -> None:
        """From now on the device runs only while ``source`` powers it."""

    def supply_changed(self, t: float, volts: float) -> None:
        """The source's voltage became ``volts`` (V) at run time ``t`` (s)."""


class PowerInput:
    """The power terminals of a simulated device: its supply range ``v_min``..``v_max`` (V), the
    time it takes to boot after power comes within range (``boot_s``), and what it draws
    (``draw(t, volts, since) -> A``, ``since`` the run time its present powered spell began).
    ``on_change(t, powered)`` is called when power comes or goes (the device resets itself there).

    Without a source the device is powered from -inf. With one, it is powered from the first
    :meth:`supply_changed` into range until one out of range."""

    def __init__(self, v_min: float, v_max: float, draw: Callable[[float, float, float], float], *,
                 boot_s: float = 0.0, on_change: Callable[[float, bool], None] | None = None):
        if not 0 <= v_min < v_max:
            raise ValueError(f"supply range {v_min}..{v_max} V")
        self.v_min = v_min
        self.v_max = v_max
        self.boot_s = boot_s
        self.draw = draw
        self.on_change = on_change
        self.source: PowerSource | None = None
        self.spell: float | None = -math.inf
        """Run time the present powered spell began (None: unpowered)."""

    def in_range(self, volts: float) -> bool:
        return self.v_min <= volts <= self.v_max

    # ---- PowerLoad --------------------------------------------------------------------------
    def connect(self, source: PowerSource) -> None:
        self.source = source
        self.spell = None
        if self.on_change is not None:
            self.on_change(-math.inf, False)

    def supply_changed(self, t: float, volts: float) -> None:
        if self.spell is None and self.in_range(volts):
            self.spell = t
            if self.on_change is not None:
                self.on_change(t, True)
        elif self.spell is not None and not self.in_range(volts):
            self.spell = None
            if self.on_change is not None:
                self.on_change(t, False)

    def current_a(self, t: float, volts: float) -> float:
        if self.spell is None or not self.in_range(volts):
            return 0.0
        return self.draw(t, volts, self.spell)

    # ---- the device's side ------------------------------------------------------------------
    def powered(self, t: float) -> bool:
        """Powered (maybe still booting) at run time ``t``."""
        return self.spell is not None and t >= self.spell

    def running(self, t: float) -> bool:
        """Powered and booted at run time ``t``: it answers and works."""
        return self.spell is not None and t >= self.spell + self.boot_s

    def demand_changed(self, t: float) -> None:
        """The device switched something at run time ``t``: its source checks its limits."""
        if self.source is not None:
            self.source.load_changed(t)


def wire_power(config: "LabConfig", sims: "dict[str, SimInstrument]", clock) -> None:
    """Connect every ``powered_by`` of ``config`` whose two instruments are both among ``sims``;
    ``ValueError`` when one side has no power terminals of that name."""
    for name, inst in config.instruments.items():
        link = inst.powered_by
        if link is None or name not in sims or link.instrument not in sims:
            continue
        source = sims[link.instrument].power_outputs.get(link.output)
        load = sims[name].power_input
        if source is None:
            raise ValueError(f"instrument {link.instrument!r}'s simulator has no output {link.output!r} to power {name!r} with")
        if load is None:
            raise ValueError(f"instrument {name!r}'s simulator cannot be powered by another (it has no power input)")
        load.connect(source)
        source.attach(load)
