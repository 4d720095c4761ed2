"""The ``supply`` step: set an output's voltage and current limit, switch it on or off, and read
it back (runner layer; bench/runner/steps.py says what handlers return and raise)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bench.errors import DeviceFault
from bench.procedure import Step
from bench.runner.steps import StepAbort

if TYPE_CHECKING:  # pragma: no cover
    from bench.runner.engine import Runner


def supply(r: "Runner", step: Step) -> tuple[str, str]:
    p = step.params
    name, output = p["instrument"], str(int(p["output"]))
    drv = r.lab.instruments[name]
    if "voltage" in p or "current" in p:
        drv.set_output(output, p.get("voltage"), p.get("current"))
    if "on" in p:
        try:
            drv.switch(output, p["on"])
        except DeviceFault as exc:
            raise StepAbort(f"{name}: output {output} did not switch {'on' if p['on'] else 'off'}: {exc}") from None
        if p["on"] and p.get("settle"):
            r.wait_until(p["settle"])  # the lab stays under watch while the unit comes up
    reading = r.lab.instruments[name].read(output)  # looked up again: a link fault may have reopened it
    if reading.ocp_tripped or reading.ovp_tripped:
        raise StepAbort(f"{name}: output {output} tripped its protection: {reading.describe()}")
    return "done", f"output {output}: {reading.describe()}"
