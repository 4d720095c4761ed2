"""The stepper bench's config keys: how it is set up in GRBL (``axis``, ``steps_per_deg`` = $100,
``max_rate``, ``acceleration`` = $120); in ``sim:``, the simulated GRBL's EEPROM, input pins and DTR
reset, and the mechanics' periodic rate errors (docs/stepper-bench.md)."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from bench.errors import InputError
from bench.model.eccentricity import Eccentricity
from bench.yamlsrc import Fields
from drivers.stepper_bench import AXES as GRBL_AXES, BenchSetup

if TYPE_CHECKING:  # pragma: no cover
    from bench.config import ConfigContext

RETIRED_KEYS = {"speed_calibration": "the thesis firmware's n (Eq. 3.1); the bench runs stock GRBL 1.1 now: give steps_per_deg "
                                     "(GRBL $100; 'bench calibrate-bench' fits it from rotation times)"}
"""Keys of earlier configs that mean nothing now -> why (refused in a config, ignored in a recorded one)."""


@dataclass
class StepperSettings:
    setup: BenchSetup = field(default_factory=BenchSetup)
    """Its axis in GRBL, steps per degree, top rate and acceleration."""

    def open_kwargs(self) -> dict[str, Any]:
        return {"setup": self.setup}


@dataclass
class GrblSimConfig:
    """The simulated bench's GRBL (bench/sim/stepper_bench.py): ``eeprom`` ``bench`` (set up as
    the bench: steps per degree, max rate deg/s, acceleration deg/s², build info) or ``blank`` (a
    freshly flashed board); ``pins`` input pins that read triggered (``PXYZRHS``: grbl-sim's);
    ``dtr_reset_s`` the board resets on open and answers this long after (None: no reset)."""

    axis: str = "X"
    steps_per_deg: float = BenchSetup.steps_per_deg
    max_rate_dps: float = BenchSetup.max_rate_dps
    acceleration_dps2: float = 10.0
    """GRBL's default $120 (defaults.h): the thesis gives no acceleration."""
    eeprom: str = "bench"
    build_info: str = ""
    """Default: ``STEPPER_BENCH:`` and the sim's serial."""
    pins: str = ""
    dtr_reset_s: float | None = None
    true_steps_per_deg: float | None = None
    """The mechanics' steps per table degree when it differs from what GRBL is told (a bench to
    calibrate); None: the same."""
    periodic_errors: list[Eccentricity] = field(default_factory=list)
    """True-rate errors periodic in the angle (worm eccentricity, microstep ripple)."""


def microsteps_per_revolution(steps_per_deg: float) -> int:
    """Steps (microsteps) per stage revolution of a bench with ``steps_per_deg`` (GRBL $100)."""
    return int(round(360.0 * steps_per_deg))


def _grbl_axis(f: Fields, errors: list[InputError]) -> str:
    axis = f.get("axis", str, default="X")
    if axis not in GRBL_AXES:
        errors.append(InputError(f"expected a GRBL axis {', '.join(GRBL_AXES)}, got {axis!r}", f.map["axis"].location, "axis"))
        return "X"
    return axis


def settings(f: Fields, ctx: "ConfigContext") -> StepperSettings:
    """A stepper bench's ``axis`` (X), ``steps_per_deg`` (GRBL $100), ``max_rate`` (deg/s) and
    ``acceleration`` (deg/s², checked against $120 when given)."""
    ctx.retired(f, RETIRED_KEYS)
    d = BenchSetup()
    return StepperSettings(BenchSetup(_grbl_axis(f, ctx.errors),
                                      ctx.positive(f, "steps_per_deg", "1/deg", d.steps_per_deg, "GRBL $100: steps per table degree"),
                                      ctx.positive(f, "max_rate", "deg/s", d.max_rate_dps, "the fastest the bench is commanded"),
                                      ctx.positive(f, "acceleration", "deg/s^2", None, "GRBL $120")))


def sim_settings(f: Fields, ctx: "ConfigContext") -> GrblSimConfig:
    """The simulated GRBL of a stepper bench (:class:`GrblSimConfig`)."""
    errors = ctx.errors
    d = GrblSimConfig()
    g = GrblSimConfig(_grbl_axis(f, errors),
                      ctx.positive(f, "steps_per_deg", "1/deg", d.steps_per_deg, "GRBL $100"),
                      ctx.positive(f, "max_rate", "deg/s", d.max_rate_dps, "GRBL $110 / 60"),
                      ctx.positive(f, "acceleration", "deg/s^2", d.acceleration_dps2, "GRBL $120"))
    g.eeprom = f.get("eeprom", str, default="bench")
    if g.eeprom not in ("bench", "blank"):
        errors.append(InputError(f"expected eeprom bench or blank, got {g.eeprom!r}", f.map["eeprom"].location, "eeprom"))
    g.build_info = f.get("build_info", str, default=f"STEPPER_BENCH:{ctx.sim.serial if ctx.sim else ''}")
    g.pins = f.get("pins", str, default="")
    if g.pins is not None and not re.fullmatch(r"P?X?Y?Z?D?R?H?S?", g.pins):
        errors.append(InputError(f"expected input pins in GRBL's report order (P X Y Z D R H S), got {g.pins!r}", f.map["pins"].location, "pins"))
    g.dtr_reset_s = ctx.positive(f, "dtr_reset", "s", None, "an Uno answers about 2 s after its port opens")
    g.true_steps_per_deg = ctx.positive(f, "true_steps_per_deg", "1/deg", None, "the mechanics, when GRBL's $100 is off")
    ctx.retired(f, RETIRED_KEYS)
    for key, default_harmonic in (("eccentricity", None), ("microstep_ripple", microsteps_per_revolution(g.steps_per_deg))):
        if (n := f.node_at(key)) is not None:
            err = ctx.periodic_error(n, key, default_harmonic)
            if err is not None:
                g.periodic_errors.append(err)
    return g
