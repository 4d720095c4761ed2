"""Put a simulated serial device (the ACS board) on a python-can bus as a CAN "serial tunnel".

Frames with id ``0x300 + node`` carry host -> device bytes (handed to ``device.receive`` in
order); the device's output goes back as frames with id ``0x380 + node``, 8 bytes each and a
shorter last one (``drivers/can_serial.py``, ``docs/acs-board-can.md``).

Time. The device is lazy: it produces data only when asked with a run time. One bridge thread
does everything, so the output order is the device's order: it waits up to ``pump_interval_s``
of wall time for host frames, hands any to the device, then takes the device's output at
``device.clock.now()`` and sends it. So a command is answered at once (in wall time, at the same
run time), and with a wall clock data flows in real time. Sync: a remote frame (RTR) on the
board -> host id is answered, after the output up to the current run time, with a zero-length
data frame on that id (the sync marker); :class:`drivers.can_serial.CanSerialPort` uses it on a
virtual clock to know that it has everything up to now.

Bandwidth. The bridge tells the device (``set_baudrate``) the UART-equivalent rate of the CAN
link (:func:`drivers.can_serial.uart_equivalent_baud`), so the board refuses (NAK BAD_VALUE) an
output data rate the bus cannot carry, exactly as over a UART: 763 Hz at 500 kbit/s.

Fault hooks (``inject(fault, **params)``, ``clear_faults()``):

* ``error_frames``: ``count`` (default 10) CAN error frames sent on the bus at once;
* ``bus_off``: the board's CAN controller is bus-off: host frames are not received and the
  device's output is discarded (``bytes_discarded``) until cleared;
* ``drop``: each board -> host frame is lost with probability ``p`` (default 1e-3, seeded).
"""

from __future__ import annotations

import threading

import can
import numpy as np

from drivers.can_serial import DEFAULT_BITRATE, DEFAULT_NODE, can_ids, segment, uart_equivalent_baud

PUMP_INTERVAL_S = 0.001  # wall time between looks at the device clock when no frame arrives
MAX_BATCH = 256  # host frames handled before the output is pumped again
FAULTS = ("error_frames", "bus_off", "drop")


class CanSerialBridge:
    """``device`` (a :class:`bench.sim.registry.SerialDevice`) on ``bus`` as CAN node ``node``.

    :param bus_or_channel: a python-can bus, or the name of a python-can virtual channel to join
    :param bitrate: nominal CAN bit rate (bit/s) for the link limit told to the device
    :param limit_link: tell the device the UART-equivalent link rate (``set_baudrate``)
    :param seed: seed of the ``drop`` fault's generator
    """

    def __init__(self, device, bus_or_channel: can.BusABC | str, node: int = DEFAULT_NODE, *,
                 bitrate: int = DEFAULT_BITRATE, limit_link: bool = True, seed: int = 0,
                 pump_interval_s: float = PUMP_INTERVAL_S) -> None:
        self.device = device
        self.clock = device.clock
        self.node = int(node)
        self.rx_id, self.tx_id = can_ids(self.node)  # the bridge receives host -> board, sends board -> host
        self.bitrate = int(bitrate)
        self.pump_interval_s = float(pump_interval_s)
        self._own_bus = isinstance(bus_or_channel, str)
        self.bus = (can.Bus(interface="virtual", channel=bus_or_channel, receive_own_messages=False)
                    if self._own_bus else bus_or_channel)
        if limit_link:
            device.set_baudrate(uart_equivalent_baud(self.bitrate))
        self._rng = np.random.default_rng(seed)
        self._lock = threading.Lock()
        self.bus_off = False
        self.drop_p = 0.0
        self.frames_received = 0
        self.frames_sent = 0
        self.frames_dropped = 0
        self.bytes_discarded = 0
        self.syncs_answered = 0
        self._syncs = 0
        self.error: BaseException | None = None  # what stopped the bridge thread, if anything
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"can-serial bridge node {self.node}", daemon=True)
        self._thread.start()

    @property
    def running(self) -> bool:
        return self._thread.is_alive()

    def close(self) -> None:
        """Stop the bridge thread and shut the bus down if the bridge opened it. Safe to call twice."""
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(1.0)
        if self._own_bus:
            self._own_bus = False
            self.bus.shutdown()

    # ---- fault hooks ------------------------------------------------------------------------
    def inject(self, fault: str, **params) -> None:
        """Inject ``fault`` (module docstring: ``error_frames``, ``bus_off``, ``drop``)."""
        if fault not in FAULTS:
            raise ValueError(f"unknown CAN fault {fault!r} (available: {', '.join(FAULTS)})")
        with self._lock:
            if fault == "error_frames":
                count = int(params.pop("count", 10))
                for _ in range(count):
                    self.bus.send(can.Message(is_error_frame=True, arbitration_id=0, is_extended_id=False))
            elif fault == "bus_off":
                self.bus_off = True
            else:
                p = float(params.pop("p", 1e-3))
                if not 0.0 <= p <= 1.0:
                    raise ValueError(f"drop probability {p} outside 0..1")
                self.drop_p = p
        if params:
            raise ValueError(f"unknown parameter(s) for {fault}: {', '.join(sorted(params))}")

    def clear_faults(self) -> None:
        """End bus-off and frame drops."""
        with self._lock:
            self.bus_off = False
            self.drop_p = 0.0

    # ---- the bridge thread ------------------------------------------------------------------
    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                batch = []
                msg = self.bus.recv(timeout=self.pump_interval_s)
                while msg is not None:
                    batch.append(msg)
                    if len(batch) >= MAX_BATCH:
                        break
                    msg = self.bus.recv(timeout=0)
                with self._lock:
                    for m in batch:
                        self._on_frame(m)
                    self._pump()
        except Exception as exc:  # noqa: BLE001 - kept for close()/tests; the host then sees silence
            if not self._stop.is_set():
                self.error = exc

    def _on_frame(self, msg: can.Message) -> None:
        if self.bus_off or msg.is_error_frame or msg.is_extended_id or msg.is_fd:
            return
        if msg.is_remote_frame:
            if msg.arbitration_id == self.tx_id:
                self._syncs += 1  # answered after the output up to now (see _pump)
            return
        if msg.arbitration_id == self.rx_id:
            self.frames_received += 1
            self.device.receive(bytes(msg.data))

    def _pump(self) -> None:
        data = self.device.take_output(self.clock.now())
        syncs, self._syncs = self._syncs, 0
        if self.bus_off:
            self.bytes_discarded += len(data)
            return
        for piece in segment(data):
            if self.drop_p and self._rng.random() < self.drop_p:
                self.frames_dropped += 1
                continue
            self.bus.send(can.Message(arbitration_id=self.tx_id, is_extended_id=False, data=piece))
            self.frames_sent += 1
        for _ in range(syncs):  # sync markers: zero-length frames, never dropped
            self.bus.send(can.Message(arbitration_id=self.tx_id, is_extended_id=False, dlc=0))
            self.syncs_answered += 1
