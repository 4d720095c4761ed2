"""The lab a run talks to: a clock and one driver per instrument, on hardware or simulators.

``--sim`` puts the simulators named in the config behind the very same drivers, through the
``sim://NAME`` pyserial URL handler: the driver code path is identical to a hardware run.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from bench.clock import Clock, VirtualClock, WallClock
from bench.config import LabConfig
from bench.errors import InputError
from bench.sim import registry
from bench.sim.factory import build_devices
from drivers.acs_board import AcsBoard
from drivers.stepper_bench import StepperBench
from drivers.thermocouple_reader import ThermocoupleReader

DRIVER_CLASSES = {"acs_board": AcsBoard, "stepper_bench": StepperBench, "thermocouple_reader": ThermocoupleReader}
"""Config ``driver`` name -> driver class (each has ``open(url, baudrate=, timeout_s=, on_traffic=)``)."""

TrafficSink = Callable[[str, str, str, bytes], None]
"""Called with (instrument, "command" | "reply", what (frame or command name), raw bytes)."""


@dataclass
class Lab:
    clock: Clock
    mode: str  # "sim" | "hardware"
    instruments: dict[str, AcsBoard | StepperBench | ThermocoupleReader]
    ports: dict[str, str]
    sims: dict[str, object] = field(default_factory=dict)

    def close(self) -> None:
        """Close every port and unregister simulators (errors ignored: this runs on the way out)."""
        for drv in self.instruments.values():
            try:
                drv.close()
            except Exception:  # noqa: BLE001 - closing must not mask the run's outcome
                pass
        for name in self.sims:
            registry.unregister(name)


def open_lab(config: LabConfig, names: list[str], *, sim: bool, realtime: bool, on_traffic: TrafficSink | None = None) -> Lab:
    """Open the instruments ``names`` of ``config``.

    ``sim``: simulators behind the drivers, on a virtual clock unless ``realtime``. Raises
    :class:`InputError` for an instrument missing from the config or without a ``sim`` section.
    """
    for name in names:
        if name not in config.instruments:
            raise InputError(f"instrument {name!r} used by the procedure is not in the config (has: {', '.join(config.instruments)})", None, "instruments")
    clock: Clock = WallClock() if (realtime or not sim) else VirtualClock()
    sims: dict[str, object] = {}
    ports: dict[str, str] = {}
    if sim:
        try:
            sims = build_devices(config, clock, names)
        except ValueError as exc:
            raise InputError(str(exc)) from None
        for name, dev in sims.items():
            ports[name] = registry.register(name, dev)
    else:
        ports = {name: config.instruments[name].port for name in names}
    instruments: dict[str, AcsBoard | StepperBench | ThermocoupleReader] = {}
    lab = Lab(clock, "sim" if sim else "hardware", instruments, ports, sims)
    try:
        for name in names:
            inst = config.instruments[name]
            hook = None
            if on_traffic is not None:
                hook = (lambda n: (lambda d, t, raw: on_traffic(n, d, t, raw)))(name)
            extra = {"calibration": inst.speed_calibration} if inst.driver == "stepper_bench" else {}
            cls = DRIVER_CLASSES[inst.driver]
            instruments[name] = cls.open(ports[name], baudrate=inst.baudrate, timeout_s=inst.timeout_s, on_traffic=hook, **extra)
    except Exception:
        lab.close()
        raise
    return lab
