"""The procedure schema ``bench-procedure/1``: step types and their fields, as data.

Each step is a one-key mapping ``{TYPE: {field: value, ...}}`` (``comment`` takes a string).
Every step may also carry ``name``. Quantities are strings with units ("30 min", "100 Hz") or bare
numbers in the field's unit. ``docs/procedures.md`` shows an example of every step type.
"""

from __future__ import annotations

from dataclasses import dataclass

SCHEMA_ID = "bench-procedure/1"


@dataclass(frozen=True)
class FieldSpec:
    """One field of a step. ``kind``: instrument | quantity | int | bool | str."""

    kind: str
    units: str = ""
    required: bool = True
    default: object = None
    minimum: float | None = None
    maximum: float | None = None
    doc: str = ""


@dataclass(frozen=True)
class StepSpec:
    fields: dict[str, FieldSpec]
    doc: str
    scalar_field: str | None = None  # a step written as ``TYPE: value`` fills this field


INSTRUMENT = FieldSpec("instrument", doc="name of an instrument in the procedure's `instruments` list")

STEP_TYPES: dict[str, StepSpec] = {
    "comment": StepSpec({"text": FieldSpec("str", doc="text shown and recorded")}, "A note for the operator and the record.", "text"),
    "power": StepSpec(
        {"instrument": INSTRUMENT, "on": FieldSpec("bool", doc="true to power the sensors, false to switch them off")},
        "Switch an instrument's sensor supply on or off.",
    ),
    "configure": StepSpec(
        {
            "instrument": INSTRUMENT,
            "odr": FieldSpec("quantity", "Hz", required=False, minimum=1, maximum=1000, doc="output data rate"),
            "moving_average": FieldSpec("int", required=False, minimum=1, maximum=100, doc="moving-average buffer length N"),
        },
        "Set a sensor board's output data rate and moving-average length.",
    ),
    "record": StepSpec(
        {
            "instrument": INSTRUMENT,
            "duration": FieldSpec("quantity", "s", minimum=0.0, doc="how long to record"),
            "window": FieldSpec("str", required=False, default="", doc="name of the recording window"),
        },
        "Stream and record an instrument's data for a duration.",
    ),
    "wait": StepSpec({"duration": FieldSpec("quantity", "s", minimum=0.0, doc="how long to wait")}, "Wait."),
    "bit": StepSpec(
        {"instrument": INSTRUMENT, "expect_mask": FieldSpec("int", required=False, default=0, minimum=0, maximum=0xFFFF, doc="expected failed-subsystem mask")},
        "Run the built-in test; the step fails unless the failed mask equals expect_mask.",
    ),
}
"""Step types of schema version 1. A later schema version adds chamber, table and bench steps."""
