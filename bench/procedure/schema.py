"""The procedure schema ``bench-procedure/1``: step types and their fields, as data.

Each step is a one-key mapping ``{TYPE: {field: value, ...}}`` (``comment`` and ``prompt`` also
take a string). Every step may also carry ``name``. Quantities are strings with units
("30 min", "-29 degC", "1e-5 Torr") or bare numbers in the field's unit. Any field value may be a
parameter or loop variable: ``$cold`` (the whole value) or ``${rate}`` inside text.
``docs/procedures.md`` shows an example of every step type.

Two kinds of steps: **actions** (:func:`step_types`: the core's and every installed kind's), which the runner executes, and **blocks**
(:data:`BLOCK_TYPES`: ``repeat``, ``for_each``, ``call``, ``rate_steps``), which the loader
expands into actions before anything runs — the runner never sees a loop.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from bench.kinds.record import WAIT_TIMEOUT, FieldSpec, StepDef, StepSpec, instrument_field
from bench.units import TEMPERATURE_DIFFERENCE

if TYPE_CHECKING:  # pragma: no cover
    from bench.kinds.record import Kind

__all__ = ["BLOCK_TYPES", "FieldSpec", "PROMPT_TIMEOUT_S", "REQUIREMENTS", "SCHEMA_ID", "STEP_TYPES", "StepSpec",
           "instrument_field", "kind_step", "step_types"]

SCHEMA_ID = "bench-procedure/1"


STREAMING = FieldSpec("instrument", streams=True, doc="name of an instrument in the procedure's `instruments` list (one that streams: a board)")
TIMEOUT = WAIT_TIMEOUT
PROMPT_TIMEOUT_S = 3600.0
"""Default wall time (s) a prompt waits for the operator's answer before the run aborts."""
STATISTICS = ("mean", "std", "min", "max", "rms", "slope", "count", "scale_factor_error", "bias")

CORE_STEP_TYPES: dict[str, StepSpec] = {
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
    "record": StepSpec(
        {
            "instrument": STREAMING,
            "duration": FieldSpec("quantity", "s", minimum=0.0, doc="how long to record"),
            "window": FieldSpec("str", required=False, default="", doc="name of the recording window (checks refer to it)"),
        },
        "Stream and record an instrument's data for a duration, as a named window.",
    ),
    "wait": StepSpec({"duration": FieldSpec("quantity", "s", minimum=0.0, doc="how long to wait")}, "Wait (polled instruments keep being logged).", "duration"),
    "wait_until_stable": StepSpec(
        {
            "signal": FieldSpec("signal", doc="INSTRUMENT.COLUMN of a polled instrument, e.g. thermocouples.ch101 or tvac.air_temp"),
            "band": FieldSpec("quantity", "", minimum=0.0, doc="max - min over the hold time must stay within this (in the signal's units)"),
            "hold": FieldSpec("quantity", "s", minimum=0.0, doc="how long the signal must stay within the band"),
            "timeout": TIMEOUT,
            "record": FieldSpec("instrument", required=False, streams=True, doc="stream this instrument (a board) meanwhile"),
            "window": FieldSpec("str", required=False, default="", doc="window name of that recording"),
        },
        "Wait until a signal is stable (e.g. temperature within 0.5 degC for 10 min); abort on timeout.",
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
            "record": FieldSpec("instrument", required=False, streams=True, doc="stream this instrument (a board) meanwhile"),
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
"""Action steps of schema version 1 that belong to no kind (the runner's own handlers)."""


def step_types() -> dict[str, StepSpec]:
    """Every action step type: the core's, then each installed kind's (``Kind.steps``)."""
    from bench.kinds import registry

    out = dict(CORE_STEP_TYPES)
    for kind in registry.kinds().values():
        for d in kind.steps:
            out.setdefault(d.type, d.spec)
    return out


def kind_step(stype: str) -> "tuple[Kind, StepDef] | None":
    """The kind that adds step type ``stype`` and its definition; None for a core step or an unknown one."""
    from bench.kinds import registry

    for kind in registry.kinds().values():
        for d in kind.steps:
            if d.type == stype:
                return kind, d
    return None


def __getattr__(name: str):  # noqa: ANN202 - the module's lazy constant
    if name == "STEP_TYPES":
        return step_types()
    raise AttributeError(name)


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
