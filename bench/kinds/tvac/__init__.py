"""Kind ``tvac``: the thermal-vacuum chamber — a Watlow F4 controller on Modbus (TCP through a
gateway, or RTU) and a Pfeiffer TPG 261 gauge on RS-232 (docs/tvac.md)."""

from bench.kinds.record import (LINK_WORDS, WAIT_TIMEOUT, Envelope, FaultDef, FieldSpec, Kind, Limit, Signal, SimSpec, StepDef, StepSpec,
                                instrument_field)

_M = "bench.kinds.tvac"
CHAMBER = instrument_field("tvac")

KIND = Kind(
    name="tvac",
    summary="thermal-vacuum chamber: Watlow F4 controller (Modbus TCP or RTU) and Pfeiffer TPG 261 gauge",
    driver="drivers.tvac:TvacChamber",
    settings=f"{_M}.settings:settings",
    sim=SimSpec(f"{_M}.sim:build", settings=f"{_M}.settings:sim_settings", transports=("tcp", "rtu"),
                tcp_ports=f"{_M}.settings:tcp_ports"),
    baudrate=9600,  # Watlow F4 and TPG 261 ship at 9600 (protocols.md sections 1-2)
    safe_state_timeout_s=30.0,
    safe_state_source="[U] as long as a link fault during the run is retried (reconnect_timeout): the chamber's safe set point matters",
    standard_name="tvac",
    noun="chamber",
    signals=(
        Signal("air_temp", "degC", "air_temp", label="chamber air"),
        Signal("mount_temp", "degC", "mount_temp", label="chamber mount"),
        Signal("pressure", "Torr", "pressure", label="chamber pressure"),
    ),
    limits=(
        # -40 degC (assumed, below NPSAT1's -29) to +100 degC (bake-out, NPSAT1 IV.D.2)
        Limit("set_point", "degC", (-40.0, 100.0), source="-40 degC [U] below NPSAT1's -29 degC; +100 degC bake-out, NPSAT1 IV.D.2"),
        Limit("ramp", "delta_degC/min"),
        Limit("pressure", "Torr"),
    ),
    steps=(
        StepDef("set_temperature", StepSpec(
            {
                "instrument": CHAMBER,
                "set_point": FieldSpec("quantity", "degC", doc="chamber set point"),
                "ramp": FieldSpec("quantity", "delta_degC/min", required=False, minimum=0.0,
                                  doc="set-point ramp rate (0 or absent: step change, heater/cooler limited)"),
                "wait": FieldSpec("bool", required=False, default=False, doc="wait until the chamber air is within `band` of the set point"),
                "band": FieldSpec("quantity", "delta_degC", required=False, default=1.0, minimum=0.0, exclusive_minimum=True,
                                  doc="with wait: how close (default 1 degC; above 0: the air never sits exactly on the set point)"),
                "timeout": WAIT_TIMEOUT,
            },
            "Give the chamber a new set point (optionally ramped); optionally wait until the air reaches it."),
            f"{_M}.steps:set_temperature", f"{_M}.estimate:set_temperature", limits=(("set_point", "set_point"), ("ramp", "ramp"))),
        StepDef("pump_down", StepSpec(
            {"instrument": CHAMBER, "pressure": FieldSpec("quantity", "Torr", minimum=0.0, doc="wait until the pressure is at or below this"),
             "timeout": WAIT_TIMEOUT},
            "Close the vent, start the pumps and wait for the pressure."),
            f"{_M}.steps:pump_down", f"{_M}.estimate:pump_down", limits=(("pressure", "pressure"),)),
        StepDef("vent", StepSpec(
            {"instrument": CHAMBER, "pressure": FieldSpec("quantity", "Torr", required=False, default=700.0,
                                                          doc="wait until the pressure is at or above this"), "timeout": WAIT_TIMEOUT},
            "Stop the pumps, open the vent valve and wait for the pressure to rise."),
            f"{_M}.steps:vent", f"{_M}.estimate:vent"),
    ),
    reading=f"{_M}.reading:reading",
    timeout_note="the Watlow F4 ships at 9600 8N1, Modbus address 1 (?unit=N); on RS-485 swap A and B if nothing answers",
    faults=(
        FaultDef("gauge_unplug", "transient", "the pressure gauge's serial cable pulled and plugged back", (1.0, 8.0),
                 LINK_WORDS, f"{_M}.faults:gauge_unplug", rank=4),
        FaultDef("modbus_timeout", "transient", "the chamber controller stops answering Modbus requests", (1.0, 8.0),
                 LINK_WORDS, f"{_M}.faults:modbus_timeout", rank=5),
        FaultDef("modbus_busy", "transient", "the chamber controller answers exception 6 (device busy)", (1.0, 5.0),
                 LINK_WORDS + ("exception", "busy"), f"{_M}.faults:modbus_busy", rank=6),
        FaultDef("modbus_disconnect", "transient", "the Modbus TCP gateway drops and refuses connections", (1.0, 8.0),
                 LINK_WORDS + ("refused", "connect"), f"{_M}.faults:modbus_disconnect", rank=7),
        FaultDef("chamber_runaway", "hazard", "chamber temperature runs away at 5-20 degC/min", None,
                 ("lab safety", "interlock", "temperature", "not under control"), f"{_M}.faults:chamber_runaway", rank=11),
        FaultDef("control_sensor_open", "hazard", "the chamber's control thermocouple opens", None,
                 ("input error", "open"), f"{_M}.faults:control_sensor_open", rank=12),
    ),
    links=(("controller", r"^(read|write) \d+"), ("gauge", "")),
    replay=f"{_M}.replay:wire",
    # [U] our choice: above the overshoot of a controlled ramp, below damage (docs/reliability.md)
    envelope=Envelope("set_point", ("air_temp", "mount_temp"), 5.0, "degC", "air and mount temperature"),
    config_hint="tvac: port: modbus-rtu://PATH (Watlow F4, 9600 8N1, address 1) and gauge_port: PATH of the TPG 261",
    example="""driver: tvac
port: modbus-tcp://192.168.10.20:502   # the F4 behind a Modbus TCP gateway
gauge_port: /dev/ttyUSB2               # TPG 261
safe_set_point: 20 degC
timeout: 1 s
sim: {backend: tvac}
""",
    docs="docs/tvac.md",
)
