"""The rate table's procedure steps: ``table_rate``, ``table_move``, ``table_tilt``, ``table_stop``
(CiA 402 profile velocity and position modes; each waits until the drives report the target
reached) (runner layer)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bench.procedure import Step
from bench.runner.steps import MOTION_TIMEOUT_S, RATE_TOLERANCE_DPS, StepAbort

if TYPE_CHECKING:  # pragma: no cover
    from bench.runner.engine import Runner


def table_rate(r: "Runner", step: Step) -> tuple[str, str]:
    p = step.params
    drv = r.lab.instruments[p["instrument"]]
    actual = drv.set_rate(p["rate"], p.get("accel"))
    sig = f"{p['instrument']}.rate"
    if not r.wait_until(MOTION_TIMEOUT_S, lambda: abs(r.read_signal(sig, fresh=True) - actual) <= RATE_TOLERANCE_DPS):
        raise StepAbort(f"{p['instrument']}: table did not reach {actual:g} deg/s within {MOTION_TIMEOUT_S:g} s")
    if p.get("settle"):
        r.wait_until(p["settle"])
    return "done", f"{actual:+g} deg/s"


def _wait_target(r: "Runner", inst: str, what: str) -> None:
    def reached() -> bool:
        s = r.lab.instruments[inst].read()  # looked up each time: a link fault may reopen the driver
        if s["any_fault"]:
            raise StepAbort(f"{inst}: drive fault during {what}")
        return bool(s["target_reached"] and s["tilt_target_reached"])

    if not r.wait_until(MOTION_TIMEOUT_S, reached):
        raise StepAbort(f"{inst}: {what} not finished within {MOTION_TIMEOUT_S:g} s")


def table_move(r: "Runner", step: Step) -> tuple[str, str]:
    p = step.params
    r.lab.instruments[p["instrument"]].move_to(p["angle"], p.get("rate"))
    _wait_target(r, p["instrument"], f"move to {p['angle']:g} deg")
    return "done", f"at {r.read_signal(p['instrument'] + '.angle', fresh=True):.3f} deg"


def table_tilt(r: "Runner", step: Step) -> tuple[str, str]:
    p = step.params
    r.lab.instruments[p["instrument"]].tilt(p["angle"])
    _wait_target(r, p["instrument"], f"tilt to {p['angle']:g} deg")
    return "done", f"tilted {r.read_signal(p['instrument'] + '.tilt', fresh=True):.3f} deg"


def table_stop(r: "Runner", step: Step) -> tuple[str, str]:
    inst = step.params["instrument"]
    r.lab.instruments[inst].stop()
    if not r.wait_until(MOTION_TIMEOUT_S, lambda: abs(r.read_signal(f"{inst}.rate", fresh=True)) <= RATE_TOLERANCE_DPS):
        raise StepAbort(f"{inst}: table did not stop within {MOTION_TIMEOUT_S:g} s")
    return "done", "stopped"
