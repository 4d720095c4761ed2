"""Simulated stepper bench: stock GRBL 1.1h on the bench's Arduino Uno, turning the world's stage.

The ESTCube-2 bench (thesis 3.2) is an Arduino Uno driving an EasyDriver (step/dir, 1/8
microstepping) through a worm gear: GRBL's own target hardware. This simulator is GRBL 1.1h as
it answers on its serial port (gnea/grbl ``protocol.c``, ``system.c``, ``report.c``,
``settings.c``, ``gcode.c``, ``planner.c``), checked byte for byte against transcripts of the
real firmware (docs/golden/grbl-transcripts/, tests/golden/test_grbl_transcripts.py):

* boot: with a blank EEPROM ``error:7`` and the default settings before the welcome message;
  ``$22=1`` (homing) boots into Alarm; an optional reset when the port opens (an Uno's DTR);
* the realtime bytes ``?`` ``!`` ``~`` 0x18 0x85 and the overrides, acted on as they arrive (a
  reset while moving: ``ALARM:3``, 500 ms, the welcome message, the unlock hint);
* the line protocol: 128-byte receive buffer, GRBL's line filter (spaces and comments dropped,
  upper case, 79 characters), ``ok`` / ``error:N`` after each line, nothing processed while a
  hold suspends the firmware, a motion line answered only when the planner has room;
* the states Idle, Run, Hold:0/1, Jog, Alarm, Check, Sleep and their reports (field order, the
  ``WCO:``/``Ov:`` refresh counters, ``Pn:`` from the configured input pins);
* ``$$ $# $G $I $I= $N $Nx= $x=val $J= $C $X $H $SLP $RST=`` and the g-code of
  :mod:`bench.sim.grbl_gcode`; motion by :mod:`bench.sim.grbl_motion` (planner, acceleration).

The bench turns about the axis of ``axis`` (X): machine position in degrees, rates in deg/min.
Not modelled: the safety door (0x84), homing switches (``$H`` with homing enabled fails with
``ALARM:9``), probing, arcs, laser mode, sleep wake-up other than reset.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from typing import Iterator


from bench.sim import grbl_gcode as gc
from bench.sim.grbl_gcode import f32
from bench.sim.grbl_motion import PLANNER_BLOCKS, AxisLimits, Motion
from bench.sim.registry import ReplyBuffer
from bench.sim.stage import RotatingStage

GRBL_VERSION = "1.1h"
GRBL_BUILD = "20190830"
BANNER = f"\r\nGrbl {GRBL_VERSION} ['$' for help]\r\n".encode("ascii")
OPTIONS = f"V,{PLANNER_BLOCKS},128"
"""report.c report_build_info: VARIABLE_SPINDLE, 15 planner blocks, 128-byte receive buffer."""
RX_BUFFER_SIZE = 128
LINE_BUFFER_SIZE = 80
ALARM_REPORT_DELAY_S = 0.5
"""report.c report_alarm_message: ``delay_ms(500)`` after ``ALARM:N``; input meanwhile is lost."""
HELP = "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]"
REPORT_WCO_REFRESH_BUSY, REPORT_WCO_REFRESH_IDLE = 30, 10
REPORT_OVR_REFRESH_BUSY, REPORT_OVR_REFRESH_IDLE = 20, 10
AXES = "XYZ"

DEFAULT_SETTINGS: dict[int, float] = {
    0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 1, 11: 0.010, 12: 0.002, 13: 0, 20: 0, 21: 0, 22: 0,
    23: 0, 24: 25.0, 25: 500.0, 26: 250, 27: 1.0, 30: 1000, 31: 0, 32: 0,
    100: 250.0, 101: 250.0, 102: 250.0, 110: 500.0, 111: 500.0, 112: 500.0,
    120: 10.0, 121: 10.0, 122: 10.0, 130: 200.0, 131: 200.0, 132: 200.0,
}
"""GRBL 1.1h's defaults (defaults.h DEFAULTS_GENERIC) as the firmware printed them after a blank
EEPROM (docs/golden/grbl-transcripts/boot-blank-eeprom.txt), in its report order."""
_INTEGER_SETTINGS = frozenset((0, 1, 2, 3, 4, 5, 6, 10, 13, 20, 21, 22, 23, 26, 32))
_RPM_SETTINGS = frozenset((30, 31))

STATUS_OK = 0
_IDLE_ERROR, _GC_LOCK, _OVERFLOW, _INVALID_STATEMENT, _BAD_NUMBER = 8, 9, 11, 3, 2
_SETTING_DISABLED, _STEP_PULSE_MIN, _NEGATIVE, _SOFT_LIMIT_ERROR = 5, 6, 4, 10


def grbl_float(value: float, decimals: int) -> str:
    """print.c printFloat: ``value`` with ``decimals`` places, rounded as the firmware does in
    single precision (a negative value that rounds to zero keeps its sign)."""
    if value == 0.0 and not math.copysign(1.0, value) < 0:
        return _ZEROS[decimals]
    n = f32(value)
    sign = ""
    if n < 0:
        sign, n = "-", -n
    d = decimals
    while d >= 2:
        n = f32(n * 100.0)
        d -= 2
    if d:
        n = f32(n * 10.0)
    n = f32(n + 0.5)
    digits = str(int(n))
    if decimals:
        digits = digits.rjust(decimals + 1, "0")
        return f"{sign}{digits[:-decimals]}.{digits[-decimals:]}"
    return sign + digits


_ZEROS = {d: ("0." + "0" * d if d else "0") for d in range(8)}


@dataclass
class Eeprom:
    """What GRBL keeps across resets and power cycles."""

    settings: dict[int, float] = field(default_factory=lambda: dict(DEFAULT_SETTINGS))
    build_info: str = ""
    startup_lines: list[str] = field(default_factory=lambda: ["", ""])
    coord_data: dict[int, list[float]] = field(default_factory=lambda: {i: [0.0, 0.0, 0.0] for i in range(8)})
    valid: bool = True
    """False: a blank EEPROM (a freshly flashed board): the next power-up restores the defaults."""


def bench_eeprom(steps_per_deg: float, max_rate_deg_min: float, accel_deg_s2: float, axis: str = "X",
                 build_info: str = "") -> Eeprom:
    """An EEPROM configured as the bench: the axis's steps per degree, max rate and acceleration."""
    ee = Eeprom(build_info=build_info)
    k = AXES.index(axis)
    ee.settings[100 + k] = f32(steps_per_deg)
    ee.settings[110 + k] = f32(max_rate_deg_min)
    ee.settings[120 + k] = f32(accel_deg_s2)
    return ee


