"""Driver of a sensor board that speaks binary frames over a UART (or CAN), per its frame description.

The board's wire format is data (:class:`drivers.board_frames.FrameDescription`): ours by default
(``drivers/frames/acs_board.yaml``, docs/acs-board-protocol.md), or the lab's own
(docs/frame-descriptions.md). The driver sends the description's commands, waits for their
acknowledgement (or NAK) with a timeout, and decodes the data stream in batches with
:class:`drivers.frame_decoder.FrameDecoder`. Data frames that arrive while a command is waiting
for its reply are kept and returned by the next :meth:`poll`, so no sample is lost to a command.
Only idempotent reads (identify, get-config, built-in test) are retried. A command the
description does not have raises :class:`ProtocolError` naming it.

Units: those of the description's fields as decoded (gyro deg/s, accelerometer g, magnetometer
µT, temperatures °C, board time s).
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np
import serial

from drivers import board_frames
from drivers.acs_protocol import MOVING_AVG_MAX
from drivers.base import Driver, Transient, check_timeout
from drivers.board_frames import FrameDescription
from drivers.frame_decoder import DecodedBatch, FrameDecoder, merge_batches
from drivers.frame_schema import builtin_description
from drivers.errors import DeviceFault, InstrumentError, InstrumentTimeout, ProtocolError
from drivers.transport import link_bytes_per_s, open_serial

TrafficHook = Callable[[str, str, bytes], None]
"""Called with ("command" | "reply", frame name, raw frame bytes) for every command and its answer."""

DEFAULT_BAUDRATE = 115200
DEFAULT_TIMEOUT_S = 0.5


class AcsBoard(Driver):
    """One sensor board on a serial port (hardware, ``sim://`` simulator or pseudo-terminal), speaking
    the frames of ``description`` (ours when None).

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
        description: FrameDescription | None = None,
    ):
        self.port = port
        self.description = description or builtin_description()
        """The board's frames as data (:mod:`drivers.board_frames`)."""
        self.compensation = compensation
        """Gyro compensation (:class:`bench.model.compensation.Compensation`, NPSAT1 Eq. 2) or None."""
        self.timeout_s = check_timeout(timeout_s)
        self.read_attempts = 1 + retries
        self.name = "acs_board"
        self.on_traffic = on_traffic
        self.decoder = FrameDecoder(self.description)
        self._pending: list[DecodedBatch] = []
        self.unsolicited_replies = 0
        up = self.description.power_up
        self._known = {"odr_hz": up["odr_hz"], "moving_avg_n": up["moving_avg_n"], "streaming": bool(up["streaming"]),
                       "sensor_power": bool(up["sensors_on"]), "baud": getattr(port, "baudrate", 0) or 0}
        """The configuration as last commanded (what :meth:`get_config` says when the board has no GET_CONFIG)."""

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
        """Vendor, model, serial and firmware strings: those the board's reply carries."""
        return board_frames.parse_reply(self.description, "identify", self._transact("identify", idempotent=True))

    def get_config(self) -> dict:
        """Current output data rate (Hz), moving-average length, streaming, sensor power, baud rate as
        the board reports them (GET_CONFIG; a value its reply lacks: as last commanded). A board
        without GET_CONFIG: what the driver last commanded, with ``read_back: False``."""
        if "get_config" not in self.description.commands:
            return dict(self._known, read_back=False)
        got = board_frames.parse_reply(self.description, "get_config", self._transact("get_config", idempotent=True))
        return {**{k: v for k, v in self._known.items() if k not in got}, **got}

    def sensor_power(self, on: bool) -> None:
        """Switch the sensors' supply on or off (off also stops streaming)."""
        self._transact("sensor_power", power=1 if on else 0)
        self._known["sensor_power"] = bool(on)
        self._known["streaming"] = self._known["streaming"] and bool(on)

    def link_odr_limit_hz(self) -> int:
        """Highest output data rate the link carries: its bytes per second over the data frame's
        length (the board refuses rates beyond its own limit itself)."""
        link = getattr(self.port, "link_bytes_per_s", None) or link_bytes_per_s(self.port.baudrate)  # CAN ports know theirs
        return int(link // self.description.data_frame_len)

    def set_odr(self, hz: int) -> None:
        """Set the output data rate in Hz (integer, limited by the link: data frames at baud/10 bytes/s)."""
        limit = self.link_odr_limit_hz()
        if not 1 <= hz <= limit:
            raise ValueError(f"output data rate {hz} Hz outside 1..{limit} Hz for {self.port.baudrate} baud "
                             f"and {self.description.data_frame_len}-byte data frames")
        self._transact("set_odr", odr_hz=int(hz))
        self._known["odr_hz"] = int(hz)

    def set_moving_average(self, n: int) -> None:
        """Set the moving-average buffer length N (1..100 samples; the board pre-fills the buffer)."""
        if not 1 <= n <= MOVING_AVG_MAX:
            raise ValueError(f"moving-average length {n} outside 1..{MOVING_AVG_MAX}")
        self._transact("set_moving_avg", n=int(n))
        self._known["moving_avg_n"] = int(n)

    def start_stream(self) -> None:
        self._transact("start_stream")
        self._known["streaming"] = True

    def stop_stream(self) -> None:
        self._transact("stop_stream")
        self._known["streaming"] = False

    def run_bit(self) -> int:
        """Run the built-in test; returns the failed-subsystem mask (0 = all passed)."""
        return int(board_frames.parse_reply(self.description, "run_bit", self._transact("run_bit", idempotent=True))["failed_mask"])

    def safe_state(self) -> str:
        """Stop streaming (the sensors stay powered: a stationary board is harmless)."""
        self.stop_stream()
        return f"{self.description.commands['stop_stream'].op.upper()}: streaming stopped (sensors left powered)"

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

    def stream_columns(self) -> list[tuple[str, str, str, tuple[int, ...]]]:
        """``(name, units, dtype, row shape)`` of the recorded columns of the data stream
        (:meth:`drivers.board_frames.FrameDescription.stream_columns`)."""
        return self.description.stream_columns()

    def compensated_gyro(self, batch: DecodedBatch) -> np.ndarray:
        """The batch's gyro rates compensated with :attr:`compensation` (n, 3) deg/s, using the gyro
        die temperature (first temperature channel, °C). Raises ``ValueError`` without one."""
        if self.compensation is None:
            raise ValueError("acs_board: no calibration configured (instrument 'calibration:' in the lab config)")
        temp = batch.columns["temp"]
        return self.compensation.apply(batch.columns["gyro"], temp[:, 0] if temp.ndim == 2 else temp,
                                       batch.columns.get("accel"))

    def _feed(self, data: bytes) -> DecodedBatch:
        batch = self.decoder.feed(data)
        self._pending.append(batch)
        return batch

    def _transact(self, op: str, *, idempotent: bool = False, **values: Any) -> bytes:
        """Send command ``op`` with ``values`` and return the payload of its acknowledgement (an
        idempotent one is sent again when no reply comes, :attr:`read_attempts` times in all)."""
        d = self.description
        cmd = d.commands.get(op)
        if cmd is None:
            raise ProtocolError(f"acs_board: the board's frame description {d.name!r} has no {op} command "
                                f"(it has: {', '.join(d.commands)})")
        return self._exchange(cmd, board_frames.pack_items(d, cmd.payload, values), idempotent=idempotent)

    def _exchange(self, cmd: board_frames.Command, payload: bytes, *, idempotent: bool = False) -> bytes:
        """Send ``cmd`` with ``payload`` as it is; its acknowledgement's payload (see :meth:`_transact`)."""
        d = self.description
        frame = d.encode_frame(cmd.id, payload)
        name = cmd.op.upper()
        attempts = self.read_attempts if idempotent else 1
        budget = max(256, int(link_bytes_per_s(self.port.baudrate) * self.timeout_s))
        nak_id = d.nak.id if d.nak is not None else None

        def attempt(_: int) -> bytes:
            try:
                self.port.write(frame)
            except serial.SerialException as exc:
                raise InstrumentError(f"acs_board: writing {name} failed: {exc}") from None
            self._traffic("command", cmd.id, frame)
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
                    nak = None
                    if rtype == nak_id:
                        refused, code = board_frames.parse_nak(d, rpayload)
                        if refused is not None and refused != cmd.id:
                            continue  # another command's NAK
                        nak = code
                    elif rtype != cmd.reply.id:
                        continue
                    del batch.replies[i]
                    self._traffic("reply", rtype, d.encode_frame(rtype, rpayload))
                    if nak is not None:
                        reason = d.nak.names.get(nak, f"code {nak}")
                        if reason == "NOT_ALLOWED_IN_STATE":
                            raise DeviceFault(f"acs_board refused {name}: not allowed in its current state")
                        raise ProtocolError(f"acs_board refused {name}: {reason}")
                    return rpayload
            raise Transient(InstrumentTimeout(f"acs_board: no reply to {name} within {self.timeout_s:g} s ({attempts} attempt(s))"))

        return self.read_retrying(attempt, attempts=attempts)

    def _traffic(self, direction: str, ftype: int, raw: bytes) -> None:
        if self.on_traffic is not None:
            self.on_traffic(direction, self.description.frame_name(ftype), raw)
