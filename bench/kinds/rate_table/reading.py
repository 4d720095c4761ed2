"""The rate table's ``instruments check`` reading: angle, rate, tilt and drive state (no motion)."""


def reading(drv) -> str:  # noqa: ANN001 - a drivers.rate_table.RateTable
    r = drv.read()
    return f"angle {r['angle_deg']:.3f} deg, rate {r['rate_dps']:.3f} deg/s, tilt {r['tilt_deg']:.3f} deg, {r['state']}"
