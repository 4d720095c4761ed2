"""The supply's ``instruments check`` reading: each output the lab uses as it is (changes nothing)."""


def reading(drv) -> str:  # noqa: ANN001 - a bench_dc_supply.driver.DcSupply
    outputs = sorted(drv.outputs) or ["1"]
    return "; ".join(f"output {n}: {drv.read(n).describe()}" for n in outputs)
