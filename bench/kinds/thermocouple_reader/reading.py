"""The thermocouple reader's ``instruments check`` reading: its reference junction."""


def reading(drv) -> str:  # noqa: ANN001 - a drivers.thermocouple_reader.ThermocoupleReader
    return f"reference junction {drv.reference_junction_c(101):.2f} degC"
