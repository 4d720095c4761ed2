"""Kind ``stepper_bench``: the ESTCube-2 rotating bench, a stepper driven by stock GRBL 1.1 on an
Arduino (docs/stepper-bench.md)."""

from bench.kinds.record import FieldSpec, Kind, Limit, RateSchedule, Signal, SimSpec, StepDef, StepSpec, instrument_field

_M = "bench.kinds.stepper_bench"
BENCH = instrument_field("stepper_bench")
_ARDUINO = "an Arduino: the stepper bench runs stock GRBL 1.1 on one (driver: stepper_bench; set-up: docs/stepper-bench.md)"

KIND = Kind(
    name="stepper_bench",
    summary="stepper rotating bench on stock GRBL 1.1 (serial, G-code jogging)",
    driver="drivers.stepper_bench:StepperBench",
    settings=f"{_M}.settings:settings",
    sim=SimSpec(f"{_M}.sim:build", settings=f"{_M}.settings:sim_settings"),
    safe_state_timeout_s=5.0,
    safe_state_source="[U] a moving axis must be confirmed at rest within a few seconds (docs/reliability.md)",
    moves=True,
    standard_name="stepper_bench",
    noun="stepper bench",
    signals=(
        Signal("angle", "deg", "bench_angle", label="stepper bench"),
        Signal("rate", "deg/s"),
    ),
    # "limited the speed to maximum of about 3.5 deg/s" (ESTCube-2 section 5)
    limits=(Limit("rate", "deg/s", (-3.5, 3.5), magnitude="signed", source="ESTCube-2 section 5: about 3.5 deg/s at most"),),
    steps=(
        StepDef("bench_rate", StepSpec(
            {"instrument": BENCH, "rate": FieldSpec("quantity", "deg/s", doc="bench rate (signed; 0 stops)"),
             "settle": FieldSpec("quantity", "s", required=False, default=0.0, minimum=0.0, doc="wait this long afterwards")},
            "Turn the stepper bench at a rate (GRBL jogging at that feed; 0 stops it with a jog cancel)."),
            f"{_M}.steps:bench_rate", "bench.procedure.estimate:settle", limits=(("rate", "rate"),), moves=True),
    ),
    reading=f"{_M}.reading:reading",
    timeout_note="an Arduino may reset when the port opens (DTR) and GRBL answers only about 2 s later",
    serial_faults=("serial_unplug", "serial_noise", "serial_corrupt"),
    rate_schedule=RateSchedule("bench_rate", "bench_rate", (("rate", 0.0),)),
    usb_ids=((0x2341, _ARDUINO), (0x2A03, _ARDUINO)),
    example="""driver: stepper_bench
port: /dev/ttyACM0          # the Arduino Uno running GRBL 1.1
steps_per_deg: 894.33       # GRBL $100
max_rate: 3.5 deg/s
sim: {backend: stepper_bench, serial: SIM-0002, steps_per_deg: 894.33}
""",
    docs="docs/stepper-bench.md",
)
