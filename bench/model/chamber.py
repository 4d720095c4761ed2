"""The thermal-vacuum chamber's model: its parameters and the laws the simulator and the planner share.

The simulated chamber (:mod:`bench.sim.chamber`, whose docstring and ``docs/simulation.md`` give the
sources of every default) integrates these laws in run time; ``bench plan`` uses their closed forms
to estimate how long a procedure's chamber waits take (:mod:`bench.procedure.estimate`). Both take
the numbers from one :class:`ChamberParams`, the model layer below both.

Laws (units in the names: °C, s, Torr):

* gas coupling: ``f = P / (P + conduction_transition_torr)`` of the ambient-pressure coupling is
  left at pressure P (1 at atmosphere, 0 in vacuum);
* air: slews toward the working set point at the heater's or cooler's limit (ambient and vacuum
  rates interpolated by ``f``) while more than ``control_band_c`` away, then approaches it
  exponentially with the time constant ``control_band_c / slew rate``;
* unit (mount, then sensor die): first order behind the air, conductance
  ``f / tau_ambient_s + (1 - f) / tau_vacuum_s``; the powered die sits ``self_heating_c`` above;
* pressure: roughing ``dP/dt = -P / tau_rough_s`` to ``crossover_torr``, then the turbo's
  ``dP/dt = -P² / turbo_k_torr_s`` down to ``ultimate_torr``; venting with the pumps off,
  ``dP/dt = (760 - P) / tau_vent_s``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from bench.params import dataclass_from_dict

ATMOSPHERE_TORR = 760.0


@dataclass
class ChamberParams:
    """Parameters of the chamber model; units in the names (sources: :mod:`bench.sim.chamber`)."""

    initial_temp_c: float = 20.0
    set_point_low_c: float = -40.0
    set_point_high_c: float = 100.0
    heat_rate_ambient_c_per_min: float = 0.62
    cool_rate_ambient_c_per_min: float = 0.47
    rate_vacuum_c_per_min: float = 0.20
    control_band_c: float = 2.0
    tau_ambient_s: float = 100.0
    tau_vacuum_s: float = 1800.0
    conduction_transition_torr: float = 1.0
    self_heating_c: float = 4.0
    tau_rough_s: float = 25.0
    crossover_torr: float = 0.1
    turbo_k_torr_s: float = 0.29
    ultimate_torr: float = 1e-7
    leak_per_s: float = 6.3e-5
    vent_equilibrium_torr: float = 190.0
    history_s: float = 7200.0

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "ChamberParams":
        """Build from a mapping; unknown keys raise ``KeyError`` naming them."""
        return dataclass_from_dict(cls, data)

    @property
    def tau_vent_s(self) -> float:
        """Vent time constant (s) that makes pump-on-with-vent-open settle at the equilibrium."""
        p = self.vent_equilibrium_torr
        return self.tau_rough_s * (ATMOSPHERE_TORR - p) / p

    def fraction_ambient(self, pressure_torr: float) -> float:
        """Share ``f`` (0..1) of the ambient-pressure gas coupling left at ``pressure_torr``."""
        return pressure_torr / (pressure_torr + self.conduction_transition_torr)

    def slew_rate_c_per_s(self, heating: bool, f: float) -> float:
        """Fastest air temperature change (°C/s) of the heater (``heating``) or the cooler at gas
        coupling ``f`` (:meth:`fraction_ambient`)."""
        ambient = self.heat_rate_ambient_c_per_min if heating else self.cool_rate_ambient_c_per_min
        return (f * ambient + (1 - f) * self.rate_vacuum_c_per_min) / 60.0

    def unit_conductance_per_s(self, f: float) -> float:
        """Coupling (1/s) of the unit (mount, die) to the air at gas coupling ``f``."""
        return f / self.tau_ambient_s + (1 - f) / self.tau_vacuum_s


def pump_down_time_s(p: ChamberParams, to_torr: float, from_torr: float = ATMOSPHERE_TORR) -> float:
    """Run time (s) the pumps take from ``from_torr`` to ``to_torr`` (roughing, then the turbo's
    1/t law); ``inf`` at or below the ultimate pressure, 0 if already there."""
    if to_torr >= from_torr:
        return 0.0
    if to_torr <= p.ultimate_torr:
        return math.inf
    t = 0.0
    if from_torr > p.crossover_torr:
        t += p.tau_rough_s * math.log(from_torr / max(to_torr, p.crossover_torr))
        from_torr = p.crossover_torr
    if to_torr < from_torr:
        t += p.turbo_k_torr_s * (1.0 / to_torr - 1.0 / from_torr)
    return t


def vent_time_s(p: ChamberParams, to_torr: float, from_torr: float) -> float:
    """Run time (s) venting with the pumps off takes from ``from_torr`` up to ``to_torr``; ``inf``
    at or above atmosphere, 0 if already there."""
    if to_torr <= from_torr:
        return 0.0
    if to_torr >= ATMOSPHERE_TORR:
        return math.inf
    return p.tau_vent_s * math.log((ATMOSPHERE_TORR - from_torr) / (ATMOSPHERE_TORR - to_torr))
