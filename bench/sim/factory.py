"""Build the simulators a lab config names, on one world and one clock.

Each instrument becomes a :class:`SimInstrument`: its serial devices (reached in-process as
``sim://NAME`` / ``sim://NAME.SUB``, or on pseudo-terminals under ``bench sim serve``), and, for
instruments whose link is not serial, the URL of the live endpoint.

Two transports for those (:data:`TRANSPORTS`), the same bytes on both: ``inprocess`` (the dry-run
default) answers in the caller's thread — the chamber controller's Modbus TCP (or RTU) ADUs on an
in-process byte stream (``modbus-tcp+stream://sim://NAME``), the rate table's CAN frames on a
synchronous in-process bus (``can://sync/CHANNEL``); ``socket`` is a real Modbus TCP server on
127.0.0.1 (a thread with an event loop), pymodbus's serial client for RTU, and a python-can virtual
bus with notifier threads. ``bench sim serve`` (``fixed_ports``) always uses the socket transport:
other processes connect to it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from bench.config import InstrumentConfig, LabConfig
from bench.model.imu_simple import SimpleImuModel
from bench.sim.acs_board import AcsBoardIdentity, AcsBoardSim
from bench.sim.registry import SerialDevice
from bench.sim.serial_faults import FaultySerialLink
from bench.sim.stepper_bench import StepperBenchSim, bench_eeprom
from bench.sim.thermocouple_reader import ThermocoupleReaderSim
from bench.sim.world import World

LOCALHOST = "127.0.0.1"
TRANSPORTS = ("inprocess", "socket")
"""How a dry-run reaches the simulators whose link is not a plain serial line (see the module docstring)."""


@dataclass
class SimInstrument:
    """One simulated instrument, ready for its driver.

    ``serial``: sub-name -> serial link (a :class:`FaultySerialLink` around the device: fault
    hooks on the bytes); ``""`` is the instrument's own link, others are auxiliary links
    (``gauge`` of the chamber, ``slcan`` adapter of a CAN bus). ``url``: the
    driver's URL when its own link is not serial, or wraps it (``modbus-rtu://sim://NAME``). ``url_kwargs``: driver keyword -> sub-name of
    the serial device whose URL it takes. ``endpoints``: (transport, address) lines for people.
    ``device``: the simulator object with the fault hooks.
    """

    name: str
    device: object
    serial: dict[str, SerialDevice] = field(default_factory=dict)
    url: str | None = None
    url_kwargs: dict[str, str] = field(default_factory=dict)
    endpoints: list[tuple[str, str]] = field(default_factory=list)
    closers: list[Callable[[], None]] = field(default_factory=list)

    def close(self) -> None:
        """Stop servers and buses (errors ignored: this runs on the way out)."""
        for close in reversed(self.closers):
            try:
                close()
            except Exception:  # noqa: BLE001 - closing must not mask the run's outcome
                pass
        self.closers.clear()


def serial_url(name: str, sub: str) -> str:
    """In-process URL of serial device ``sub`` of instrument ``name``."""
    return f"sim://{name}" if not sub else f"sim://{name}.{sub}"


def build_devices(config: LabConfig, clock, names: list[str] | None = None, *, world: World | None = None,
                  fixed_ports: bool = False, transport: str = "inprocess") -> dict[str, SimInstrument]:
    """One simulator per instrument (restricted to ``names`` if given), keyed by instrument name,
    all on one world: the stepper bench and the rate table turn the unit, the chamber heats it.

    ``fixed_ports``: bind network servers to the ports the config gives (``bench sim serve``, always
    the ``socket`` transport); otherwise any free port, so parallel dry-runs never collide.
    ``transport``: one of :data:`TRANSPORTS`. Raises ``ValueError`` naming an instrument that has no
    ``sim`` section, or for an unknown transport.
    """
    if transport not in TRANSPORTS:
        raise ValueError(f"dry-run transport {transport!r} is not one of {', '.join(TRANSPORTS)}")
    inprocess = transport == "inprocess" and not fixed_ports
    world = world or World(config.world)
    out: dict[str, SimInstrument] = {}
    try:
        for name, inst in config.instruments.items():
            if names is not None and name not in names:
                continue
            if inst.sim is None:
                raise ValueError(f"instrument {name!r} has no 'sim' section in {config.path}; it cannot be simulated")
            out[name] = _BUILDERS[inst.sim.backend](name, inst, clock, world, fixed_ports, inprocess)
    except BaseException:
        for sim in out.values():
            sim.close()
        raise
    return out


def _serial_only(name: str, device, seed: int = 0) -> SimInstrument:
    return SimInstrument(name, device, serial={"": FaultySerialLink(device, seed)})


def _acs_board(name: str, inst: InstrumentConfig, clock, world: World, fixed_ports: bool,
               inprocess: bool) -> SimInstrument:
    rng = np.random.default_rng(inst.sim.seed)
    if inst.sim.sensor_spec is not None:
        from bench.sim.acs_board import board_model_from_spec

        model = board_model_from_spec(inst.sim.sensor_spec, rng)
    else:
        model = SimpleImuModel(inst.sim.model, rng)
    dev = AcsBoardSim(clock, world, model, AcsBoardIdentity(serial=inst.sim.serial), baudrate=inst.baudrate,
                      bit_fail_mask=inst.sim.bit_fail_mask, description=inst.frames)
    if inst.sim.transport != "can":
        return _serial_only(name, dev, inst.sim.seed)
    from bench.sim.can_serial_bridge import CanSerialBridge

    node = inst.sim.node_id
    channel = inst.sim.can_channel if fixed_ports else f"{inst.sim.can_channel}-{name}-{id(world):x}"
    bridge = CanSerialBridge(dev, channel, node=node, seed=inst.sim.seed)
    return SimInstrument(name, bridge, url=f"can://virtual/{channel}?node={node}", closers=[bridge.close],
                         endpoints=[("can", f"python-can virtual channel {channel!r} (this process), node {node}")])


def _stepper_bench(name: str, inst: InstrumentConfig, clock, world: World, fixed_ports: bool,
                   inprocess: bool) -> SimInstrument:
    world.stage.periodic_errors = tuple(e for e in inst.sim.periodic_errors if e.amplitude)
    g = inst.sim.grbl
    eeprom = None if g.eeprom == "blank" else bench_eeprom(g.steps_per_deg, g.max_rate_dps * 60.0, g.acceleration_dps2,
                                                           g.axis, g.build_info)
    return _serial_only(name, StepperBenchSim(clock, world.stage, eeprom, axis=g.axis, pins=g.pins,
                                              dtr_reset_s=g.dtr_reset_s, baudrate=inst.baudrate,
                                              true_steps_per_deg=g.true_steps_per_deg))


def _thermocouple_reader(name: str, inst: InstrumentConfig, clock, world: World, fixed_ports: bool,
                         inprocess: bool) -> SimInstrument:
    from bench.sim.thermocouple_reader import KEYSIGHT_34970A

    dev = ThermocoupleReaderSim(clock, world, inst.sim.serial, tuple(inst.sim.open_channels), inst.baudrate,
                                spec=KEYSIGHT_34970A, installed_types=inst.tc_type, seed=inst.sim.seed)
    out = _serial_only(name, dev, inst.sim.seed)
    if fixed_ports:
        # other processes (PyVISA, a terminal) also reach it as a 34972A on its LAN SCPI socket
        from bench.sim.scpi_socket import ScpiSocketServer

        server = ScpiSocketServer(dev)
        port = server.start(LOCALHOST, inst.sim.scpi_port)
        out.closers.append(server.stop)
        out.endpoints.append(("tcp", f"{LOCALHOST}:{port} (SCPI raw socket, VISA TCPIP::{LOCALHOST}::{port}::SOCKET)"))
    return out


def _tvac(name: str, inst: InstrumentConfig, clock, world: World, fixed_ports: bool,
          inprocess: bool) -> SimInstrument:
    from bench.sim.tpg261 import Tpg261Sim
    from bench.sim.watlow_f4_server import WatlowF4Server

    gauge = Tpg261Sim(clock, world.chamber, baudrate=inst.gauge_baudrate)
    if inst.sim.transport == "rtu":  # the controller on its own serial link: sim://NAME, or a pty when served
        from bench.sim.watlow_f4_rtu import WatlowF4RtuSim

        rtu = WatlowF4RtuSim(clock, world.chamber, baudrate=inst.baudrate)
        scheme = "modbus-rtu+stream" if inprocess else "modbus-rtu"  # the stream client reads without polling the wall clock
        return SimInstrument(name, rtu, serial={"": FaultySerialLink(rtu, inst.sim.seed), "gauge": FaultySerialLink(gauge, inst.sim.seed)},
                             url=f"{scheme}://{serial_url(name, '')}", url_kwargs={"gauge_url": "gauge"})
    if inprocess:  # the same Modbus TCP ADUs on an in-process stream, answered in the caller's thread
        from bench.sim.watlow_f4_stream import WatlowF4StreamSim

        stream = WatlowF4StreamSim(clock, world.chamber)
        return SimInstrument(name, stream, serial={"": FaultySerialLink(stream, inst.sim.seed), "gauge": FaultySerialLink(gauge, inst.sim.seed)},
                             url=f"modbus-tcp+stream://{serial_url(name, '')}", url_kwargs={"gauge_url": "gauge"},
                             endpoints=[("modbus-tcp", f"in-process stream {serial_url(name, '')} (unit id 1)")])
    server = WatlowF4Server(clock, world.chamber)
    port = server.start(LOCALHOST, inst.sim.modbus_port if fixed_ports else 0)
    url = f"modbus-tcp://{LOCALHOST}:{port}"
    return SimInstrument(name, server, serial={"gauge": FaultySerialLink(gauge, inst.sim.seed)}, url=url, url_kwargs={"gauge_url": "gauge"},
                         endpoints=[("modbus-tcp", f"{LOCALHOST}:{port} (unit id 1)")], closers=[server.stop])


def _rate_table(name: str, inst: InstrumentConfig, clock, world: World, fixed_ports: bool,
                inprocess: bool) -> SimInstrument:
    from bench.sim.rate_table import RateTableSim

    node = inst.sim.node_id
    if inst.sim.periodic_errors:
        world.table.rotation.eccentricity = inst.sim.periodic_errors[0]  # the rotation axis's worm gear
    # in-process labs get a channel of their own, so parallel dry-runs never share a bus
    channel = inst.sim.can_channel if fixed_ports else f"{inst.sim.can_channel}-{name}-{id(world):x}"
    if inprocess:  # frames delivered in the sender's thread: no notifier threads, no queues
        from drivers.can_transport import SyncBus

        bus, interface, what = SyncBus(channel), "sync", "synchronous in-process CAN channel"
    else:
        bus, interface, what = channel, "virtual", "python-can virtual channel"
    sim = RateTableSim(clock, world.table.rotation, world.table.tilt, node_id=node, serial=inst.sim.serial, bus=bus)
    out = SimInstrument(name, sim, url=f"can://{interface}/{channel}?node={node}", closers=[sim.close],
                        endpoints=[("can", f"{what} {channel!r} (this process), nodes {node} rotation, {node + 1} tilt")])
    if fixed_ports:
        # other processes reach the bus through a simulated SLCAN USB-CAN adapter on a pseudo-terminal
        from bench.sim.slcan_gateway import SlcanGatewaySim

        gateway = SlcanGatewaySim(channel)
        out.serial["slcan"] = FaultySerialLink(gateway, inst.sim.seed)
        out.closers.insert(0, gateway.close)
    return out


_BUILDERS = {
    "acs_board": _acs_board,
    "stepper_bench": _stepper_bench,
    "thermocouple_reader": _thermocouple_reader,
    "tvac": _tvac,
    "rate_table": _rate_table,
}
