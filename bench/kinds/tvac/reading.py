"""The chamber's ``instruments check`` reading: air, set point, pressure (changes nothing)."""


def reading(drv) -> str:  # noqa: ANN001 - a drivers.tvac.TvacChamber
    r = drv.read()
    return f"air {r['air_temp_c']:.1f} degC, set point {r['set_point_c']:.1f} degC, {r['pressure_torr']:.3g} Torr"
