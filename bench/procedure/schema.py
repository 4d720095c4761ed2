"""The procedure schema ``bench-procedure/1``: step types and their fields, as data.

Each step is a one-key mapping ``{TYPE: {field: value, ...}}`` (``comment`` and ``prompt`` also
take a string). Every step may also carry ``name``. Quantities are strings with units
("30 min", "-29 degC", "1e-5 Torr") or bare numbers in the field's unit. Any field value may be a
parameter or loop variable: ``$cold`` (the whole value) or ``${rate}`` inside text.
``docs/procedures.md`` shows an example of every step type.

Two kinds of steps: **actions** (:data:`STEP_TYPES`), which the runner executes, and **blocks**
(:data:`BLOCK_TYPES`: ``repeat``, ``for_each``, ``call``, ``rate_steps``), which the loader
expands into actions before anything runs — the runner never sees a loop.
"""

from __future__ import annotations

from dataclasses import dataclass

from bench.units import TEMPERATURE_DIFFERENCE

SCHEMA_ID = "bench-procedure/1"


@dataclass(frozen=True)
class FieldSpec:
    """One field of a step. ``kind``: instrument | quantity | int | bool | str | signal | choice | vibration (a file)."""

    kind: str
    units: str = ""
    required: bool = True
    default: object = None
    minimum: float | None = None
    maximum: float | None = None
    exclusive_minimum: bool = False
    """The value must be above ``minimum``, not equal to it (a band of 0 could never be met)."""
    doc: str = ""
    choices: tuple[str, ...] = ()
    instrument_kinds: tuple[str, ...] = ()
    """For ``instrument`` fields: the drivers that can do this step (empty: any)."""


@dataclass(frozen=True)
class StepSpec:
    fields: dict[str, FieldSpec]
    doc: str
    scalar_field: str | None = None  # a step written as ``TYPE: value`` fills this field


def _inst(*kinds: str) -> FieldSpec:
    return FieldSpec("instrument", instrument_kinds=kinds, doc="name of an instrument in the procedure's `instruments` list"
                     + (f" (driver {' or '.join(kinds)})" if kinds else ""))


BOARD = _inst("acs_board")
CHAMBER = _inst("tvac")
TABLE = _inst("rate_table")
BENCH = _inst("stepper_bench")
TIMEOUT = FieldSpec("quantity", "s", required=False, default=12 * 3600.0, minimum=0.0, doc="give up after this long (default 12 h)")
PROMPT_TIMEOUT_S = 3600.0
"""Default wall time (s) a prompt waits for the operator's answer before the run aborts."""
STATISTICS = ("mean", "std", "min", "max", "rms", "slope", "count", "scale_factor_error", "bias")

