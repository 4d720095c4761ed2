"""CAN transport shared by CAN drivers: open a python-can bus from a ``can://`` URL with typed errors.

URL forms (``docs/rate-table.md``)::

    can://virtual/CHANNEL?node=1                      python-can virtual bus (in-process)
    can://slcan/DEVICE?bitrate=500000&node=1          SLCAN (LAWICEL) USB-CAN adapter on a serial device
    can://socketcan/can0?node=1                       Linux SocketCAN interface

``DEVICE`` is anything ``serial.serial_for_url`` opens: ``/dev/ttyACM0`` (written
``can://slcan//dev/ttyACM0`` or ``can://slcan/dev/ttyACM0``), ``/dev/pts/3``, or ``sim://NAME`` for a
simulated adapter registered in this process. Query options: ``node`` (CANopen node id, 1..127,
default 1), ``bitrate`` (bit/s; slcan default 500000, the CiA 301 / python-can ``S6`` setting),
slcan only: ``tty_baudrate`` (bit/s, default 115200 as python-can) and ``settle_s`` (s to wait after
opening the serial device; python-can waits 2 s for adapters that reset on open, default here 0).
An unknown option is an error, as in pyserial's URL handlers.
"""

from __future__ import annotations

import urllib.parse
from dataclasses import dataclass, field

import can

from drivers.errors import InstrumentError

INTERFACES = ("virtual", "slcan", "socketcan")
DEFAULT_NODE = 1
DEFAULT_SLCAN_BITRATE = 500_000  # python-can slcan "S6"; a common CANopen bit rate (CiA 301 table)
DEFAULT_TTY_BAUDRATE = 115_200  # python-can slcan default
_OPTIONS = {
    "virtual": {"node"},
    "socketcan": {"node", "bitrate"},
    "slcan": {"node", "bitrate", "tty_baudrate", "settle_s"},
}


@dataclass(frozen=True)
class CanUrl:
    """A parsed ``can://`` URL."""

    interface: str
    channel: str
    node: int = DEFAULT_NODE
    options: dict[str, str] = field(default_factory=dict)


def parse_can_url(url: str) -> CanUrl:
    """Split ``can://INTERFACE/CHANNEL?opts``; :class:`InstrumentError` naming the problem."""
    if not url.startswith("can://"):
        raise InstrumentError(f"not a CAN URL (expected can://INTERFACE/CHANNEL?node=N): {url!r}")
    rest = url[len("can://"):]
    interface, sep, tail = rest.partition("/")
    if interface not in INTERFACES or not sep:
        raise InstrumentError(f"CAN URL {url!r}: interface must be one of {', '.join(INTERFACES)}")
    channel, _, query = tail.rpartition("?") if "?" in tail else (tail, "", "")
    if not channel:
        raise InstrumentError(f"CAN URL {url!r} names no channel")
    if interface == "slcan" and channel.startswith("dev/"):
        channel = "/" + channel
    try:
        pairs = urllib.parse.parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query))
    except ValueError:
        raise InstrumentError(f"CAN URL {url!r}: malformed options {query!r}") from None
    options = dict(pairs)
    unknown = set(options) - _OPTIONS[interface]
    if unknown:
        raise InstrumentError(f"CAN URL {url!r}: unknown option(s) {', '.join(sorted(unknown))} for {interface}")
    try:
        node = int(options.pop("node", DEFAULT_NODE))
    except ValueError:
        raise InstrumentError(f"CAN URL {url!r}: node must be an integer") from None
    if not 1 <= node <= 127:
        raise InstrumentError(f"CAN URL {url!r}: node {node} outside 1..127")
    return CanUrl(interface, channel, node, options)


def open_bus(url: str | CanUrl) -> can.BusABC:
    """Open the python-can bus of ``url``. Raises :class:`InstrumentError` if it cannot be opened."""
    u = parse_can_url(url) if isinstance(url, str) else url
    try:
        if u.interface == "virtual":
            return can.Bus(interface="virtual", channel=u.channel, receive_own_messages=False)
        if u.interface == "socketcan":
            kwargs = {"bitrate": int(u.options["bitrate"])} if "bitrate" in u.options else {}
            return can.Bus(interface="socketcan", channel=u.channel, **kwargs)
        return can.Bus(
            interface="slcan",
            channel=u.channel,
            bitrate=int(u.options.get("bitrate", DEFAULT_SLCAN_BITRATE)),
            tty_baudrate=int(u.options.get("tty_baudrate", DEFAULT_TTY_BAUDRATE)),
            sleep_after_open=float(u.options.get("settle_s", 0.0)),
        )
    except (can.CanError, OSError, ValueError, ImportError) as exc:
        raise InstrumentError(f"cannot open CAN bus {u.interface}:{u.channel}: {exc}") from None
