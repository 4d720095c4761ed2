"""Simulated stepper rotating bench: GRBL-style line protocol, turning the world's stage.

Commands (docs/stepper-bench.md): ``$I`` identify, ``$N=<int>`` speed parameter (sign =
direction), ``$RUN``, ``$STOP``, ``$S`` status; realtime bytes ``?`` (status report, no ``ok``),
``!`` (hold: stop at once), 0x18 (reset: stop, banner). Errors: ``error:2`` bad number or value,
``error:3`` unsupported command, ``error:9`` ``$RUN`` before a speed was set.

The rate produced by n follows the bench's own calibration (Eq. 3.1 with the sim's k, b), which is
what the driver's calibration must match; 1/8 microstepping of a 200-step motor gives positions
in steps of 360/1600 deg at the motor, far below the table's angle resolution reported here (mdeg).
"""

from __future__ import annotations

import threading

from bench import __version__
from bench.sim.stage import RotatingStage
from drivers.stepper_speed import BenchSpeedCalibration

BANNER = b"StepperBench sim ['$' for help]\r\n"
N_MAX = 65535


class StepperBenchSim:
    def __init__(self, clock, stage: RotatingStage, calibration: BenchSpeedCalibration | None = None,
                 serial_number: str = "SIM-0002", baudrate: int = 115200):
        self.clock = clock
        self.stage = stage
        self.cal = calibration or BenchSpeedCalibration()
        self.serial_number = serial_number
        self.baudrate = baudrate
        self.n = 0
        self.running = False
        self._in = bytearray()
        self._out = bytearray()
        self._lock = threading.RLock()

    # ---- SerialDevice -----------------------------------------------------------------------
    def set_baudrate(self, baudrate: int) -> None:
        self.baudrate = int(baudrate)

    def discard_input(self) -> None:
        with self._lock:
            self._in.clear()

    def take_output(self, t_s: float, max_bytes: int | None = None) -> bytes:
        with self._lock:
            k = len(self._out) if max_bytes is None else min(max_bytes, len(self._out))
            data = bytes(self._out[:k])
            del self._out[:k]
            return data

    def pending_bytes(self, t_s: float) -> int:
        return len(self._out)

    def next_output_time(self) -> float | None:
        return self.clock.now() if self._out else None

    def receive(self, data: bytes) -> None:
        with self._lock:
            for b in bytes(data):
                if b == ord("?"):
                    self._out += self._status().encode() + b"\r\n"
                elif b == ord("!"):
                    self._set_running(False)
                elif b == 0x18:
                    self._set_running(False)
                    self._in.clear()
                    self._out += BANNER
                elif b in (0x0A, 0x0D):
                    if self._in:
                        self._line(self._in.decode("ascii", "replace").strip())
                        self._in.clear()
                elif len(self._in) < 128:  # GRBL's line buffer; longer lines are cut
                    self._in.append(b)

    # ---- protocol ---------------------------------------------------------------------------
    def _reply(self, *lines: str) -> None:
        for line in lines:
            self._out += line.encode("ascii") + b"\r\n"

    def _line(self, line: str) -> None:
        if line == "$I":
            self._reply(f"[VER:sim-{__version__}:{self.serial_number}]", "ok")
        elif line == "$S":
            self._reply(self._status(), "ok")
        elif line == "$RUN":
            if self.n == 0:
                self._reply("error:9")
                return
            self._set_running(True)
            self._reply("ok")
        elif line == "$STOP":
            self._set_running(False)
            self._reply("ok")
        elif line.startswith("$N="):
            try:
                n = int(line[3:])
            except ValueError:
                self._reply("error:2")
                return
            if n == 0 or abs(n) > N_MAX:
                self._reply("error:2")
                return
            self.n = n
            if self.running:
                self.stage.set_rate(self.clock.now(), self.rate_dps())
            self._reply("ok")
        else:
            self._reply("error:3")

    def rate_dps(self) -> float:
        """Rate the current n gives (deg/s, signed), from the bench's calibration."""
        if self.n == 0:
            return 0.0
        v = self.cal.speed_for_n(abs(self.n))
        return v if self.n > 0 else -v

    def _set_running(self, on: bool) -> None:
        self.running = on
        self.stage.set_rate(self.clock.now(), self.rate_dps() if on else 0.0)

    def _status(self) -> str:
        angle = float(self.stage.angle_deg(self.clock.now())) % 360.0
        return f"<{'Run' if self.running else 'Idle'}|N:{self.n}|Pos:{angle:.3f}>"
