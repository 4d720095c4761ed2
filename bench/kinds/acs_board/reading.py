"""The sensor board's ``instruments check`` reading: its configuration as it reports it."""


def reading(drv) -> str:  # noqa: ANN001 - a drivers.acs_board.AcsBoard
    c = drv.get_config()
    told = "" if c.get("read_back", True) else " (not read back: the board's frame description has no GET_CONFIG)"
    return f"ODR {c['odr_hz']} Hz, moving average {c['moving_avg_n']}, sensors {'on' if c['sensor_power'] else 'off'}{told}"