STEP_TYPES: dict[str, StepSpec] = {
    "comment": StepSpec({"text": FieldSpec("str", doc="text shown and recorded")}, "A note for the operator and the record.", "text"),
    "prompt": StepSpec(
        {
            "text": FieldSpec("str", doc="what the operator must do or confirm"),
            "id": FieldSpec("str", required=False, default="", doc="key of the answer in an answers file (default: the step name)"),
            "timeout": FieldSpec("quantity", "s", required=False, default=PROMPT_TIMEOUT_S, minimum=0.0,
                                 doc="wall time to wait for an answer before the run aborts (default 1 h)"),
        },
        "Ask the operator to act and confirm (yes/no; anything else is asked again, up to 3 times); 'no' aborts the run. "
        "Answers can come from a file (--answers).",
        "text",
    ),
    "power": StepSpec(
        {"instrument": BOARD, "on": FieldSpec("bool", doc="true to power the sensors, false to switch them off")},
        "Switch an instrument's sensor supply on or off.",
    ),
    "configure": StepSpec(
        {
            "instrument": BOARD,
            "odr": FieldSpec("quantity", "Hz", required=False, minimum=1, maximum=1000, doc="output data rate"),
            "moving_average": FieldSpec("int", required=False, minimum=1, maximum=100, doc="moving-average buffer length N"),
        },
        "Set a sensor board's output data rate and moving-average length.",
    ),
    "record": StepSpec(
        {
            "instrument": BOARD,
            "duration": FieldSpec("quantity", "s", minimum=0.0, doc="how long to record"),
            "window": FieldSpec("str", required=False, default="", doc="name of the recording window (checks refer to it)"),
        },
        "Stream and record an instrument's data for a duration, as a named window.",
    ),
    "wait": StepSpec({"duration": FieldSpec("quantity", "s", minimum=0.0, doc="how long to wait")}, "Wait (polled instruments keep being logged).", "duration"),
    "bit": StepSpec(
        {"instrument": BOARD, "expect_mask": FieldSpec("int", required=False, default=0, minimum=0, maximum=0xFFFF, doc="expected failed-subsystem mask")},
        "Run the built-in test; the step fails unless the failed mask equals expect_mask.",
    ),
    "set_temperature": StepSpec(
        {
            "instrument": CHAMBER,
            "set_point": FieldSpec("quantity", "degC", doc="chamber set point"),
            "ramp": FieldSpec("quantity", f"{TEMPERATURE_DIFFERENCE}/min", required=False, minimum=0.0,
                              doc="set-point ramp rate (0 or absent: step change, heater/cooler limited)"),
            "wait": FieldSpec("bool", required=False, default=False, doc="wait until the chamber air is within `band` of the set point"),
            "band": FieldSpec("quantity", TEMPERATURE_DIFFERENCE, required=False, default=1.0, minimum=0.0, exclusive_minimum=True,
                              doc="with wait: how close (default 1 degC; above 0: the air never sits exactly on the set point)"),
            "timeout": TIMEOUT,
        },
        "Give the chamber a new set point (optionally ramped); optionally wait until the air reaches it.",
    ),
    "wait_until_stable": StepSpec(
        {
            "signal": FieldSpec("signal", doc="INSTRUMENT.COLUMN of a polled instrument, e.g. thermocouples.ch101 or tvac.air_temp"),
            "band": FieldSpec("quantity", "", minimum=0.0, doc="max - min over the hold time must stay within this (in the signal's units)"),
            "hold": FieldSpec("quantity", "s", minimum=0.0, doc="how long the signal must stay within the band"),
            "timeout": TIMEOUT,
            "record": FieldSpec("instrument", required=False, instrument_kinds=("acs_board",), doc="stream this board meanwhile"),
            "window": FieldSpec("str", required=False, default="", doc="window name of that recording"),
        },
        "Wait until a signal is stable (e.g. temperature within 0.5 degC for 10 min); abort on timeout.",
    ),
    "pump_down": StepSpec(
        {"instrument": CHAMBER, "pressure": FieldSpec("quantity", "Torr", minimum=0.0, doc="wait until the pressure is at or below this"), "timeout": TIMEOUT},
        "Close the vent, start the pumps and wait for the pressure.",
    ),
    "vent": StepSpec(
        {"instrument": CHAMBER, "pressure": FieldSpec("quantity", "Torr", required=False, default=700.0, doc="wait until the pressure is at or above this"),
         "timeout": TIMEOUT},
        "Stop the pumps, open the vent valve and wait for the pressure to rise.",
    ),
    "table_rate": StepSpec(
        {
            "instrument": TABLE,
            "rate": FieldSpec("quantity", "deg/s", doc="rotation rate (signed)"),
            "accel": FieldSpec("quantity", "deg/s**2", required=False, minimum=0.0, doc="acceleration limit (default: the drive's)"),
            "settle": FieldSpec("quantity", "s", required=False, default=0.0, minimum=0.0, doc="wait this long after reaching the rate"),
        },
        "Turn the rate table at a rate (profile velocity mode), wait until reached, then settle.",
    ),
    "table_move": StepSpec(
        {"instrument": TABLE, "angle": FieldSpec("quantity", "deg", doc="rotation angle to move to"),
         "rate": FieldSpec("quantity", "deg/s", required=False, minimum=0.0, doc="move speed (default: the drive's)")},
        "Move the table's rotation axis to an angle and wait until it is there.",
    ),
    "table_tilt": StepSpec(
        {"instrument": TABLE, "angle": FieldSpec("quantity", "deg", doc="tilt of the platter (0 = level; -latitude cancels Earth rate on the table axis)")},
        "Tilt the table and wait until it is there.",
    ),
    "table_stop": StepSpec({"instrument": TABLE}, "Stop the table (both axes stay enabled).", "instrument"),
    "bench_rate": StepSpec(
        {"instrument": BENCH, "rate": FieldSpec("quantity", "deg/s", doc="bench rate (signed; 0 stops)"),
         "settle": FieldSpec("quantity", "s", required=False, default=0.0, minimum=0.0, doc="wait this long afterwards")},
        "Turn the stepper bench at a rate (GRBL jogging at that feed; 0 stops it with a jog cancel).",
    ),
    "mount": StepSpec(
        {
            "up": FieldSpec("choice", choices=("x", "y", "z", "-x", "-y", "-z"), doc="sensor axis along the table's rotation axis (platter normal)"),
            "id": FieldSpec("str", required=False, default="", doc="prompt id for the answers file (default mount_UP)"),
        },
        "The unit is (re)mounted with a given axis on the rotation axis: the operator does it and confirms; a dry-run turns the simulated unit.",
        "up",
    ),
    "vibrate": StepSpec(
        {
            "profile": FieldSpec("vibration", doc="vibration file (bench-vibration/1), relative to the procedure, e.g. ../configs/vibration/gevs_workmanship.yaml"),
            "axis": FieldSpec("choice", choices=("x", "y", "z", "-x", "-y", "-z"), doc="shaker axis in the unit's frame"),
            "record": FieldSpec("instrument", required=False, instrument_kinds=("acs_board",), doc="stream this board meanwhile"),
            "window": FieldSpec("str", required=False, default="", doc="window name of that recording"),
        },
        "Shake the unit with a random-vibration or sine-sweep profile (hardware: the operator runs the shaker and confirms).",
    ),
    "check": StepSpec(
        {
            "signal": FieldSpec("signal", doc="INSTRUMENT.COLUMN[.x|y|z], e.g. acs_board.gyro.z or tvac.air_temp"),
            "statistic": FieldSpec("choice", choices=STATISTICS, doc="what to compute over the window(s)"),
            "window": FieldSpec("str", doc="recording window name; a trailing * matches several (rate fits)"),
            "min": FieldSpec("quantity", "", required=False, doc="lower limit (in the signal's units)"),
            "max": FieldSpec("quantity", "", required=False, doc="upper limit"),
            "reference": FieldSpec("str", required=False, default="", doc="name of an earlier check to compare with"),
            "max_difference": FieldSpec("quantity", "", required=False, minimum=0.0, doc="with reference: allowed |value - reference|"),
        },
        "Compute a statistic of a recorded signal and compare it with limits; the result is stored.",
    ),
}
"""Action steps of schema version 1 (executed by the runner)."""

REQUIREMENTS: dict[str, str] = {
    "unit": "true: `bench run` needs `--unit SERIAL` (the unit under test is recorded in the run file)",
}
"""Keys of the top-level ``requires:`` mapping (each a bool, default false): what a run of the
procedure must be given. ``validate`` and ``plan`` accept them; ``run`` enforces them."""

BLOCK_TYPES: dict[str, str] = {
    "repeat": "repeat `steps` `count` times (loop variable `$iteration`, 1-based)",
    "for_each": "run `steps` once per value of `values`, with the loop variable `$VAR` set",
    "call": "run another procedure file with `args` for its parameters",
    "rate_steps": "a rate schedule on the table or the bench: rate, settle, record a window per rate",
}
"""Block steps, expanded by the loader into action steps."""

SIGNAL_UNITS_HINT = {"degC": TEMPERATURE_DIFFERENCE}
"""A band or limit on a signal in degC is a temperature difference when compared with max-min."""
