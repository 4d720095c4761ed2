"""Simulated sensor board: answers its frame description byte for byte, data from the sensor model.

The board's wire format is data (:class:`drivers.board_frames.FrameDescription`; ours by default,
docs/acs-board-protocol.md; a lab's own, docs/frame-descriptions.md): the commands it accepts,
their replies and NAKs, the data frame's fields and status bits all follow it. Fields bench has
physics for are filled from the model and the world (``gyro``, ``accel``, ``mag``, temperatures
from the unit's temperature, the counter, the board clock, the status bits); any other field
carries its description's ``sim`` value.

The simulator is clock-driven and lazy: :meth:`AcsBoardSim.advance` produces, in one vectorised
batch, every data frame the board would have sent up to a run time, so a virtual clock can jump an
hour ahead and the data is the same as if it had been produced in real time. Commands are handled
when they arrive (:meth:`receive`), after the data frames that precede them in time.

Behaviour (``docs/acs-board-protocol.md``): the board powers up with sensors off, not streaming,
100 Hz output data rate and moving-average length 1. The moving-average buffer is pre-filled with
the first sample after sensor power-on or a length change (ESTCube-2 thesis section 3.3).

Sensor model: :class:`SimpleImuModel` (``model: imu_simple``, the default) or, for a model file
with ``model: npsat1_gyro``, :class:`GyroBoardModel`: the gyro of :mod:`bench.model.gyro` (NPSAT1
Eq. 1-3 with temperature, pressure, power-on time and stateful noise) and the simple model's
accelerometer and magnetometer (:func:`board_model_from_file`, docs/sensor-models.md).
"""

from __future__ import annotations

import dataclasses
import math
import threading
from typing import Any
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench import __version__
from bench.errors import InputError
from bench.model.gyro import GyroModel
from bench.model.imu_simple import Environment, ImuModelParams, SimpleImuModel
from bench.model.inputs import SensorInputs
from bench.sim.board_power import BOOT_S, SUPPLY_RANGE_V, board_current_a
from bench.sim.power import PowerInput
from bench.sim.world import World
from drivers import board_frames
from drivers.acs_protocol import MOVING_AVG_MAX
from drivers.board_frames import FrameDescription
from drivers.frame_decoder import FrameDecoder
from drivers.frame_schema import builtin_description

PRESSURE_STEP_S = 10.0
"""Largest spacing (s) of the chamber-pressure samples interpolated for the gyro model."""


@dataclass
class AcsBoardIdentity:
    vendor: str = "bench-sim"
    model: str = "ACS-IMU sim MPU-6000+LIS3MDL"
    serial: str = "SIM-0001"
    firmware: str = f"sim-{__version__}"


