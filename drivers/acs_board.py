"""Driver of the ACS/sensor board (binary frames over UART; protocol in docs/acs-board-protocol.md).

The driver sends commands, waits for their acknowledgement (or NAK) with a timeout, and decodes
the data stream in batches with :class:`drivers.acs_protocol.FrameDecoder`. Data frames that
arrive while a command is waiting for its reply are kept and returned by the next :meth:`poll`,
so no sample is lost to a command. Only idempotent reads (identify, get-config, built-in test)
are retried.

Units: gyro deg/s, accelerometer g, magnetometer µT, temperatures °C, board time s.
"""

from __future__ import annotations

import struct
from dataclasses import fields
from typing import Callable

import numpy as np
import serial

from drivers.base import Driver, Transient, check_timeout
from drivers.errors import DeviceFault, InstrumentError, InstrumentTimeout, ProtocolError
from drivers import acs_protocol as proto
from drivers.acs_protocol import DecodedBatch, FrameType, NakCode
from drivers.transport import link_bytes_per_s, open_serial

TrafficHook = Callable[[str, str, bytes], None]
"""Called with ("command" | "reply", frame name, raw frame bytes) for every command and its answer."""

DEFAULT_BAUDRATE = 115200
DEFAULT_TIMEOUT_S = 0.5


def merge_batches(batches: list[DecodedBatch]) -> DecodedBatch:
    """Concatenate decoded batches in order: arrays joined, reply lists joined, counts summed."""
    if len(batches) == 1:
        return batches[0]
    kwargs = {}
    for f in fields(DecodedBatch):
        values = [getattr(b, f.name) for b in batches]
        first = values[0]
        if isinstance(first, np.ndarray):
            kwargs[f.name] = np.concatenate(values, axis=0)
        elif isinstance(first, list):
            kwargs[f.name] = [item for v in values for item in v]
        else:
            kwargs[f.name] = sum(values)
    return DecodedBatch(**kwargs)


