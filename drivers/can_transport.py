"""CAN transport shared by CAN drivers: open a python-can bus from a ``can://`` URL with typed errors.

URL forms (``docs/rate-table.md``)::

    can://virtual/CHANNEL?node=1                      python-can virtual bus (in-process)
    can://sync/CHANNEL?node=1                         synchronous in-process bus (:class:`SyncBus`)
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

import collections
import threading
import time
import urllib.parse
from dataclasses import dataclass, field
from typing import Callable

import can

from drivers.errors import InstrumentError

INTERFACES = ("virtual", "sync", "slcan", "socketcan")
DEFAULT_NODE = 1
DEFAULT_SLCAN_BITRATE = 500_000  # python-can slcan "S6"; a common CANopen bit rate (CiA 301 table)
DEFAULT_TTY_BAUDRATE = 115_200  # python-can slcan default
_OPTIONS = {
    "virtual": {"node"},
    "sync": {"node"},
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
        if u.interface == "sync":
            return SyncBus(u.channel)
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


SYNC_RX_QUEUE = 1024
"""Frames a :class:`SyncBus` without listeners keeps for :meth:`SyncBus.recv` (the oldest are dropped)."""
_sync_channels: dict[str, list["SyncBus"]] = {}
_sync_lock = threading.Lock()


class SyncBus(can.BusABC):
    """A python-can bus in this process whose frames are delivered at once, in the sender's thread:
    :meth:`send` calls the listeners of every other :class:`SyncBus` on the same channel name before
    it returns. No queue, no thread: a request and the replies it causes are one call stack, so a
    protocol stack on a virtual clock (canopen's SDO client, a simulated drive) never waits on the
    wall clock. Listeners are attached with :meth:`add_listener` (or :func:`connect_network` for a
    canopen network) instead of a ``can.Notifier``; a bus without listeners keeps the last
    :data:`SYNC_RX_QUEUE` frames for :meth:`recv`. Error frames are delivered like data frames."""

    def __init__(self, channel: str, **kwargs) -> None:
        self.channel_id = channel
        self.channel_info = f"synchronous in-process channel {channel}"
        self._listeners: list[Callable[[can.Message], None]] = []
        self._rx: collections.deque[can.Message] = collections.deque(maxlen=SYNC_RX_QUEUE)
        self._rx_ready = threading.Condition()
        super().__init__(channel=channel, **kwargs)
        with _sync_lock:
            _sync_channels.setdefault(channel, []).append(self)

    def add_listener(self, listener: Callable[[can.Message], None] | can.Listener) -> None:
        """Call ``listener`` (a callable or a ``can.Listener``) with every frame another bus sends."""
        self._listeners.append(listener.on_message_received if isinstance(listener, can.Listener) else listener)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self._is_shutdown:
            raise can.CanOperationError("Cannot operate on a closed bus")
        with _sync_lock:
            peers = [b for b in _sync_channels.get(self.channel_id, ()) if b is not self]
        stamp = time.time()
        for bus in peers:
            bus._deliver(can.Message(timestamp=stamp, arbitration_id=msg.arbitration_id, is_extended_id=msg.is_extended_id,
                                     is_remote_frame=msg.is_remote_frame, is_error_frame=msg.is_error_frame,
                                     dlc=msg.dlc, data=bytes(msg.data), is_rx=True, channel=self.channel_id))

    def _deliver(self, msg: can.Message) -> None:
        if self._listeners:
            for listener in list(self._listeners):
                listener(msg)
            return
        with self._rx_ready:
            self._rx.append(msg)
            self._rx_ready.notify()

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        with self._rx_ready:
            if not self._rx:
                self._rx_ready.wait(timeout)
            return (self._rx.popleft() if self._rx else None), False

    def shutdown(self) -> None:
        super().shutdown()
        with _sync_lock:
            peers = _sync_channels.get(self.channel_id, [])
            if self in peers:
                peers.remove(self)
            if not peers:
                _sync_channels.pop(self.channel_id, None)


def connect_network(network) -> None:
    """Connect a ``canopen.Network`` built on its bus: ``network.connect()`` (python-can's notifier
    thread feeds it), except on a :class:`SyncBus`, whose sends call the network's listeners
    directly (``network.notifier`` stays None; ``network.disconnect()`` works as usual)."""
    if isinstance(network.bus, SyncBus):
        for listener in network.listeners:
            network.bus.add_listener(listener)
    else:
        network.connect()
