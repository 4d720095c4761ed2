"""Kind ``dc_supply`` for bench: a Rigol DP800-series programmable DC supply (DP832) that powers the
unit under test, SCPI over RS-232 or its LAN socket — a lab's own instrument in its own package.

bench finds it by its entry point (pyproject.toml: group ``bench.instruments``); everything bench
needs to know is this record. Its code is named by dotted path and imported when used: the driver
(:mod:`bench_dc_supply.driver`, bench's drivers layer only), the config keys
(:mod:`bench_dc_supply.settings`), the simulator (:mod:`bench_dc_supply.sim`,
:mod:`bench_dc_supply.simulator`), the ``supply`` step (:mod:`bench_dc_supply.steps`). README.md
cites the Programming Guide's pages for each command.
"""

from bench.kinds import FaultDef, FieldSpec, Figure, Kind, Limit, Signal, SimSpec, StepDef, StepSpec, instrument_field

_M = "bench_dc_supply"
SUPPLY = instrument_field("dc_supply")

KIND = Kind(
    name="dc_supply",
    summary="programmable DC supply powering the unit: Rigol DP800 (DP832) SCPI over RS-232 or LAN",
    driver=f"{_M}.driver:DcSupply",
    settings=f"{_M}.settings:settings",
    sim=SimSpec(f"{_M}.simulator:build", settings=f"{_M}.settings:sim_settings", tcp_ports=f"{_M}.settings:tcp_ports"),
    baudrate=9600,  # the DP800's RS-232 at its factory setting
    safe_state_timeout_s=10.0,
    safe_state_source="[U] a few commands and their read-back; told after what it powers (bench.runner.safe_state)",
    needs_clock=True,  # power_up waits the unit's settle time on the lab's clock (virtual in a dry-run)
    standard_name="psu",
    noun="supply",
    signals=(
        Signal("voltage*", "V", "supply_voltage", label="{column}", numbers=(1, 3)),
        Signal("current*", "A", "supply_current", label="{column}", numbers=(1, 3)),
    ),
    limits=(
        # the DP832's programmable ranges (Programming Guide, :APPLy table); a lab narrows them to its unit's
        Limit("voltage", "V", (0.0, 32.0), source="DP832 CH1/CH2 0-32 V (DP800 Programming Guide, :APPLy)"),
        Limit("current", "A", (0.0, 3.2), source="DP832 0-3.2 A (DP800 Programming Guide, :APPLy)"),
    ),
    steps=(
        StepDef("supply", StepSpec(
            {
                "instrument": SUPPLY,
                "output": FieldSpec("int", required=False, default=1, minimum=1, maximum=3, doc="output number (DP832: 1-3)"),
                "voltage": FieldSpec("quantity", "V", required=False, minimum=0.0, doc="output voltage"),
                "current": FieldSpec("quantity", "A", required=False, minimum=0.0, doc="current limit"),
                "on": FieldSpec("bool", required=False, doc="switch the output on (true) or off (false)"),
                "settle": FieldSpec("quantity", "s", required=False, default=0.0, minimum=0.0,
                                    doc="after switching on: wait this long before reading back (the unit comes up)"),
            },
            "Set a supply output's voltage and current limit and/or switch it on or off; it is read back "
            "(voltage, current, CV/CC) and a tripped protection aborts the run."),
            f"{_M}.steps:supply", "bench.procedure.estimate:settle", limits=(("voltage", "voltage"), ("current", "current"))),
    ),
    reading=f"{_M}.reading:reading",
    timeout_note="the DP800's RS-232 rate is set on its front panel (Utility > I/O Config, default 9600); on LAN use socket://HOST:5555",
    faults=(
        FaultDef("supply_trip", "hazard", "the unit's supply trips its over-current protection (output 1)", None,
                 ("tripped", "protection", "no frames", "supply"), f"{_M}.faults:supply_trip"),
    ),
    serial_faults=("serial_unplug", "serial_noise", "serial_corrupt"),
    figures=(Figure("unit power", ("voltage*", "current*"), "What the supply measured at its terminals."),),
    config_hint="dc_supply: port: PATH of the DP800's RS-232 (9600 8N1) or socket://HOST:5555, outputs: {1: {voltage: 5 V, current: 0.1 A}}",
    example="""driver: dc_supply
port: socket://192.168.1.40:5555       # the DP832's LAN socket (or its RS-232 port)
timeout: 1 s
outputs:
  1: {voltage: 5 V, current: 0.1 A, ovp: 5.5 V, ocp: 0.08 A, settle: 0.5 s}
sim: {backend: dc_supply, serial: DP8C000000001}
""",
    docs="examples/bench-dc-supply/README.md",
)
