"""Simulated stepper rotating bench: GRBL-style line protocol, turning the world's stage.

Commands (docs/stepper-bench.md): ``$I`` identify, ``$N=<int>`` speed parameter (sign =
direction), ``$RUN``, ``$STOP``, ``$S`` status, ``$X`` kill alarm lock; realtime bytes ``?``
(status report, no ``ok``), ``!`` (feed hold: stop at once, state ``Hold:0``), ``~`` (resume a
hold), 0x18 (soft reset). The responses follow GRBL 1.1 (gnea/grbl ``doc/markdown/interface.md``,
``commands.md``; ``docs/golden/grbl.md``): ``ok`` / ``error:N`` end every line, an empty line is
answered ``ok``, a line longer than GRBL's 80-byte buffer is refused with ``error:11``, a reset
prints the welcome message ``Grbl 1.1f ['$' for help]``, and a reset while turning raises
``ALARM:3`` (position lost) and locks ``$RUN`` out (``error:9``) until ``$X``.

Errors: ``error:2`` bad number or value, ``error:3`` unsupported ``$`` command, ``error:9``
``$RUN`` in the alarm state, ``error:11`` line too long, ``error:22`` ``$RUN`` before a speed
was set ("feed rate has not yet been set").

The rate produced by n follows the bench's own calibration (Eq. 3.1 with the sim's k, b), which is
what the driver's calibration must match; 1/8 microstepping of a 200-step motor gives positions
in steps of 360/1600 deg at the motor, far below the table's angle resolution reported here (mdeg).
"""

from __future__ import annotations

from bench import __version__
from bench.sim.line_device import LineDeviceSim
from bench.sim.stage import RotatingStage
from drivers.stepper_speed import BenchSpeedCalibration

GRBL_VERSION = "1.1f"  # the GRBL interface version the protocol follows
BANNER = f"\r\nGrbl {GRBL_VERSION} ['$' for help]\r\n".encode("ascii")  # report.c report_init_message
ALARM_LOCK = "[MSG:'$H'|'$X' to unlock]"
N_MAX = 65535
LINE_BUFFER = 80  # grbl/protocol.h LINE_BUFFER_SIZE: 79 characters and the terminating zero


class StepperBenchSim(LineDeviceSim):
    realtime_bytes = frozenset(b"?!~\x18")
    max_line = LINE_BUFFER - 1
    answer_empty_lines = True  # GRBL answers an empty line with ok

    def __init__(self, clock, stage: RotatingStage, calibration: BenchSpeedCalibration | None = None,
                 serial_number: str = "SIM-0002", baudrate: int = 115200):
        super().__init__(clock, baudrate)
        self.stage = stage
        self.cal = calibration or BenchSpeedCalibration()
        self.serial_number = serial_number
        self.n = 0
        self.running = False
        self.held = False  # feed hold (``!``) in force: state Hold:0, ``~`` resumes
        self.resume_running = False
        self.alarm = 0  # active alarm code (0: none)

    @property
    def state(self) -> str:
        """GRBL machine state as the status report names it."""
        if self.alarm:
            return "Alarm"
        if self.held:
            return "Hold:0"  # hold complete: the stepper stops within a microstep
        return "Run" if self.running else "Idle"

    def on_realtime(self, byte: int) -> None:
        if byte == ord("?"):
            self.reply(self._status())
        elif byte == ord("!"):
            if not self.alarm and not self.held:  # acts in Idle and Run, ignored otherwise
                self.resume_running = self.running
                self.held = True
                self._set_running(False)
        elif byte == ord("~"):
            if self.held:
                self.held = False
                self._set_running(self.resume_running)
        else:  # 0x18 soft reset
            moving = self.running
            self.held = False
            self._set_running(False)
            self.discard_input()
            if moving:
                self.alarm = 3  # reset while in motion: position may be lost
                self.reply(f"ALARM:{self.alarm}")
            self._out += BANNER
            if self.alarm:
                self.reply(ALARM_LOCK)

    def on_overflow(self, line: str) -> None:
        self.reply("error:11")  # line too long: not executed

    def on_line(self, line: str) -> None:
        if line == "":
            self.reply("ok")
        elif line == "$I":
            self.reply(f"[VER:sim-{__version__}:{self.serial_number}]")
            self.reply("[OPT:]")  # no GRBL compile-time options
            self.reply("ok")
        elif line == "$S":
            self.reply(self._status())
            self.reply("ok")
        elif line == "$X":
            if self.alarm:
                self.alarm = 0
                self.reply("[MSG:Caution: Unlocked]")
            self.reply("ok")
        elif line == "$RUN":
            if self.alarm:
                self.reply("error:9")
            elif self.n == 0:
                self.reply("error:22")
            else:
                self.held = False
                self._set_running(True)
                self.reply("ok")
        elif line == "$STOP":
            self.held = False
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
        """GRBL 1.1 status report: state, machine position (the table angle in deg as the X axis,
        0..360, 3 decimals as in mm mode), feed (deg/min, no decimals, as GRBL's ``F:`` without a
        variable spindle), then our field ``N:`` (the speed parameter)."""
        angle = float(self.stage.commanded_angle_deg(self.clock.now())) % 360.0
        feed = abs(self.rate_dps()) * 60.0 if self.running else 0.0
        return f"<{self.state}|MPos:{angle:.3f},0.000,0.000|F:{feed:.0f}|N:{self.n}>"
