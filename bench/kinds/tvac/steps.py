"""The chamber's procedure steps: what ``set_temperature``, ``pump_down`` and ``vent`` do to it
(runner layer: bench/runner/steps.py explains outcomes, :class:`StepAbort` and waits)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bench.procedure import Step
from bench.runner.steps import StepAbort

if TYPE_CHECKING:  # pragma: no cover
    from bench.runner.engine import Runner


def set_temperature(r: "Runner", step: Step) -> tuple[str, str]:
    p = step.params
    drv = r.lab.instruments[p["instrument"]]
    drv.set_point(p["set_point"], p.get("ramp", 0.0))
    what = f"set point {p['set_point']:g} degC" + (f" at {p['ramp']:g} degC/min" if p.get("ramp") else "")
    if not p.get("wait"):
        return "done", what
    sig = f"{p['instrument']}.air_temp"
    ok = r.wait_until(p["timeout"], lambda: abs(r.read_signal(sig) - p["set_point"]) <= p["band"])
    if not ok:
        raise StepAbort(f"{p['instrument']}: chamber air did not reach {p['set_point']:g} degC ± {p['band']:g} within {p['timeout']:g} s (now {r.read_signal(sig):.1f} degC)")
    return "done", f"{what}; reached ({r.read_signal(sig):.1f} degC)"


def pump_down(r: "Runner", step: Step) -> tuple[str, str]:
    p = step.params
    r.lab.instruments[p["instrument"]].pump_down()
    sig = f"{p['instrument']}.pressure"
    if not r.wait_until(p["timeout"], lambda: r.read_signal(sig) <= p["pressure"]):
        raise StepAbort(f"{p['instrument']}: pressure did not fall to {p['pressure']:g} Torr within {p['timeout']:g} s (now {r.read_signal(sig):.3g} Torr)")
    r.in_vacuum = True
    return "done", f"{r.read_signal(sig):.3g} Torr"


def vent(r: "Runner", step: Step) -> tuple[str, str]:
    p = step.params
    r.in_vacuum = False
    r.lab.instruments[p["instrument"]].vent()
    sig = f"{p['instrument']}.pressure"
    if not r.wait_until(p["timeout"], lambda: r.read_signal(sig) >= p["pressure"]):
        raise StepAbort(f"{p['instrument']}: pressure did not rise to {p['pressure']:g} Torr within {p['timeout']:g} s")
    return "done", f"{r.read_signal(sig):.3g} Torr"
