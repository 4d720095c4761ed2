"""Kind ``rate_table``: the 2-axis rate table, two CiA 402 drives (rotation, tilt) on CAN
(SocketCAN or an SLCAN adapter) (docs/rate-table.md)."""

from bench.kinds.record import LINK_WORDS, FaultDef, FieldSpec, Kind, Limit, RateSchedule, Signal, SimSpec, StepDef, StepSpec, instrument_field

_M = "bench.kinds.rate_table"
TABLE = instrument_field("rate_table")
_ESTIMATE = f"{_M}.estimate:table_step"

KIND = Kind(
    name="rate_table",
    summary="2-axis rate table: two CiA 402 drives (rotation, tilt) on CAN",
    driver="drivers.rate_table:RateTable",
    sim=SimSpec(f"{_M}.sim:build", settings=f"{_M}.settings:sim_settings"),
    safe_state_timeout_s=5.0,
    safe_state_source="[U] the quick stop from 60 deg/s takes 1 s per axis; 5 s leaves room for one reconnection "
                      "of 0.5 + 1 + 2 s (docs/reliability.md)",
    moves=True,
    needs_clock=True,
    standard_name="rate_table",
    noun="rate table",
    signals=(
        Signal("angle", "deg", "table_angle"),
        Signal("rate", "deg/s", "table_rate", label="rate table rate"),
        Signal("tilt", "deg", "table_tilt", label="rate table tilt"),
        Signal("statusword", ""),
        Signal("tilt_statusword", ""),
    ),
    # bench.sim.table_motion defaults [U] (docs/rate-table.md)
    limits=(
        Limit("rate", "deg/s", (-60.0, 60.0), magnitude="signed", source="[U] bench.sim.table_motion (docs/rate-table.md)"),
        Limit("accel", "deg/s**2", (0.0, 60.0), magnitude="positive", source="[U] bench.sim.table_motion"),
        Limit("tilt", "deg", (-120.0, 120.0), source="[U] bench.sim.table_motion"),
        Limit("angle", "deg"),
    ),
    steps=(
        StepDef("table_rate", StepSpec(
            {
                "instrument": TABLE,
                "rate": FieldSpec("quantity", "deg/s", doc="rotation rate (signed)"),
                "accel": FieldSpec("quantity", "deg/s**2", required=False, minimum=0.0, doc="acceleration limit (default: the drive's)"),
                "settle": FieldSpec("quantity", "s", required=False, default=0.0, minimum=0.0, doc="wait this long after reaching the rate"),
            },
            "Turn the rate table at a rate (profile velocity mode), wait until reached, then settle."),
            f"{_M}.steps:table_rate", _ESTIMATE, limits=(("rate", "rate"), ("accel", "accel")), moves=True),
        StepDef("table_move", StepSpec(
            {"instrument": TABLE, "angle": FieldSpec("quantity", "deg", doc="rotation angle to move to"),
             "rate": FieldSpec("quantity", "deg/s", required=False, minimum=0.0, doc="move speed (default: the drive's)")},
            "Move the table's rotation axis to an angle and wait until it is there."),
            f"{_M}.steps:table_move", _ESTIMATE, limits=(("rate", "rate"), ("angle", "angle")), moves=True),
        StepDef("table_tilt", StepSpec(
            {"instrument": TABLE, "angle": FieldSpec("quantity", "deg",
                                                     doc="tilt of the platter (0 = level; -latitude cancels Earth rate on the table axis)")},
            "Tilt the table and wait until it is there."),
            f"{_M}.steps:table_tilt", _ESTIMATE, limits=(("angle", "tilt"),), moves=True),
        StepDef("table_stop", StepSpec({"instrument": TABLE}, "Stop the table (both axes stay enabled).", "instrument"),
                f"{_M}.steps:table_stop", _ESTIMATE),
    ),
    reading=f"{_M}.reading:reading",
    faults=(
        FaultDef("can_error_frames", "transient", "a burst of CAN error frames (5-50), once", None,
                 LINK_WORDS + ("error frame", "SDO"), f"{_M}.faults:can_error_frames", rank=8),
        FaultDef("can_bus_off", "transient", "the drives fall silent (bus-off as the host sees it)", (1.0, 8.0),
                 LINK_WORDS + ("SDO", "silent"), f"{_M}.faults:can_bus_off", rank=9),
        FaultDef("table_stuck", "hazard", "the rate table's rotation axis seizes", None,
                 ("timeout", "never", "rate", "following", "stuck", "at rate"), f"{_M}.faults:table_stuck", rank=14),
    ),
    replay=f"{_M}.replay:wire",
    rate_schedule=RateSchedule("table_rate", "table_stop", accel=True),
    usb_ids=((0x16D0, "a CANable (SLCAN): the rate table's CAN bus (driver: rate_table, port: can://slcan/PATH?bitrate=500000&node=1)"),),
    example="""driver: rate_table
port: can://socketcan/can0?node=1      # rotation node 1, tilt node 2
timeout: 0.5 s
sim: {backend: rate_table, serial: SIM-0005, node_id: 1}
""",
    docs="docs/rate-table.md",
)
