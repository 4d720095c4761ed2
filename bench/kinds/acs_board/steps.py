"""The sensor board's procedure steps: ``power`` (its sensor supply), ``configure`` (output data
rate, moving average; read back where the board can), ``bit`` (built-in test) (runner layer)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bench.procedure import Step

if TYPE_CHECKING:  # pragma: no cover
    from bench.runner.engine import Runner


def power(r: "Runner", step: Step) -> tuple[str, str]:
    r.lab.instruments[step.params["instrument"]].sensor_power(step.params["on"])
    return "done", "sensors on" if step.params["on"] else "sensors off"


def configure(r: "Runner", step: Step) -> tuple[str, str]:
    drv = r.lab.instruments[step.params["instrument"]]
    done = []
    if "odr" in step.params:
        hz = step.params["odr"]
        if abs(hz - round(hz)) > 1e-9:
            raise ValueError(f"step {step.path}: output data rate must be a whole number of Hz, got {hz:g} Hz")
        drv.set_odr(int(round(hz)))
        done.append(f"odr {int(round(hz))} Hz")
    if "moving_average" in step.params:
        drv.set_moving_average(int(step.params["moving_average"]))
        done.append(f"moving average N={int(step.params['moving_average'])}")
    cfg = drv.get_config()
    if not cfg.get("read_back", True):
        return "done", ", ".join(done) + " (acknowledged; not read back: the board has no GET_CONFIG)"
    if "odr" in step.params and cfg["odr_hz"] != int(round(step.params["odr"])) or (
        "moving_average" in step.params and cfg["moving_avg_n"] != int(step.params["moving_average"])
    ):
        return "failed", ", ".join(done) + f" requested, but the board reports odr {cfg['odr_hz']} Hz, N={cfg['moving_avg_n']}"
    return "done", ", ".join(done) + " (read back from the board)"


def bit(r: "Runner", step: Step) -> tuple[str, str]:
    mask = r.lab.instruments[step.params["instrument"]].run_bit()
    expected = step.params["expect_mask"]
    if mask == expected:
        return "passed", f"failed-subsystem mask 0x{mask:04x}"
    return "failed", f"failed-subsystem mask 0x{mask:04x}, expected 0x{expected:04x}"
