"""Kind ``thermocouple_reader``: a Keysight 34970A/34972A data acquisition unit with a 34901A
multiplexer reading thermocouples on the unit, SCPI on RS-232 (docs/thermocouples.md)."""

from bench.kinds.record import FaultDef, Kind, Signal, SimSpec

_M = "bench.kinds.thermocouple_reader"

KIND = Kind(
    name="thermocouple_reader",
    summary="thermocouple reader: Keysight 34970A/34972A with a 34901A, SCPI on RS-232 (or LAN)",
    driver="drivers.thermocouple_reader:ThermocoupleReader",
    settings=f"{_M}.settings:settings",
    sim=SimSpec(f"{_M}.sim:build", settings=f"{_M}.settings:sim_settings", tcp_ports=f"{_M}.settings:tcp_ports"),
    safe_state_timeout_s=30.0,
    safe_state_source="[U] as long as a link fault during the run is retried (reconnect_timeout)",
    standard_name="thermocouples",
    noun="thermocouple reader",
    signals=(Signal("ch*", "degC", "unit_temp", label="thermocouple {column}", numbers=(101, 399)),),
    reading=f"{_M}.reading:reading",
    timeout_note="the 34970A needs a null-modem cable and its RS-232 rate set on the front panel (Utility > Interface)",
    faults=(
        FaultDef("thermocouple_open", "hazard", "the unit's thermocouple ch101 opens", None,
                 ("open", "no valid reading", "interlock"), f"{_M}.faults:thermocouple_open", rank=13),
    ),
    serial_faults=("serial_unplug", "serial_noise", "serial_corrupt"),
    config_hint="thermocouple_reader: baudrate as set on the 34970A's front panel (Utility > Interface), e.g. 57600",
    example="""driver: thermocouple_reader
port: /dev/ttyUSB1          # the 34970A's RS-232, null-modem
baudrate: 57600
timeout: 1 s
channels: [101, 102]
sim: {backend: thermocouple_reader, serial: SIM-0003}
""",
    docs="docs/thermocouples.md",
)
