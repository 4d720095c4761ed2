"""The stepper bench's ``instruments check`` reading: GRBL's state, angle and rate."""


def reading(drv) -> str:  # noqa: ANN001 - a drivers.stepper_bench.StepperBench
    s = drv.status()
    return f"{s['state']}, angle {s['angle_deg']:.3f} deg, rate {s['rate_dps']:.3f} deg/s"
