"""Build the device simulators a lab config names, on one world and one clock."""

from __future__ import annotations

import numpy as np

from bench.config import LabConfig
from bench.model.imu_simple import SimpleImuModel
from bench.sim.acs_board import AcsBoardIdentity, AcsBoardSim
from bench.sim.stepper_bench import StepperBenchSim
from bench.sim.thermocouple_reader import ThermocoupleReaderSim
from bench.sim.world import World


def build_devices(config: LabConfig, clock, names: list[str] | None = None) -> dict[str, object]:
    """One simulator per instrument (restricted to ``names`` if given), keyed by instrument name,
    all on one world: the stepper bench turns the stage the sensor board sits on.

    Raises ``ValueError`` naming an instrument that has no ``sim`` section.
    """
    world = World(config.world)
    devices: dict[str, AcsBoardSim] = {}
    for name, inst in config.instruments.items():
        if names is not None and name not in names:
            continue
        if inst.sim is None:
            raise ValueError(f"instrument {name!r} has no 'sim' section in {config.path}; it cannot be simulated")
        if inst.sim.backend == "thermocouple_reader":
            devices[name] = ThermocoupleReaderSim(clock, world, inst.sim.serial, tuple(inst.sim.open_channels), inst.baudrate)
            continue
        if inst.sim.backend == "stepper_bench":
            devices[name] = StepperBenchSim(clock, world.stage, inst.sim.speed_calibration, inst.sim.serial, inst.baudrate)
            continue
        rng = np.random.default_rng(inst.sim.seed)
        model = SimpleImuModel(inst.sim.model, rng)
        devices[name] = AcsBoardSim(
            clock,
            world,
            model,
            AcsBoardIdentity(serial=inst.sim.serial),
            baudrate=inst.baudrate,
            bit_fail_mask=inst.sim.bit_fail_mask,
        )
    return devices
