"""Kind ``acs_board``: the sensor board under test — binary frames over a UART (or CAN), as its
frame description says (ours: drivers/frames/acs_board.yaml, docs/acs-board-protocol.md; a lab's own:
config ``frames:``, docs/frame-descriptions.md)."""

from bench.kinds.record import FieldSpec, Kind, Limit, Signal, SimSpec, StepDef, StepSpec, instrument_field

_M = "bench.kinds.acs_board"
BOARD = instrument_field("acs_board")

ROLES = {"gyro": "gyro", "accel": "accel", "mag": "mag", "temp": "sensor_temp"}
"""A board's field name -> its role (bench.kinds.record.ROLES), whatever frame description it has."""

KIND = Kind(
    name="acs_board",
    summary="sensor board under test: binary frames over UART or CAN, from its frame description",
    driver="drivers.acs_board:AcsBoard",
    settings=f"{_M}.settings:settings",
    sim=SimSpec(f"{_M}.sim:build", settings=f"{_M}.settings:sim_settings", transports=("uart", "can")),
    safe_state_timeout_s=30.0,
    safe_state_source="[U] as long as a link fault during the run is retried (reconnect_timeout)",
    streams=True,
    standard_name="acs_board",
    noun="sensor board",
    # our board's signals (drivers/frames/acs_board.yaml; tests/test_frame_descriptions.py checks the two
    # agree); a board with a frame description of its own has its own (BoardSettings.signals)
    signals=(
        Signal("gyro", "deg/s", "gyro", vector=True),
        Signal("accel", "g_n", "accel", vector=True),
        Signal("mag", "uT", "mag", vector=True),
        Signal("temp", "degC", "sensor_temp", vector=True,
               labels=("board temp: gyro die", "board temp: accel die", "board temp: board")),
    ),
    limits=(Limit("odr", "Hz", (1.0, 1000.0), source="the board's SET_ODR range (docs/acs-board-protocol.md)"),),
    steps=(
        StepDef("power", StepSpec({"instrument": BOARD, "on": FieldSpec("bool", doc="true to power the sensors, false to switch them off")},
                                  "Switch an instrument's sensor supply on or off."),
                f"{_M}.steps:power", f"{_M}.estimate:power", needs=(("", ("sensor_power",)),)),
        StepDef("configure", StepSpec(
            {
                "instrument": BOARD,
                "odr": FieldSpec("quantity", "Hz", required=False, minimum=1, maximum=1000, doc="output data rate"),
                "moving_average": FieldSpec("int", required=False, minimum=1, maximum=100, doc="moving-average buffer length N"),
            },
            "Set a sensor board's output data rate and moving-average length."),
            f"{_M}.steps:configure", limits=(("odr", "odr"),), needs=(("odr", ("set_odr",)), ("moving_average", ("set_moving_avg",)))),
        StepDef("bit", StepSpec(
            {"instrument": BOARD, "expect_mask": FieldSpec("int", required=False, default=0, minimum=0, maximum=0xFFFF,
                                                           doc="expected failed-subsystem mask")},
            "Run the built-in test; the step fails unless the failed mask equals expect_mask."),
            f"{_M}.steps:bit", needs=(("", ("run_bit",)),)),
    ),
    reading=f"{_M}.reading:reading",
    timeout_note="the board streams binary frames at 115200 8N1 unless reconfigured",
    serial_faults=("serial_unplug", "serial_noise", "serial_corrupt", "stream_stall"),
    replay=f"{_M}.replay:wire",
    example="""driver: acs_board
port: /dev/ttyUSB0          # 115200 8N1
timeout: 0.5 s
sim: {backend: acs_board, seed: 1, serial: SIM-0001}
""",
    docs="docs/acs-board-protocol.md",
)
