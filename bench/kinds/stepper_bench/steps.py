"""The stepper bench's procedure step: ``bench_rate`` (GRBL jogging at that feed; 0 stops it with a
jog cancel) (runner layer)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bench.procedure import Step

if TYPE_CHECKING:  # pragma: no cover
    from bench.runner.engine import Runner


def bench_rate(r: "Runner", step: Step) -> tuple[str, str]:
    p = step.params
    drv = r.lab.instruments[p["instrument"]]
    if p["rate"] == 0:
        drv.stop()
        msg = "stopped"
    else:
        actual = drv.set_rate(p["rate"])
        drv.run()
        msg = f"{actual:+.4f} deg/s"
    if p.get("settle"):
        r.wait_until(p["settle"])
    return "done", msg
