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
from typing import TYPE_CHECKING, Any, Callable

from bench.kinds import registry
from bench.sim.power import wire_power
from bench.sim.registry import SerialDevice
from bench.sim.serial_faults import FaultySerialLink
from bench.sim.world import World

if TYPE_CHECKING:  # pragma: no cover
    from bench.config import LabConfig

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
    ``device``: the simulator object with the fault hooks. ``power_input``: what another simulated
    instrument powers (a unit under test), ``power_outputs``: output name -> what it powers others
    with (a supply) (:mod:`bench.sim.power`).
    """

    name: str
    device: object
    serial: dict[str, SerialDevice] = field(default_factory=dict)
    url: str | None = None
    url_kwargs: dict[str, str] = field(default_factory=dict)
    endpoints: list[tuple[str, str]] = field(default_factory=list)
    closers: list[Callable[[], None]] = field(default_factory=list)
    power_input: Any = None
    power_outputs: dict[str, Any] = field(default_factory=dict)

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


@dataclass
class SimContext:
    """What a kind's simulator builder (``SimSpec.builder``) gets besides the instrument: the lab's
    ``clock`` and ``world``, whether network servers bind the config's ports (``fixed_ports``,
    ``bench sim serve``) and whether the dry-run's links are in-process (``inprocess``)."""

    clock: Any
    world: World
    fixed_ports: bool = False
    inprocess: bool = True

    def can_channel(self, base: str, name: str) -> str:
        """The CAN channel of instrument ``name``'s simulated bus: the config's under ``bench sim
        serve``, else one private to this lab, so parallel dry-runs never share a bus."""
        return base if self.fixed_ports else f"{base}-{name}-{id(self.world):x}"


def serial_only(name: str, device, seed: int = 0) -> SimInstrument:
    """A simulated instrument on one serial link (fault hooks on its bytes)."""
    return SimInstrument(name, device, serial={"": FaultySerialLink(device, seed)})


def scpi_socket(out: SimInstrument, device, port: int) -> None:
    """Also serve ``device`` (a line device answering SCPI) on a raw TCP socket of 127.0.0.1 (VISA
    ``TCPIP::HOST::PORT::SOCKET``), stopped with the instrument."""
    from bench.sim.scpi_socket import ScpiSocketServer

    server = ScpiSocketServer(device)
    bound = server.start(LOCALHOST, port)
    out.closers.append(server.stop)
    out.endpoints.append(("tcp", f"{LOCALHOST}:{bound} (SCPI raw socket, VISA TCPIP::{LOCALHOST}::{bound}::SOCKET)"))


def build_devices(config: "LabConfig", clock, names: list[str] | None = None, *, world: World | None = None,
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
    world = world or World(config.world)
    ctx = SimContext(clock, world, fixed_ports, transport == "inprocess" and not fixed_ports)
    out: dict[str, SimInstrument] = {}
    try:
        for name, inst in config.instruments.items():
            if names is not None and name not in names:
                continue
            if inst.sim is None:
                raise ValueError(f"instrument {name!r} has no 'sim' section in {config.path}; it cannot be simulated")
            out[name] = registry.load(inst.kind.sim.builder)(name, inst, ctx)
        wire_power(config, out, clock)
    except BaseException:
        for sim in out.values():
            sim.close()
        raise
    return out


