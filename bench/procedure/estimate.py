"""How long a procedure takes: an estimate per step from the lab model (``bench plan``, ``bench
validate``, the progress ETA of ``bench run``).

Timed steps count their durations (``record``, ``wait``, settle times, vibration profiles). Waits
for the lab are estimated from the lab model of :mod:`bench.model` (the numbers the simulator runs
on; a lab config's ambient temperature and instrument drivers when one is given), following the
procedure's steps in order so that each wait starts from where the previous steps left the lab:

* ``set_temperature`` with ``wait``: the air slews at the heater's or cooler's rate (or the
  ``ramp``, if slower) and approaches the set point exponentially inside the control band
  (:mod:`bench.model.chamber`), at the rates of the pressure the chamber is at;
* ``wait_until_stable`` on a temperature of the chamber or the unit (``tvac.air_temp``,
  ``tvac.mount_temp``, thermocouples, the board's die ``temp``): until the chamber has finished
  its slew or ramp, then until the remaining drift over the ``hold`` fits in the ``band`` (the
  slowest of the air's approach and the unit's time constant, the die's self-heating after
  power-on), then the ``hold``;
* ``pump_down`` and ``vent``: the pump-down law (roughing, then the turbo's 1/t) and the vent law;
* rate table motions: acceleration-limited trapezoids at the step's or the drive's profile rate
  and acceleration (:mod:`bench.model.rate_table`).

A wait without a model (``wait_until_stable`` on another signal, a table move from an unknown
angle) counts what it takes at least (its hold, the braking) and marks the estimate a **lower
bound**. A wait the model says never ends counts its ``timeout`` (the run would abort there).
Operator prompts count 0 s: how long a person takes is not known (a dry-run's clock stands still).

Units: s of run time, °C, Torr, deg, deg/s, deg/s².
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Iterable

from bench.kinds import registry
from bench.model.chamber import ATMOSPHERE_TORR, ChamberParams
from bench.model.rate_table import TableParams
from bench.procedure.schema import kind_step
from bench.procedure.signals import default_kinds, parse_signal, role_of

if TYPE_CHECKING:  # pragma: no cover
    from bench.procedure.loader import Procedure, Step

PROMPT_TYPES = ("prompt", "mount")
"""Steps that wait for the operator (counted 0 s)."""


@dataclass
class LabModel:
    """What the estimate knows of the lab: ``ambient_c`` (°C, the chamber's air at the start), the
    chamber and rate-table models, and ``kinds`` (instrument -> driver; None: the standard names)."""

    ambient_c: float = 20.0
    chamber: ChamberParams = field(default_factory=ChamberParams)
    table: TableParams = field(default_factory=TableParams)
    kinds: dict[str, str] | None = None


@dataclass
class StepEstimate:
    """One step: ``duration_s`` (s of run time), whether it is only a ``lower_bound``, and ``basis``
    (how it was estimated, for people)."""

    duration_s: float
    lower_bound: bool = False
    basis: str = ""


@dataclass
class Estimate:
    """The estimate of every step of a procedure, in order."""

    steps: list[StepEstimate]
    prompts: int = 0
    """Operator prompts (counted 0 s)."""

    @property
    def total_s(self) -> float:
        """Sum of the steps (s)."""
        return sum(s.duration_s for s in self.steps)

    @property
    def lower_bound(self) -> bool:
        """True if any step is only a lower bound: the procedure takes at least :attr:`total_s`."""
        return any(s.lower_bound for s in self.steps)

    def starts_s(self) -> list[float]:
        """Estimated run time (s) at which each step starts."""
        out, t = [], 0.0
        for s in self.steps:
            out.append(t)
            t += s.duration_s
        return out


class ChamberState:
    """The chamber's air as the estimate follows it: approaching ``target_c`` from side ``sign``
    at ``speed`` (°C/s) until ``t_tail`` (s), where it is ``tail_c`` away, then exponentially with
    ``tau_air_s``; the unit follows the air with the time constant of the current pressure."""

    def __init__(self, p: ChamberParams, ambient_c: float):
        self.p = p
        self.target_c = ambient_c
        self.sign = 1.0
        self.speed = 0.0
        self.t_tail = 0.0
        self.tail_c = 0.0
        self.tau_air_s = 1.0
        self.pressure_torr = ATMOSPHERE_TORR
        self.power_changed_at: float | None = None  # run time (s) the board's power last changed

    def distance(self, t: float) -> float:
        """How far (°C) the air is from the set point at run time ``t``."""
        if t < self.t_tail:
            return self.tail_c + self.speed * (self.t_tail - t)
        return self.tail_c * math.exp(-(t - self.t_tail) / self.tau_air_s)

    def set_point(self, t: float, sp_c: float, ramp_c_per_min: float) -> None:
        air = self.target_c - self.sign * self.distance(t)
        d = abs(sp_c - air)
        heating = sp_c > air
        slew = self.p.slew_rate_c_per_s(heating, self.p.fraction_ambient(self.pressure_torr))
        band = self.p.control_band_c
        ramp = ramp_c_per_min / 60.0
        speed, tail = (ramp, band * ramp / slew) if 0 < ramp < slew else (slew, band)
        self.target_c, self.sign, self.speed, self.tau_air_s = sp_c, 1.0 if heating else -1.0, speed, band / slew
        self.tail_c = min(d, tail)
        self.t_tail = t + (d - self.tail_c) / speed

    def reach_s(self, t: float, band_c: float) -> float:
        """Run time (s) from ``t`` until the air is within ``band_c`` of the set point."""
        if self.tail_c <= band_c:
            return max(0.0, self.t_tail - (band_c - self.tail_c) / max(self.speed, 1e-12) - t)
        if band_c <= 0:
            return math.inf
        return max(0.0, self.t_tail + self.tau_air_s * math.log(self.tail_c / band_c) - t)

    def unit_tau_s(self) -> float:
        return 1.0 / self.p.unit_conductance_per_s(self.p.fraction_ambient(self.pressure_torr))

    def stable_s(self, t: float, where: str, band_c: float, hold_s: float) -> float:
        """Run time (s) from ``t`` until a temperature of the ``air``, the ``unit`` (mount,
        thermocouples) or the ``die`` has drifted less than ``band_c`` over ``hold_s``."""
        t0 = max(t, self.t_tail)
        tau_u = self.unit_tau_s()
        drift = self.distance(t0)
        tau = self.tau_air_s
        if where != "air":
            drift += self.speed * tau_u * math.exp(-(t0 - self.t_tail) / tau_u)
            tau = max(tau, tau_u)
        if where == "die" and self.power_changed_at is not None:
            drift += self.p.self_heating_c * math.exp(-(t0 - self.power_changed_at) / tau_u)
        drift *= 1.0 - math.exp(-hold_s / tau) if hold_s > 0 else 0.0
        settle = tau * math.log(drift / band_c) if band_c > 0 and drift > band_c else (0.0 if drift <= band_c else math.inf)
        return (t0 - t) + settle + hold_s


class EstimateContext:
    """What a step's estimate (``StepDef.estimate``) works with: the run time ``t`` (s) the step
    starts at, the ``lab`` model, the instruments' ``kinds``, the chamber and unit temperatures
    (:meth:`chamber`) and any state a kind keeps per instrument between steps (:meth:`state`: a
    table's rate and angle)."""

    def __init__(self, lab: LabModel, kinds: dict[str, str]):
        self.lab = lab
        self.kinds = kinds
        self.t = 0.0
        self._chambers: dict[str, ChamberState] = {}
        self._states: dict[str, object] = {}

    def chamber(self, name: str | None = None) -> ChamberState:
        """The temperatures of the unit's environment as driven by chamber ``name`` (default: the
        lab's one environment: the first instrument whose kind has an ``envelope`` on air temperature,
        else a room at the ambient temperature)."""
        if name is None:
            name = next((n for n, k in self.kinds.items() if _is_chamber(k)), "")
        return self._chambers.setdefault(name, ChamberState(self.lab.chamber, self.lab.ambient_c))

    def state(self, key: str, make):  # noqa: ANN001, ANN201 - any per-instrument state a kind keeps
        """The state ``key`` (made by ``make()`` the first time)."""
        if key not in self._states:
            self._states[key] = make()
        return self._states[key]


def _is_chamber(kind: str) -> bool:
    k = registry.get(kind)
    return k is not None and any(s.role == "air_temp" for s in k.signals)


def estimate_procedure(steps: Iterable["Step"], lab: LabModel | None = None) -> Estimate:
    """The :class:`Estimate` of ``steps`` (a procedure's expanded steps) on the lab ``lab``
    (default: the model's own defaults and the standard instrument names)."""
    lab = lab or LabModel()
    kinds = lab.kinds if lab.kinds is not None else default_kinds()
    ctx = EstimateContext(lab, kinds)
    out: list[StepEstimate] = []
    prompts = 0
    for s in steps:
        p = s.params
        e = StepEstimate(0.0)
        if s.type in ("record", "wait"):
            e = StepEstimate(float(p.get("duration", 0.0)), basis="duration")
        elif s.type in PROMPT_TYPES:
            prompts += 1
            e = StepEstimate(0.0, basis="operator prompt, not counted")
        elif s.type == "wait_until_stable":
            e = _stable(s, ctx)
        elif s.type == "vibrate":
            e = StepEstimate(_vibration_s(p.get("profile")), basis="vibration profile duration")
        elif (found := kind_step(s.type)) is not None and found[1].estimate:
            e = registry.load(found[1].estimate)(s, ctx)
        out.append(e)
        ctx.t += e.duration_s
    return Estimate(out, prompts)


def capped(duration_s: float, p: dict, basis: str) -> StepEstimate:
    """A modelled wait, at most its ``timeout`` (the run aborts there)."""
    timeout = float(p.get("timeout", math.inf))
    if duration_s > timeout:
        return StepEstimate(timeout, basis=f"{basis}: not within its timeout, counted at the timeout (the run would abort)")
    return StepEstimate(duration_s, basis=basis)


TEMPERATURE_ROLES = {"air_temp": "air", "mount_temp": "unit", "unit_temp": "unit", "sensor_temp": "die"}
"""Signal role -> which temperature of the chamber model a signal reads."""


def _stable(s: "Step", ctx: EstimateContext) -> StepEstimate:
    p = s.params
    hold, band = float(p.get("hold", 0.0)), float(p.get("band", 0.0))
    try:
        inst, column, _axis = parse_signal(str(p["signal"]))
    except KeyError:
        inst, column = "", ""
    where = TEMPERATURE_ROLES.get(role_of(column, ctx.kinds.get(inst, "")))
    if where is None:
        return StepEstimate(hold, lower_bound=True, basis=f"no model of {p.get('signal')}: its hold, at least")
    return capped(ctx.chamber().stable_s(ctx.t, where, band, hold), p, f"chamber and unit settling, then the hold (chamber model, {where})")


def _vibration_s(profile: object) -> float:
    """Duration (s) of a vibration profile file; 0 if it cannot be read (validation reports it)."""
    from bench.errors import InputError
    from bench.model.vibration import load_vibration

    try:
        return float(load_vibration(Path(str(profile))).duration_s)
    except (InputError, OSError, ValueError):
        return 0.0


def run_file_bytes(procedure: "Procedure") -> int:
    """Rough run-file size (B) for the free-space check before a run: streamed rows only while a
    step records (``record``, or ``record:`` on a wait/vibration), as if at 1 kHz with 20 values of
    8 B, plus the polled instruments for the whole estimated run (5 instruments at 1 Hz, 10 values
    of 8 B), plus 1 MB of fixed overhead."""
    est = procedure.estimate()
    recording_s = sum(e.duration_s for step, e in zip(procedure.steps, est.steps)
                      if step.type == "record" or step.params.get("record"))
    return int(recording_s * 1000 * 20 * 8 + est.total_s * 5 * 10 * 8) + 1_000_000


def settle(s: "Step", ctx: EstimateContext) -> StepEstimate:
    """A step that takes its ``settle`` time (s), e.g. a bench that reaches its rate at once."""
    return StepEstimate(float(s.params.get("settle", 0.0)), basis="settle")