class GyroBoardModel:
    """Board sensors with the gyro of a :class:`GyroModel`, accelerometer and magnetometer of a
    :class:`SimpleImuModel` (whose parameters also give the board's low-pass cut-off, ``p``).

    The gyro model must have output path ``none``: the board quantises and averages itself
    (:func:`drivers.acs_protocol.physical_to_raw`, :meth:`AcsBoardSim._moving_average`). Its
    noise state carries over between batches; a drop of the time since power-on is a power cycle
    (new run-to-run bias)."""

    def __init__(self, gyro: GyroModel, imu: SimpleImuModel):
        if gyro.p.output != "none":
            raise ValueError("the board's gyro model must have output 'none' (the board quantises itself)")
        self.gyro = gyro
        self.imu = imu
        self.p = imu.p

    def sample(
        self, since_power_s: np.ndarray, temp_c: np.ndarray, env: Environment, odr_hz: float, *,
        t_s: np.ndarray, pressure_torr: np.ndarray | float | None = None, table_angle_deg: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Gyro (deg/s), accelerometer (g), magnetometer (µT) outputs (n, 3) before quantisation at
        run times ``t_s`` (s); ``env`` rate includes Earth rate (the world's)."""
        _, accel, mag = self.imu.sample(since_power_s, temp_c, env, odr_hz)
        inputs = SensorInputs(time_s=t_s, rate_dps=env.rate_dps, temp_c=temp_c, pressure_torr=pressure_torr,
                              power_on_s=since_power_s, specific_force_g=env.specific_force_g, table_angle_deg=table_angle_deg)
        return self.gyro.evaluate(inputs), accel, mag


def board_model_from_file(path: str | Path, rng: np.random.Generator) -> SimpleImuModel | GyroBoardModel:
    """The board's sensor model from a model file (``configs/sensors/*.yaml``): ``imu_simple`` →
    :class:`SimpleImuModel`; ``npsat1_gyro`` → :class:`GyroBoardModel` (gyro output path forced to
    ``none``; accelerometer and magnetometer with the :class:`ImuModelParams` defaults). Raises a
    located :class:`InputError` for a bad file or a model that cannot drive the board."""
    from bench.model.loader import load_sensor_model

    return board_model_from_spec(load_sensor_model(path), rng)


def board_model_from_spec(spec: Any, rng: np.random.Generator) -> SimpleImuModel | GyroBoardModel:
    """The board's sensor model from a loaded :class:`bench.model.loader.SensorModelSpec`."""
    if spec.imu is not None:
        return SimpleImuModel(spec.imu, rng)
    if spec.gyro is not None:
        return GyroBoardModel(spec.gyro_model(rng, output="none"), SimpleImuModel(ImuModelParams(), rng))
    raise InputError(f"model {spec.model!r} cannot drive the ACS board (expected imu_simple or npsat1_gyro)", spec.location, "model")


class AcsBoardSim:
    """The board: protocol state machine plus sensor sampling. Thread-safe (one lock)."""

    def __init__(
        self,
        clock,
        world: World,
        model: SimpleImuModel | GyroBoardModel,
        identity: AcsBoardIdentity | None = None,
        baudrate: int = 115200,
        bit_fail_mask: int = 0,
        description: FrameDescription | None = None,
    ):
        self.description = description or builtin_description()
        self.clock = clock
        self.world = world
        self.model = model
        self.identity = identity or AcsBoardIdentity()
        self.baudrate = baudrate
        self.bit_fail_mask = bit_fail_mask
        self._lock = threading.RLock()
        self.frames_sent = 0
        self.power = PowerInput(*SUPPLY_RANGE_V, self._draw, boot_s=BOOT_S, on_change=self._power_changed)
        """The board's power terminals: powered from -inf until a supply is connected
        (bench/sim/power.py; what it draws: bench/sim/board_power.py)."""
        self._power_up_state(clock.now())

    def _power_up_state(self, now: float) -> None:
        """The state the board boots into (its frame description's power-up state)."""
        d = self.description
        self._decoder = FrameDecoder(d, accept_unknown_types=True)
        self._out = bytearray()
        up = d.power_up
        self.sensor_power = bool(up["sensors_on"])
        self.power_on_t = 0.0
        self.streaming = False
        self.odr_hz = up["odr_hz"]
        self.moving_avg_n = up["moving_avg_n"]
        self._history: np.ndarray | None = None  # last N-1 raw samples (rows, 9)
        self._stream_t0 = 0.0
        self._next_k = 0
        if up["streaming"]:
            self._start_stream(now)
        self._counter = 0
        self._bit_failed = False

    # ---- power ------------------------------------------------------------------------------
    def _power_changed(self, t: float, powered: bool) -> None:
        """Power came (the board boots into its power-up state, after BOOT_S) or went (it stops)."""
        with self._lock:
            if math.isfinite(t):
                self._advance_locked(t)  # what it sent while it had power
            self._power_up_state(t if math.isfinite(t) else self.clock.now())
            if powered and self.streaming:
                self._stream_t0 += BOOT_S
            if not powered:
                self.streaming = False
            if math.isfinite(t):
                self.world.set_unit_power(t, self.sensor_power)

    def _draw(self, t: float, volts: float, since: float) -> float:
        with self._lock:
            return board_current_a(t, volts, since, sensors_on=self.sensor_power, streaming=self.streaming, odr_hz=self.odr_hz,
                                   frame_bytes=self.description.data_frame_len, baudrate=self.baudrate)

    # ---- link -------------------------------------------------------------------------------
    def max_odr_hz(self) -> int:
        """Highest output data rate the UART can carry (8N1 = 10 bits per byte, one data frame per
        sample) and the board allows."""
        return int(min(self.baudrate / 10 // self.description.data_frame_len, self.description.max_odr_hz))

    def set_baudrate(self, baudrate: int) -> None:
        with self._lock:
            self.baudrate = int(baudrate)

    # ---- host -> board ----------------------------------------------------------------------
    def receive(self, data: bytes) -> None:
        """Bytes written by the host at the current clock time (lost while the board is off or booting)."""
        with self._lock:
            now = self.clock.now()
            if not self.power.running(now):
                return
            self._advance_locked(now)
            batch = self._decoder.feed(bytes(data))
            if batch.crc_errors:
                for _ in range(batch.crc_errors):
                    self._nak(0, "crc_error")
            for ftype, payload in batch.replies:
                self._handle(ftype, payload)

    def _reply(self, ftype: int, payload: bytes = b"") -> None:
        self._out += self.description.encode_frame(ftype, payload)

    def _nak(self, command: int, reason: str) -> None:
        """The NAK of ``reason`` (the description's code; no answer where it has none)."""
        nak = self.description.nak
        if nak is None or nak.codes.get(reason) is None:
            return
        self._reply(nak.id, board_frames.pack_items(self.description, nak.payload, {"command": command & 0xFF, "code": nak.codes[reason]}))

    def _handle(self, ftype: int, payload: bytes) -> None:
        d = self.description
        cmd = d.command_by_id(ftype)
        if cmd is None:
            self._nak(ftype, "unknown_command")
            return
        values = board_frames.unpack_items(d, cmd.payload, payload)
        if values is None:
            self._nak(ftype, "bad_length")
            return
        if ("sensors_on" in cmd.requires and not self.sensor_power) or ("not_streaming" in cmd.requires and self.streaming):
            self._nak(ftype, "not_allowed_in_state")
            return
        now = self.clock.now()
        op = cmd.op
        if op == "set_odr" and not 1 <= values["odr_hz"] <= self.max_odr_hz():  # MPU-6000 ODR range 4..1000 Hz (ESTCube Table 2.1)
            self._nak(ftype, "bad_value")
            return
        if op == "set_moving_avg" and not 1 <= values["n"] <= MOVING_AVG_MAX:
            self._nak(ftype, "bad_value")
            return
        if op == "sensor_power" and values["power"] not in (0, 1):
            self._nak(ftype, "bad_value")
            return
        answer: dict = {}
        if op == "identify":
            i = self.identity
            answer = {"vendor": i.vendor, "model": i.model, "serial": i.serial, "firmware": i.firmware}
        elif op == "start_stream":
            if not self.streaming:
                self._start_stream(now)
        elif op == "stop_stream":
            self.streaming = False
        elif op == "set_odr":
            if self.streaming:
                self._stream_t0 = self._stream_t0 + (self._next_k - 1) / self.odr_hz
                self._next_k = 1
            self.odr_hz = values["odr_hz"]
        elif op == "set_moving_avg":
            self.moving_avg_n = values["n"]
            self._history = None  # re-filled with the next sample
        elif op == "run_bit":
            self._bit_failed = self.bit_fail_mask != 0
            answer = {"failed_mask": self.bit_fail_mask}
        elif op == "sensor_power":
            on = bool(values["power"])
            if on and not self.sensor_power:
                self.power_on_t = now
                self._history = None
            if not on:
                self.streaming = False
            self.sensor_power = on
            self.world.set_unit_power(now, self.sensor_power)
        if op in ("sensor_power", "start_stream", "stop_stream", "set_odr"):
            self.power.demand_changed(now)
        elif op == "get_config":
            answer = {"odr_hz": self.odr_hz, "moving_avg_n": self.moving_avg_n, "streaming": int(self.streaming),
                      "sensor_power": int(self.sensor_power), "baud": self.baudrate}
        self._reply(cmd.reply.id, board_frames.build_reply(d, op, answer, payload))

    def _start_stream(self, now: float) -> None:
        self.streaming = True
        self._stream_t0 = now
        self._next_k = 1  # first sample one period after the command

    # ---- board -> host ----------------------------------------------------------------------
    def advance(self, t_s: float) -> None:
        """Produce every data frame with a sample time <= ``t_s`` (run time, s)."""
        with self._lock:
            self._advance_locked(t_s)

    def _advance_locked(self, t_s: float) -> None:
        if not self.streaming:
            return
        period = 1.0 / self.odr_hz
        last_k = math.floor((t_s - self._stream_t0) * self.odr_hz + 1e-9)
        n = last_k - self._next_k + 1
        if n <= 0:
            return
        k = np.arange(self._next_k, last_k + 1, dtype=np.float64)
        self._next_k = last_k + 1
        t = self._stream_t0 + k * period
        self._out += self._frames(t)

    def _frames(self, t: np.ndarray) -> bytes:
        n = t.shape[0]
        temp = self.world.unit_temperature_c(t)
        env = self.world.environment(t)
        if self.world.vibration.overlaps(float(t[0]), float(t[-1])):
            # the shaker is bolted to the fixture: its acceleration is already in the unit's frame
            vib = self.world.vibration.specific_force_g(t, lowpass_hz=self.model.p.lowpass_cutoff_hz)
            env = dataclasses.replace(env, specific_force_g=np.broadcast_to(env.specific_force_g, vib.shape) + vib)
        if isinstance(self.model, GyroBoardModel):
            table_deg = self.world.stage.angle_deg(t) + self.world.table.rotation.angle_deg(t)
            gyro, accel, mag = self.model.sample(t - self.power_on_t, temp, env, self.odr_hz, t_s=t,
                                                 pressure_torr=self._pressure_torr(t), table_angle_deg=table_deg)
        else:
            gyro, accel, mag = self.model.sample(t - self.power_on_t, temp, env, self.odr_hz)
        raw = np.concatenate([gyro, accel, mag], axis=1)
        raw = self._moving_average(raw)
        d = self.description
        physical = {}
        for f in d.signals:
            if f.name in ("gyro", "accel", "mag"):
                k = ("gyro", "accel", "mag").index(f.name)
                physical[f.name] = raw[:, 3 * k: 3 * k + 3]
            elif f.quantity == "temperature":  # every temperature sensor of the board is at the unit's temperature
                physical[f.name] = temp if f.count == 1 else np.repeat(temp[:, None], f.count, axis=1)
            else:
                physical[f.name] = np.full((n,) + f.shape, f.sim)
        wire, saturated = d.to_raw(physical)
        bits = d.status_bits
        status_f = d.field("status")
        if status_f is not None:
            status = np.full(n, bits.get("always", 0) | bits.get("streaming", 0) | (bits.get("sensor_power", 0) if self.sensor_power else 0),
                             dtype=np.uint64)
            if self._bit_failed:
                status |= np.uint64(bits.get("bit_failed", 0))
            if saturated is not None and bits.get("saturated"):
                status[np.asarray(saturated, dtype=bool)] |= np.uint64(bits["saturated"])
            wire["status"] = status
        counter_f = d.field("counter")
        if counter_f is not None:
            mod = counter_f.modulus
            wire["counter"] = (self._counter + np.arange(n)) % mod
            self._counter = (self._counter + n) % mod
        wire["board_time"] = d.clock_ticks(t)
        self.frames_sent += n
        return d.encode_data(wire)

    def _pressure_torr(self, t: np.ndarray) -> np.ndarray:
        """Chamber pressure (Torr) at sample times ``t``: the chamber answers one time at a time,
        so it is sampled every PRESSURE_STEP_S at most and interpolated."""
        chamber = self.world.chamber
        span = float(t[-1] - t[0])
        if span <= PRESSURE_STEP_S:
            return np.full(t.shape[0], chamber.pressure_torr(float(t[-1])))
        grid = np.linspace(float(t[0]), float(t[-1]), int(span / PRESSURE_STEP_S) + 2)
        return np.interp(t, grid, [chamber.pressure_torr(float(x)) for x in grid])

    def _moving_average(self, raw: np.ndarray) -> np.ndarray:
        """N-sample boxcar over consecutive samples, buffer pre-filled with the first sample."""
        n_avg = self.moving_avg_n
        if n_avg == 1:
            return raw
        if self._history is None:
            self._history = np.repeat(raw[:1], n_avg - 1, axis=0)
        full = np.concatenate([self._history, raw], axis=0)
        csum = np.cumsum(np.concatenate([np.zeros((1, raw.shape[1])), full], axis=0), axis=0)
        out = (csum[n_avg:] - csum[:-n_avg])[-raw.shape[0]:] / n_avg
        self._history = full[-(n_avg - 1):]
        return out

    def take_output(self, t_s: float, max_bytes: int | None = None) -> bytes:
        """Advance to ``t_s`` and remove up to ``max_bytes`` of pending output."""
        with self._lock:
            self._advance_locked(t_s)
            if max_bytes is None or max_bytes >= len(self._out):
                data = bytes(self._out)
                self._out.clear()
            else:
                data = bytes(self._out[:max_bytes])
                del self._out[:max_bytes]
            return data

    def pending_bytes(self, t_s: float) -> int:
        with self._lock:
            self._advance_locked(t_s)
            return len(self._out)

    def next_output_time(self) -> float | None:
        """Run time (s) of the next data frame, or None when nothing more will come unasked."""
        with self._lock:
            if self._out:
                return self.clock.now()
            if not self.streaming:
                return None
            return self._stream_t0 + self._next_k / self.odr_hz

    def discard_input(self) -> None:
        """Forget partial command bytes (host reset its output buffer / reopened the port)."""
        with self._lock:
            self._decoder = FrameDecoder(self.description, accept_unknown_types=True)
