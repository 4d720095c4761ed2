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

from bench import __version__
from bench.sim.line_device import LineDeviceSim
from bench.sim.stage import RotatingStage
from drivers.stepper_speed import BenchSpeedCalibration

BANNER = b"StepperBench sim ['$' for help]\r\n"
N_MAX = 65535


class StepperBenchSim(LineDeviceSim):
    realtime_bytes = frozenset(b"?!\x18")
    max_line = 128  # GRBL's line buffer

    def __init__(self, clock, stage: RotatingStage, calibration: BenchSpeedCalibration | None = None,
                 serial_number: str = "SIM-0002", baudrate: int = 115200):
        super().__init__(clock, baudrate)
        self.stage = stage
        self.cal = calibration or BenchSpeedCalibration()
        self.serial_number = serial_number
        self.n = 0
        self.running = False

    def on_realtime(self, byte: int) -> None:
        if byte == ord("?"):
            self.reply(self._status())
        elif byte == ord("!"):
            self._set_running(False)
        else:  # 0x18 reset
            self._set_running(False)
            self.discard_input()
            self._out += BANNER

    def on_line(self, line: str) -> None:
        if line == "$I":
            self.reply(f"[VER:sim-{__version__}:{self.serial_number}]")
            self.reply("ok")
        elif line == "$S":
            self.reply(self._status())
            self.reply("ok")
        elif line == "$RUN":
            if self.n == 0:
                self.reply("error:9")
                return
            self._set_running(True)
            self.reply("ok")
        elif line == "$STOP":
            self._set_running(False)
            self.reply("ok")
        elif line.startswith("$N="):
            try:
                n = int(line[3:])
            except ValueError:
                self.reply("error:2")
                return
            if n == 0 or abs(n) > N_MAX:
                self.reply("error:2")
                return
            self.n = n
            if self.running:
                self.stage.set_rate(self.clock.now(), self.rate_dps())
            self.reply("ok")
        else:
            self.reply("error:3")

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
        angle = float(self.stage.commanded_angle_deg(self.clock.now())) % 360.0
        return f"<{'Run' if self.running else 'Idle'}|N:{self.n}|Pos:{angle:.3f}>"