Wait = tuple  # ("space",) | ("sync",) | ("until", t_s)


class StepperBenchSim(ReplyBuffer):
    """GRBL 1.1h on the bench's Uno. ``eeprom`` None: blank (error:7 and the defaults at power-up).
    ``pins``: input pins read as triggered, in report order (``PXYZRHS``: grbl-sim's, all of them).
    ``dtr_reset_s``: when the port is opened the board resets and boots this long after (an Uno's
    DTR; None: no reset on open). ``axis``: the bench's rotation axis (stage rate = its velocity).
    ``true_steps_per_deg``: the steps per table degree of the mechanics (None: what the EEPROM's
    ``$100`` says); a ``$100`` that differs makes the table turn at feed·$100/true instead of the
    feed, as a mis-set GRBL does."""

    def __init__(self, clock, stage: RotatingStage | None = None, eeprom: Eeprom | None = None, *, axis: str = "X",
                 pins: str = "", dtr_reset_s: float | None = None, baudrate: int = 115200,
                 true_steps_per_deg: float | None = None):
        self.clock = clock
        self.stage = stage
        self.baudrate = baudrate
        self.axis = AXES.index(axis)
        self.pins = pins
        self.dtr_reset_s = dtr_reset_s
        self.true_steps_per_deg = true_steps_per_deg
        self.eeprom = eeprom if eeprom is not None else Eeprom(valid=False)
        self._lock = threading.RLock()
        self._out = bytearray()
        self.t = clock.now()
        self.position_steps = [0, 0, 0]
        self._power_up(self.t)

    # ---- power-up and reset ---------------------------------------------------------------------
    def _power_up(self, t: float) -> None:
        """main.c: settings from EEPROM (restored with error:7 when blank), position zero."""
        self.t = t
        self.position_steps = [0, 0, 0]
        self.motion = Motion(self._limits(), t)
        self.state = "Idle"
        self._reset_requested = False
        if not self.eeprom.valid:
            self.reply("error:7")
            self.eeprom = Eeprom()  # settings_restore(SETTINGS_RESTORE_ALL)
            self._report_settings()
        if self._setting(22):
            self.state = "Alarm"  # HOMING_INIT_LOCK
        self._reset_until: float | None = None
        self._sleeping_input = False
        self._boot(t)

    def _boot(self, t: float) -> None:
        """The loop of main.c after power-up or a reset: clear everything but the position and
        the alarm, print the welcome message, then protocol_main_loop's alarm check."""
        self.t = t
        self._rx = bytearray()
        self._line = []
        self._line_flags = ""
        self._overflow = False
        self._task: Iterator[Wait] | None = None
        self._wait: Wait | None = None
        self._cycle_stop: tuple[float, list[str]] | None = None
        self.hold_complete = False
        self.jog_cancel = False
        self.wco_counter = 0
        self.ovr_counter = 0
        self.f_override = self.r_override = self.s_override = 100
        self.spindle_speed = 0.0
        self.motion = Motion(self._limits(), t)
        self.motion.steps = list(self.position_steps)
        self.motion.sync_position()
        self.gc = gc.ParserState()
        self.gc.coord_system = list(self.eeprom.coord_data[0])
        self._sync_gc_position()
        self._out += BANNER
        if self._setting(21) and any(a in self.pins for a in AXES):
            self.state = "Alarm"  # CHECK_LIMITS_AT_INIT: a limit switch reads triggered
            self.reply("[MSG:Check Limits]")
        if self.state in ("Alarm", "Sleep"):
            self.reply("[MSG:'$H'|'$X' to unlock]")
            self.state = "Alarm"
        else:
            self.state = "Idle"
            self._run_startup_lines()
        self._push_stage()

    def _run_startup_lines(self) -> None:
        for text in self.eeprom.startup_lines:
            if text:
                status, self.gc, act = gc.execute_line(text, self.gc, self.eeprom.coord_data)
                if status == STATUS_OK:
                    self._plan(act)
                self._out += b">" + text.encode("ascii") + b":"
                self._status_message(status)

    def on_open(self) -> None:
        """The port was opened: an Uno resets on DTR and boots ``dtr_reset_s`` later."""
        if self.dtr_reset_s is None:
            return
        with self._lock:
            now = self.clock.now()
            self._advance(now)
            self._out.clear()
            self.position_steps = [0, 0, 0]
            self.state = "Idle"
            self.motion = Motion(self._limits(), now)
            self._push_stage()
            self._reset_until = now + self.dtr_reset_s
            self._reset_kind = "power"

    def _soft_reset(self) -> None:
        """mc_reset: a reset while moving kills the steppers and raises ALARM:3."""
        if self._reset_until is not None:
            return
        moving = self.state in ("Run", "Jog", "Home") or (self.state == "Hold" and not self.hold_complete)
        self.position_steps = self.motion.position_steps()
        self.motion.kill()
        self._push_stage()
        if moving:
            self.state = "Alarm"
            self.reply("ALARM:3")
            self._reset_until = self.t + ALARM_REPORT_DELAY_S
            self._reset_kind = "soft"
        else:
            if self.state not in ("Alarm", "Sleep"):
                self.state = "Idle"
            self._boot(self.t)

    def _finish_reset(self) -> None:
        kind, self._reset_until = self._reset_kind, None
        if kind == "power":
            self._power_up(self.t)
        else:
            self._boot(self.t)

    # ---- settings -----------------------------------------------------------------------------
    def _setting(self, n: int) -> float:
        return self.eeprom.settings[n]

    def _limits(self) -> AxisLimits:
        s = self.eeprom.settings
        return AxisLimits(tuple(float(s[100 + k]) for k in range(3)), tuple(float(s[110 + k]) for k in range(3)),
                          tuple(float(s[120 + k]) for k in range(3)), float(s[11]))

    def _setting_text(self, n: int) -> str:
        v = self.eeprom.settings[n]
        if n in _INTEGER_SETTINGS:
            return str(int(v))
        if n in _RPM_SETTINGS:
            return grbl_float(v, 0)
        if 120 <= n <= 122:
            return grbl_float(f32(f32(f32(f32(v) * 60.0) * 60.0) / 3600.0), 3)
        return grbl_float(v, 3)

    def _report_settings(self) -> None:
        for n in DEFAULT_SETTINGS:
            self.reply(f"${n}={self._setting_text(n)}")

    def _store_setting(self, n: float, value: float) -> int:
        """settings.c settings_store_global_setting."""
        if value < 0.0:
            return _NEGATIVE
        p = int(n)
        if p >= 100:
            k = p - 100
            if not (k % 10 < 3 and k // 10 < 4):
                return _INVALID_STATEMENT
            self.eeprom.settings[p] = f32(value)
            self.motion.limits = self._limits()
            return STATUS_OK
        iv = int(math.trunc(value)) & 0xFF
        if p not in DEFAULT_SETTINGS:
            return _INVALID_STATEMENT
        if p == 0 and iv < 3:
            return _STEP_PULSE_MIN
        if p == 20 and iv and not self._setting(22):
            return _SOFT_LIMIT_ERROR
        if p in (4, 5, 6, 13, 20, 21, 22, 32):
            iv = 1 if iv else 0
        if p == 22 and not iv:
            self.eeprom.settings[20] = 0
        if p == 13:
            self.wco_counter = 0
        self.eeprom.settings[p] = float(iv) if p in _INTEGER_SETTINGS else f32(value)
        if p == 11:
            self.motion.limits = self._limits()
        return STATUS_OK

    # ---- SerialDevice ---------------------------------------------------------------------------
    def set_baudrate(self, baudrate: int) -> None:
        self.baudrate = int(baudrate)

    def discard_input(self) -> None:
        with self._lock:
            self._rx.clear()

    def receive(self, data: bytes) -> None:
        with self._lock:
            self._advance(self.clock.now())
            for b in bytes(data):
                self._serial_rx(b)
            self._step_main()

    def take_output(self, t_s: float, max_bytes: int | None = None) -> bytes:
        with self._lock:
            self._advance(self.clock.now())
            return super().take_output(t_s, max_bytes)

    def pending_bytes(self, t_s: float) -> int:
        with self._lock:
            self._advance(self.clock.now())
            return len(self._out)

    def next_output_time(self) -> float | None:
        with self._lock:
            now = self.clock.now()
            self._advance(now)
            if self._out:
                return now
            t = self._next_event()
            if t is None:
                return None
            return max(t, now + 1e-6)

    def reply(self, text: str) -> None:
        self._out += text.encode("ascii") + b"\r\n"

    def _status_message(self, status: int) -> None:
        self.reply("ok" if status == STATUS_OK else f"error:{status}")

    # ---- the serial receive interrupt: realtime bytes ----------------------------------------
    def _serial_rx(self, b: int) -> None:
        if self._reset_until is not None:
            return  # in the reset's delay: GRBL clears its input when it restarts
        if b == 0x18:
            self._soft_reset()
        elif b == 0x3F:  # ?
            self._report_status()
        elif b == 0x7E:  # ~
            self._cycle_start()
        elif b == 0x21:  # !
            self._feed_hold()
        elif b > 0x7F:
            if b == 0x85 and self.state == "Jog":
                self._cancel_jog()
            elif 0x90 <= b <= 0x9E or b in (0xA0,):
                self._override(b)
        elif len(self._rx) < RX_BUFFER_SIZE - 1:
            self._rx.append(b)

    def _feed_hold(self) -> None:
        if self.state in ("Alarm", "Check", "Sleep"):
            return
        if self.state == "Jog":
            self._cancel_jog()
        elif self.state == "Run":
            self.state = "Hold"
            self.hold_complete = False
            self.motion.stop_smoothly()
            self._push_stage()
        elif self.state == "Idle":
            self.state = "Hold"
            self.hold_complete = True

    def _cancel_jog(self) -> None:
        if not self.jog_cancel:
            self.jog_cancel = True
            self.motion.stop_smoothly()
            self._push_stage()

    def _cycle_start(self) -> None:
        if self.state == "Idle" or (self.state == "Hold" and self.hold_complete):
            self.hold_complete = False
            if self.motion.blocks:
                self.state = "Run"
                self.motion.start(self.t)
            else:
                self.state = "Idle"
            self._push_stage()

    def _override(self, b: int) -> None:
        f, r, s = self.f_override, self.r_override, self.s_override
        if b == 0x90:
            f = 100
        elif 0x91 <= b <= 0x94:
            f += {0x91: 10, 0x92: -10, 0x93: 1, 0x94: -1}[b]
        elif b == 0x95:
            r = 100
        elif b in (0x96, 0x97):
            r = 50 if b == 0x96 else 25
        elif b == 0x99:
            s = 100
        elif 0x9A <= b <= 0x9D:
            s += {0x9A: 10, 0x9B: -10, 0x9C: 1, 0x9D: -1}[b]
        f, s = min(max(f, 10), 200), min(max(s, 10), 200)
        if (f, r) != (self.f_override, self.r_override):
            self.f_override, self.r_override = f, r
            self.ovr_counter = 0
        if s != self.s_override:
            self.s_override = s
            self.ovr_counter = 0

    # ---- the status report ----------------------------------------------------------------------
    def _state_text(self) -> str:
        if self.state == "Hold":
            return "Hold:0" if self.hold_complete else "Hold:1"
        return self.state

    def _report_status(self) -> None:
        """report.c report_realtime_status."""
        steps = self.motion.position_steps()
        spmm = [self._setting(100 + k) for k in range(3)]
        pos = [f32(f32(s) / f32(m)) for s, m in zip(steps, spmm)]
        mask = int(self._setting(10))
        wco = [self.gc.coord_system[k] + self.gc.coord_offset[k] + (self.gc.tool_length_offset if k == 2 else 0.0) for k in range(3)]
        if not mask & 1:
            pos = [f32(p - f32(w)) for p, w in zip(pos, wco)]
        parts = [f"<{self._state_text()}", ("|MPos:" if mask & 1 else "|WPos:") + self._axes(pos)]
        if mask & 2:
            parts.append(f"|Bf:{PLANNER_BLOCKS - len(self.motion.blocks)},{RX_BUFFER_SIZE - len(self._rx)}")
        busy = self.state in ("Run", "Hold", "Jog", "Home")
        rate = self.motion.reported_speed() * 60.0 if busy else 0.0
        parts.append(f"|FS:{grbl_float(rate, 0)},{grbl_float(self.spindle_speed, 0)}")
        if self.pins:
            parts.append(f"|Pn:{self.pins}")
        if self.wco_counter > 0:
            self.wco_counter -= 1
        else:
            self.wco_counter = (REPORT_WCO_REFRESH_BUSY if busy else REPORT_WCO_REFRESH_IDLE) - 1
            if self.ovr_counter == 0:
                self.ovr_counter = 1
            parts.append("|WCO:" + self._axes(wco))
        if self.ovr_counter > 0:
            self.ovr_counter -= 1
        else:
            self.ovr_counter = (REPORT_OVR_REFRESH_BUSY if busy else REPORT_OVR_REFRESH_IDLE) - 1
            parts.append(f"|Ov:{self.f_override},{self.r_override},{self.s_override}")
            acc = ("S" if self.gc.modal.spindle == 1 else "C" if self.gc.modal.spindle == 2 else "") + ("F" if self.gc.modal.coolant else "")
            if acc:
                parts.append(f"|A:{acc}")
        self.reply("".join(parts) + ">")

    def _axes(self, values: list[float]) -> str:
        if self._setting(13):
            return ",".join(grbl_float(v / gc.MM_PER_INCH, 4) for v in values)
        return ",".join(grbl_float(v, 3) for v in values)

    # ---- time -------------------------------------------------------------------------------------
    def _next_event(self) -> float | None:
        times = []
        if self._reset_until is not None:
            times.append(self._reset_until)
        if self.motion.running:
            t = self.motion.next_event_s()
            if t is not None:
                times.append(t)
        if self._wait is not None and self._wait[0] == "until":
            times.append(self._wait[1])
        if self._cycle_stop is not None:
            times.append(self._cycle_stop[0])
        return min(times) if times else None

    def _advance(self, now: float) -> None:
        if (self._task is None and not self._rx and not self.motion.running and self._reset_until is None
                and self._cycle_stop is None):
            self.t = max(self.t, now)  # nothing runs, nothing waits: time just passes
            self.motion.t = self.t
            return
        for _ in range(100000):
            self._step_main()
            t_next = self._next_event()
            if t_next is None or t_next > now:
                self._move_to(now)
                self._step_main()
                return
            self._move_to(max(t_next, self.t))
        raise RuntimeError("GRBL simulator: too many events in one step")  # pragma: no cover

    def _move_to(self, t: float) -> None:
        if self._reset_until is not None and t >= self._reset_until:
            t = max(self._reset_until, self.t)
        while self.motion.running:
            events = self.motion.advance(t)
            self.t = max(self.t, self.motion.t)
            if not events:
                break
            self._on_motion(events)
            self._step_main()
        self.t = max(self.t, t)
        if not self.motion.running:
            self.motion.t = self.t
        if self._cycle_stop is not None and self.t >= self._cycle_stop[0]:
            self._finish_cycle_stop()
        if self._reset_until is not None and self.t >= self._reset_until:
            self._finish_reset()

    def _on_motion(self, events: list[str]) -> None:
        """A motion ended: the state changes once the steppers' idle delay ($1 ms, stepper.c
        st_go_idle, none when $1=255) has passed; until then the report shows the old state."""
        if "stopped" in events or "idle" in events:
            delay = 0.0 if int(self._setting(1)) == 255 else self._setting(1) / 1000.0
            self._cycle_stop = (self.t + delay, events)
        self._push_stage()

    def _finish_cycle_stop(self) -> None:
        events = self._cycle_stop[1]
        self._cycle_stop = None
        if "stopped" in events:
            if self.jog_cancel or self.state == "Jog":
                self.jog_cancel = False
                self.motion.flush()
                self._sync_gc_position()
                self.state = "Idle"
            elif self.state == "Hold":
                self.hold_complete = True
        if "idle" in events:
            self.jog_cancel = False
            self.motion.sync_position()
            if self.state in ("Run", "Jog"):
                self.state = "Idle"
            elif self.state == "Hold":
                self.hold_complete = True

    def _sync_gc_position(self) -> None:
        steps = self.motion.position_steps()
        self.gc.position = [f32(f32(s) / f32(self._setting(100 + k))) for k, s in enumerate(steps)]

    # ---- the main loop: lines -------------------------------------------------------------------
    def _suspended(self) -> bool:
        return self.state in ("Hold", "Sleep") or self.jog_cancel or self._reset_until is not None

    def _satisfied(self, wait: Wait | None) -> bool:
        if wait is None:
            return True
        if self._suspended():
            return False
        if wait[0] == "space":
            if self.motion.full() and self.state == "Idle":
                self._cycle_start()  # mc_line: auto cycle start when the planner is full
            return not self.motion.full()
        if wait[0] == "sync":
            if self.state == "Idle" and self.motion.blocks:
                self._cycle_start()
            return not self.motion.blocks and self.state not in ("Run", "Jog", "Hold")
        return self.t >= wait[1]

    def _step_main(self) -> None:
        for _ in range(10000):
            if self._reset_until is not None:
                return
            if self._task is not None:
                if not self._satisfied(self._wait):
                    return
                try:
                    self._wait = next(self._task)
                except StopIteration:
                    self._task, self._wait = None, None
                continue
            if self._suspended():
                return
            line = self._take_line()
            if line is None:
                if self.state == "Idle" and self.motion.blocks:
                    self._cycle_start()  # protocol_auto_cycle_start
                return
            self._task, self._wait = self._execute(line), None

    def _take_line(self) -> tuple[str, bool] | None:
        """protocol_main_loop's filter: (line, overflowed) at the next line end, None without one."""
        while self._rx:
            c = self._rx.pop(0)
            if c in (0x0A, 0x0D):
                text, over = "".join(self._line), self._overflow
                self._line, self._line_flags, self._overflow = [], "", False
                return text, over
            ch = chr(c)
            if self._overflow or self._line_flags:
                if ch == ")" and self._line_flags == "(":
                    self._line_flags = ""
                continue
            if c <= 0x20 or ch == "/":
                continue
            if ch == "(":
                self._line_flags = "("
            elif ch == ";":
                self._line_flags = ";"
            elif len(self._line) >= LINE_BUFFER_SIZE - 1:
                self._overflow = True
            else:
                self._line.append(ch.upper() if "a" <= ch <= "z" else ch)
        return None

    def _execute(self, item: tuple[str, bool]) -> Iterator[Wait]:
        line, overflow = item
        if overflow:
            self._status_message(_OVERFLOW)
        elif not line:
            self._status_message(STATUS_OK)
        elif line[0] == "$":
            status = yield from self._system_command(line)
            self._status_message(status)
            if self._reset_requested:  # $C off, $RST=: the reset follows the line's answer
                self._reset_requested = False
                if self.state == "Check":
                    self.state = "Idle"
                self._soft_reset()
        elif self.state in ("Alarm", "Jog"):
            self._status_message(_GC_LOCK)
        else:
            status, new, act = gc.execute_line(line, self.gc, self.eeprom.coord_data)
            if status != STATUS_OK:
                self._status_message(status)
                return
            if self.state == "Check":
                self.gc = new
                self.eeprom.coord_data.update(act.coord_data)
                self._status_message(STATUS_OK)
                return
            if act.sync or act.coord_data:
                yield ("sync",)
            self.gc = new
            self.eeprom.coord_data.update(act.coord_data)
            if act.wco_changed:
                self.wco_counter = 0
            if act.spindle_changed:
                self.ovr_counter = 0
            self.spindle_speed = self.gc.spindle_speed if self.gc.modal.spindle else 0.0
            for target, feed, rapid in act.lines:
                yield ("space",)
                self._buffer(target, feed, rapid=rapid)
            if act.dwell_s:
                yield ("until", self.t + act.dwell_s)
            if act.program_flow == 3:
                yield ("sync",)
                self._feed_hold()
            elif act.program_flow in (2, 30):
                yield ("sync",)
                self.reply("[MSG:Pgm End]")
            self._status_message(STATUS_OK)

    def _buffer(self, target: list[float], feed: float, *, rapid: bool = False, jog: bool = False) -> None:
        if self.motion.buffer_line(target, feed, rapid=rapid, jog=jog):
            if jog and self.state == "Idle":
                self.state = "Jog"
                self.motion.start(self.t)
            self._push_stage()

    def _plan(self, act: gc.Action) -> None:
        for target, feed, rapid in act.lines:
            if not self.motion.full():
                self._buffer(target, feed, rapid=rapid)

    def _system_command(self, line: str) -> Iterator[Wait]:
        """system.c system_execute_line; returns the status code."""
        if False:  # pragma: no cover - makes this a generator
            yield
        c1 = line[1] if len(line) > 1 else ""
        if c1 == "":
            self.reply(HELP)
            return STATUS_OK
        if c1 == "J":
            if self.state not in ("Idle", "Jog"):
                return _IDLE_ERROR
            if line[2:3] != "=":
                return _INVALID_STATEMENT
            status, new, act = gc.execute_line(line, self.gc, self.eeprom.coord_data, jog=True)
            if status != STATUS_OK:
                return status
            self.gc = new
            for target, feed, _ in act.lines:
                yield ("space",)
                self._buffer(target, feed, jog=True)
            return STATUS_OK
        if c1 in "$GCX":
            if line[2:] != "":
                return _INVALID_STATEMENT
            if c1 == "$":
                if self.state in ("Run", "Hold"):
                    return _IDLE_ERROR
                self._report_settings()
            elif c1 == "G":
                self._report_modes()
            elif c1 == "C":
                if self.state == "Check":
                    self.reply("[MSG:Disabled]")
                    self._reset_requested = True  # mc_reset: acted on after the line's ok
                    return STATUS_OK
                if self.state != "Idle":
                    return _IDLE_ERROR
                self.state = "Check"
                self.reply("[MSG:Enabled]")
            elif c1 == "X" and self.state == "Alarm":
                self.reply("[MSG:Caution: Unlocked]")
                self.state = "Idle"
            return STATUS_OK
        if self.state not in ("Idle", "Alarm"):
            return _IDLE_ERROR
        if c1 == "#":
            if line[2:] != "":
                return _INVALID_STATEMENT
            self._report_parameters()
            return STATUS_OK
        if c1 == "H":
            if not self._setting(22):
                return _SETTING_DISABLED
            self.state = "Alarm"
            self.reply("ALARM:9")  # the simulated bench has no limit switches to find
            return STATUS_OK
        if c1 == "S":
            if line[2:] != "LP":
                return _INVALID_STATEMENT
            self.reply("[MSG:Sleeping]")
            self.motion.kill()
            self.state = "Sleep"
            return STATUS_OK
        if c1 == "I":
            if line[2:] == "":
                self.reply(f"[VER:{GRBL_VERSION}.{GRBL_BUILD}:{self.eeprom.build_info}]")
                self.reply(f"[OPT:{OPTIONS}]")
                return STATUS_OK
            if line[2] != "=":
                return _INVALID_STATEMENT
            self.eeprom.build_info = line[3:]
            return STATUS_OK
        if c1 == "R":
            if line[2:4] != "ST" or line[4:5] != "=" or len(line) != 6 or line[5] not in "$#*":
                return _INVALID_STATEMENT
            which = line[5]
            if which in "$*":
                self.eeprom.settings = dict(DEFAULT_SETTINGS)
                self.motion.limits = self._limits()
            if which in "#*":
                self.eeprom.coord_data = {i: [0.0, 0.0, 0.0] for i in range(8)}
            if which == "*":
                self.eeprom.startup_lines = ["", ""]
                self.eeprom.build_info = ""
            self.reply("[MSG:Restoring defaults]")
            self._reset_requested = True
            return STATUS_OK
        storing_startup = False
        i = 2
        if c1 == "N":
            if line[2:] == "":
                for k, text in enumerate(self.eeprom.startup_lines):
                    self.reply(f"$N{k}={text}")
                return STATUS_OK
            if self.state != "Idle":
                return _IDLE_ERROR
            storing_startup = True
        else:
            i = 1
        r = gc.read_float(line, i)
        if r is None:
            return _BAD_NUMBER
        param, i = r
        if line[i:i + 1] != "=":
            return _INVALID_STATEMENT
        i += 1
        if storing_startup:
            text = line[i:]
            status, self.gc, act = gc.execute_line(text, self.gc, self.eeprom.coord_data)
            if status != STATUS_OK:
                return status
            self._plan(act)
            k = int(math.trunc(param))
            if 0 <= k < len(self.eeprom.startup_lines):
                self.eeprom.startup_lines[k] = text
            return STATUS_OK
        r = gc.read_float(line, i)
        if r is None:
            return _BAD_NUMBER
        value, i = r
        if i != len(line) or param > 255:
            return _INVALID_STATEMENT
        return self._store_setting(param, value)

    def _report_modes(self) -> None:
        m, g = self.gc.modal, self.gc
        flow = {3: " M0", 2: " M2", 30: " M30"}.get(m.program_flow, "")
        spindle = {1: "3", 2: "4", 0: "5"}[m.spindle]
        self.reply(f"[GC:G{m.motion} G{m.coord_select + 54} G{m.plane + 17} G{21 - m.units} G{m.distance + 90} "
                   f"G{94 - m.feed_rate_mode}{flow} M{spindle} M{'8' if m.coolant else '9'} T{g.tool} "
                   f"F{grbl_float(g.feed_rate if not self._setting(13) else g.feed_rate / gc.MM_PER_INCH, 0 if not self._setting(13) else 1)} "
                   f"S{grbl_float(g.spindle_speed, 0)}]")

    def _report_parameters(self) -> None:
        names = ["G54", "G55", "G56", "G57", "G58", "G59", "G28", "G30"]
        for k, name in enumerate(names):
            self.reply(f"[{name}:{self._axes(self.eeprom.coord_data[k])}]")
        self.reply(f"[G92:{self._axes(self.gc.coord_offset)}]")
        self.reply(f"[TLO:{self._axes([self.gc.tool_length_offset])}]")
        self.reply(f"[PRB:{self._axes([0.0, 0.0, 0.0])}:0]")

    # ---- the world --------------------------------------------------------------------------------
    def _push_stage(self) -> None:
        """Give the stage the rate of the bench's axis (deg/s) from now on, as planned."""
        if self.stage is None:
            return
        segments = [seg for seg in self.motion.profile() if seg.duration_s > 0]
        k = self.axis
        scale = 1.0 if self.true_steps_per_deg is None else self._setting(100 + k) / self.true_steps_per_deg
        pieces = [(seg.t_s, scale * seg.v * seg.unit[k], scale * seg.a * seg.unit[k]) for seg in segments]
        t_end = segments[-1].t_s + segments[-1].duration_s if segments else self.t
        self.stage.set_motion(self.t, pieces, t_end)

    # ---- reading (tests, the world) -------------------------------------------------------------------
    def machine_state(self) -> str:
        """GRBL's state now, as its report would name it (``Idle``, ``Jog``, ``Hold:0``...)."""
        with self._lock:
            self._advance(self.clock.now())
            return self._state_text()

    def angle_deg(self) -> float:
        """Machine position of the bench's axis (deg) now."""
        with self._lock:
            self._advance(self.clock.now())
            return self.motion.position_steps()[self.axis] / self._setting(100 + self.axis)

    def rate_dps(self) -> float:
        """Signed rate of the bench's axis (deg/s) now."""
        with self._lock:
            self._advance(self.clock.now())
            v, unit = self.motion.velocity()
            return v * unit[self.axis]