class AcsBoard(Driver):
    """One ACS/sensor board on a serial port (hardware, ``sim://`` simulator or pseudo-terminal).

    Idempotent commands (identify, get config, built-in test) are retried ``retries`` times when
    no reply comes; commands that change the board's state are sent once."""

    kind = "acs_board"
    streams = True  # the runner records a data stream of this instrument

    def __init__(
        self,
        port: serial.SerialBase,
        *,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        retries: int = 2,
        on_traffic: TrafficHook | None = None,
        compensation=None,
    ):
        self.port = port
        self.compensation = compensation
        """Gyro compensation (:class:`bench.model.compensation.Compensation`, NPSAT1 Eq. 2) or None."""
        self.timeout_s = check_timeout(timeout_s)
        self.read_attempts = 1 + retries
        self.name = "acs_board"
        self.on_traffic = on_traffic
        self.decoder = proto.FrameDecoder()
        self._pending: list[DecodedBatch] = []
        self.unsolicited_replies = 0

    @classmethod
    def open(cls, url: str, *, baudrate: int = DEFAULT_BAUDRATE, timeout_s: float = DEFAULT_TIMEOUT_S, clock=None, **kwargs) -> "AcsBoard":
        """Open the board on ``url``: a serial port (:func:`drivers.transport.open_serial`) or a CAN
        bus ``can://INTERFACE/CHANNEL?node=16`` (:func:`drivers.can_serial.open_can_serial`;
        ``clock``: the clock reads wait on, the lab's virtual clock in a dry-run)."""
        if url.startswith("can://"):
            from drivers.can_serial import open_can_serial

            return cls(open_can_serial(url, timeout_s, clock), timeout_s=timeout_s, **kwargs)
        return cls(open_serial(url, baudrate, timeout_s), timeout_s=timeout_s, **kwargs)

    def close(self) -> None:
        self.port.close()

    # ---- commands ---------------------------------------------------------------------------
    def identify(self) -> dict[str, str]:
        """Vendor, model, serial and firmware strings."""
        return proto.parse_identity(self._transact(FrameType.IDENTIFY, idempotent=True))

    def get_config(self) -> dict:
        """Current output data rate (Hz), moving-average length, streaming, sensor power, baud rate."""
        return proto.parse_config(self._transact(FrameType.GET_CONFIG, idempotent=True))

    def sensor_power(self, on: bool) -> None:
        """Switch the sensors' supply on or off (off also stops streaming)."""
        self._transact(FrameType.SENSOR_POWER, bytes([1 if on else 0]))

    def set_odr(self, hz: int) -> None:
        """Set the output data rate in Hz (integer, limited by the link: 38-byte frames at baud/10 bytes/s)."""
        link = getattr(self.port, "link_bytes_per_s", None) or link_bytes_per_s(self.port.baudrate)  # CAN ports know theirs
        limit = int(link // proto.DATA_FRAME_LEN)
        if not 1 <= hz <= limit:
            raise ValueError(f"output data rate {hz} Hz outside 1..{limit} Hz for {self.port.baudrate} baud")
        self._transact(FrameType.SET_ODR, struct.pack("<H", int(hz)))

    def set_moving_average(self, n: int) -> None:
        """Set the moving-average buffer length N (1..100 samples; the board pre-fills the buffer)."""
        if not 1 <= n <= proto.MOVING_AVG_MAX:
            raise ValueError(f"moving-average length {n} outside 1..{proto.MOVING_AVG_MAX}")
        self._transact(FrameType.SET_MOVING_AVG, bytes([int(n)]))

    def start_stream(self) -> None:
        self._transact(FrameType.START_STREAM)

    def stop_stream(self) -> None:
        self._transact(FrameType.STOP_STREAM)

    def run_bit(self) -> int:
        """Run the built-in test; returns the failed-subsystem mask (0 = all passed)."""
        return proto.parse_bit(self._transact(FrameType.RUN_BIT, idempotent=True))

    def safe_state(self) -> str:
        """Stop streaming (the sensors stay powered: a stationary board is harmless)."""
        self.stop_stream()
        return "STOP_STREAM: streaming stopped (sensors left powered)"

    # ---- data -------------------------------------------------------------------------------
    def poll(self) -> DecodedBatch:
        """Read everything the port has and decode it; includes data that arrived during commands."""
        waiting = self.port.in_waiting
        if waiting:
            self._feed(self.port.read(waiting))
        if not self._pending:
            return self.decoder.feed(b"")
        batch = merge_batches(self._pending)
        self._pending = []
        self.unsolicited_replies += len(batch.replies)
        return batch

    def compensated_gyro(self, batch: DecodedBatch) -> np.ndarray:
        """The batch's gyro rates compensated with :attr:`compensation` (n, 3) deg/s, using the gyro
        die temperature (first temperature channel, °C). Raises ``ValueError`` without one."""
        if self.compensation is None:
            raise ValueError("acs_board: no calibration configured (instrument 'calibration:' in the lab config)")
        return self.compensation.apply(batch.gyro_dps, batch.temp_degc[:, 0], batch.accel_g)

    def _feed(self, data: bytes) -> DecodedBatch:
        batch = self.decoder.feed(data)
        self._pending.append(batch)
        return batch

    def _transact(self, command: int, payload: bytes = b"", *, idempotent: bool = False) -> bytes:
        """Send one command and return the payload of its acknowledgement (an idempotent one is
        sent again when no reply comes, :attr:`read_attempts` times in all)."""
        frame = proto.encode_frame(command, payload)
        name = FrameType(command).name
        attempts = self.read_attempts if idempotent else 1
        budget = max(256, int(link_bytes_per_s(self.port.baudrate) * self.timeout_s))

        def attempt(_: int) -> bytes:
            try:
                self.port.write(frame)
            except serial.SerialException as exc:
                raise InstrumentError(f"acs_board: writing {name} failed: {exc}") from None
            self._traffic("command", command, frame)
            received = 0
            while received <= budget:
                try:
                    chunk = self.port.read(max(1, self.port.in_waiting))
                except serial.SerialException as exc:
                    raise InstrumentError(f"acs_board: reading the reply to {name} failed: {exc}") from None
                if not chunk:
                    break  # port timeout elapsed with nothing
                received += len(chunk)
                batch = self._feed(chunk)
                for i, (rtype, rpayload) in enumerate(batch.replies):
                    if rtype == (command | 0x80) or (rtype == FrameType.NAK and rpayload[:1] == bytes([command])):
                        del batch.replies[i]
                        self._traffic("reply", rtype, proto.encode_frame(rtype, rpayload))
                        if rtype == FrameType.NAK:
                            cmd, code = proto.parse_nak(rpayload)
                            if code == NakCode.NOT_ALLOWED_IN_STATE:
                                raise DeviceFault(f"acs_board refused {name}: not allowed in its current state")
                            reason = NakCode(code).name if code in NakCode._value2member_map_ else f"code {code}"
                            raise ProtocolError(f"acs_board refused {name}: {reason}")
                        return rpayload
            raise Transient(InstrumentTimeout(f"acs_board: no reply to {name} within {self.timeout_s:g} s ({attempts} attempt(s))"))

        return self.read_retrying(attempt, attempts=attempts)

    def _traffic(self, direction: str, ftype: int, raw: bytes) -> None:
        if self.on_traffic is not None:
            self.on_traffic(direction, proto.frame_name(ftype), raw)
