"""Driver of the stepper rotating bench: stock GRBL 1.1 on its Arduino Uno (docs/stepper-bench.md).

The ESTCube-2 bench (thesis 3.2) is an Arduino Uno driving an EasyDriver (step/dir, 1/8
microstepping) through a worm gear: GRBL's own target hardware. A lab flashes stock GRBL 1.1, sets
the bench's axis in degrees (``$100`` steps per degree, ``$110`` max rate in deg/min, ``$120``
acceleration in deg/s²) and names it with a build-info string (``$I=STEPPER_BENCH:<id>``); this
driver then speaks GRBL as shipped (:mod:`drivers.grbl`), nothing of its own:

* open: the Uno resets when the port opens (DTR); the driver sends a soft reset (0x18) and waits,
  bounded, for the welcome message, reads the state (an ALARM left by a reset while turning is
  unlocked with ``$X``, a deliberate step recorded in :attr:`StepperBench.notes`), ``$I`` and
  ``$$``, and refuses a GRBL that is not set up as the bench (:class:`NotConfigured`, with the
  ``$`` commands that set it up);
* turning at a constant rate is jogging (``$J=G91G21X<deg>F<deg/min>``): blocks of
  :data:`JOG_BLOCK_S` s of motion, kept :data:`QUEUE_S` s ahead of the axis by every status read, so
  a long dwell turns without a gap and the bench stops by itself within that time if nobody asks
  for its status any more; a rate change is a jog cancel (0x85), Idle confirmed, then new jogs;
* status only from the realtime ``?`` report, parsed field by field;
* safe state: jog cancel (0x85), or feed hold and soft reset for anything else that moves,
  confirmed by a ``?`` report (Idle or Alarm, rate 0) and an empty line answered at once.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import serial

from drivers import grbl
from drivers.base import Driver, check_timeout
from drivers.errors import DeviceFault, InstrumentError, InstrumentTimeout, NotConfigured, ProtocolError
from drivers.transport import open_serial

log = logging.getLogger(__name__)

DEFAULT_BAUDRATE = 115200  # GRBL 1.1 config.h BAUD_RATE
BUILD_INFO_TAG = "STEPPER_BENCH"
"""The build-info string (``$I=``) of a GRBL set up as this bench starts with this, then ``:<id>``."""
AXES = "XYZ"
ESTCUBE_STEPS_PER_DEG = 894.33
"""Steps per table degree of the ESTCube-2 bench [U]: 1600 microsteps per motor turn (1.8° motor at
1/8 step) through its worm, 321 960 microsteps per table turn if the thesis's n (Eq. 3.1) is the
delay between microsteps in µs (docs/stepper-bench.md); ``bench calibrate-bench`` measures it."""
ESTCUBE_MAX_RATE_DPS = 3.5
"""ESTCube-2 thesis section 5: 1/8 microstepping "limited the speed to maximum of about 3.5 deg/s"."""
BOOT_TIMEOUT_S = 4.0
"""Longest wait for GRBL's welcome message after opening the port: an Uno resets on DTR and GRBL
answers about 2 s later (issue 27, measured on a lab's board), with margin."""
JOG_BLOCK_S = 10.0
"""Seconds of motion in one jog line."""
QUEUE_S = 30.0
"""Motion kept queued ahead of the axis while turning (s): the longest the bench goes on without
being asked for its status, and what a top-up restores."""
REFILL_BELOW_S = 20.0
"""A status read tops the queue up when less than this much motion (s) is left in it."""
POLL_S = 0.05
"""Between two status reads while waiting for the bench to stop (s)."""
STOP_MARGIN_S = 2.0
"""Allowance beyond the deceleration for a stop to be confirmed (s): segments prepared ahead, the
steppers' idle delay ($1), the link."""


@dataclass(frozen=True)
class BenchSetup:
    """How the bench is set up in GRBL: its ``axis``; ``steps_per_deg`` (``$100`` for X, the value
    ``bench calibrate-bench`` gives); the fastest rate it is commanded (deg/s; ``$110`` must allow
    it); its acceleration (deg/s², ``$120``; None: any)."""

    axis: str = "X"
    steps_per_deg: float = ESTCUBE_STEPS_PER_DEG
    max_rate_dps: float = ESTCUBE_MAX_RATE_DPS
    acceleration_dps2: float | None = None

    @property
    def index(self) -> int:
        return AXES.index(self.axis)

    def setting(self, base: int) -> int:
        """GRBL setting number of this axis: ``base`` 100 (steps/unit), 110 (max rate), 120 (accel)."""
        return base + self.index


def grbl_number(value: float) -> str:
    """A value as GRBL prints its settings (3 decimals)."""
    return f"{value:.3f}"


class StepperBench(Driver):
    """The stepper rotating bench on GRBL 1.1. Rates in deg/s, angles in deg."""

    kind = "stepper_bench"
    streams = False  # no data stream: the runner records its commands and answers only

    def __init__(self, port: serial.SerialBase, *, timeout_s: float = 0.5, setup: BenchSetup | None = None,
                 on_traffic=None, boot_timeout_s: float = BOOT_TIMEOUT_S):
        self.port = port
        self.name = "stepper_bench"
        self.timeout_s = check_timeout(timeout_s)
        self.setup = setup or BenchSetup()
        self.boot_timeout_s = boot_timeout_s
        self.channel = grbl.GrblChannel(port, self.timeout_s, self.name, on_traffic)
        self.version = ""
        self.build_info = ""
        self.options = ""
        self.settings: dict[int, float] = {}
        self.notes: list[str] = []
        """Deliberate steps and findings of this session (unlocking an alarm, a restored EEPROM)."""
        self._rate_dps = 0.0
        self._turning = False
        self._queued_to = 0.0
        """Machine position (deg) the last jog sent ends at."""
        self._wco = (0.0, 0.0, 0.0)
        self.last_status: grbl.Status | None = None

    @property
    def on_traffic(self):
        return self.channel.on_traffic

    @on_traffic.setter
    def on_traffic(self, hook) -> None:
        self.channel.on_traffic = hook

    @classmethod
    def open(cls, url: str, *, baudrate: int = DEFAULT_BAUDRATE, timeout_s: float = 0.5, **kwargs) -> "StepperBench":
        """Open the port, reset GRBL and check that it is set up as the bench (:meth:`start`)."""
        drv = cls(open_serial(url, baudrate, timeout_s), timeout_s=timeout_s, **kwargs)
        try:
            drv.start()
        except BaseException:
            drv.close()
            raise
        return drv

    def close(self) -> None:
        self.port.close()

    # ---- opening ------------------------------------------------------------------------------
    def _note(self, text: str) -> None:
        self.notes.append(text)
        log.warning("%s: %s", self.name, text)

    def start(self) -> None:
        """Soft reset, welcome message (bounded wait: the board may be booting after DTR), state
        (unlock an alarm), ``$I``, ``$$``; NotConfigured for a GRBL that is not the bench."""
        ch = self.channel
        ch.realtime(grbl.SOFT_RESET)
        empty_reads = max(1, math.ceil(self.boot_timeout_s / self.timeout_s))
        try:
            before, welcome = ch.read_until(lambda t: grbl.welcome_version(t) is not None, "a reset (0x18)", empty_reads)
        except InstrumentTimeout:
            raise InstrumentTimeout(f"{self.name}: no GRBL welcome message within {self.boot_timeout_s:g} s of a "
                                    f"reset (is GRBL 1.1 flashed, at {self.port.baudrate} baud?)") from None
        if "error:7" in before:
            self._note("GRBL reported error:7 at power-up: its EEPROM was blank or corrupt and it restored "
                       "its default settings")
        version = grbl.welcome_version(welcome) or ""
        if not version.startswith("1.1"):
            raise NotConfigured(f"firmware {welcome!r} is not GRBL 1.1 (its status reports differ)",
                                "flash GRBL 1.1h (gnea/grbl) on the bench's Arduino")
        status = self._read_status()
        if status.state == "Alarm":
            self.channel.transact("$X")
            self._note("GRBL was in ALARM after the reset (the last session reset it while turning, or homing is "
                       "enabled): unlocked with $X; the angle counts on from where the axis stands")
            status = self._read_status()
        self.version, self.build_info, self.options = grbl.parse_build_info(ch.transact("$I"))
        self.settings = grbl.parse_settings(ch.transact("$$"))
        self._check_setup()

    def _check_setup(self) -> None:
        """Every way this GRBL is not the bench the config describes, with the commands that fix it."""
        s, setup = self.settings, self.setup
        problems: list[str] = []
        fixes: list[str] = []
        ident = self.build_info
        if not (ident == BUILD_INFO_TAG or ident.startswith(BUILD_INFO_TAG + ":")):
            problems.append(f"its build info is {ident!r}, not {BUILD_INFO_TAG}:<id>")
            fixes.append(f"$I={BUILD_INFO_TAG}:<this bench's id, letters, digits and -, no spaces>")
        n_steps, n_rate, n_accel = setup.setting(100), setup.setting(110), setup.setting(120)
        missing = [n for n in (13, 20, n_steps, n_rate, n_accel) if n not in s]
        if missing:
            raise ProtocolError(f"{self.name}: $$ did not list setting(s) {', '.join(f'${n}' for n in missing)}")
        if s[13] != 0:
            problems.append("it reports in inches ($13=1)")
            fixes.append("$13=0")
        if s[20] != 0:
            problems.append("soft limits are on ($20=1): a turning table has no travel limits")
            fixes.append("$20=0")
        if abs(s[n_steps] - setup.steps_per_deg) > 0.0005 + 1e-6 * setup.steps_per_deg:
            problems.append(f"${n_steps}={grbl_number(s[n_steps])} steps per degree, the config says {setup.steps_per_deg:g}")
            fixes.append(f"${n_steps}={grbl_number(setup.steps_per_deg)}")
        need = setup.max_rate_dps * 60.0
        if s[n_rate] < need - 1e-6:
            problems.append(f"${n_rate}={grbl_number(s[n_rate])} deg/min is below the bench's {setup.max_rate_dps:g} deg/s")
            fixes.append(f"${n_rate}={grbl_number(need)}")
        if s[n_accel] <= 0 or (setup.acceleration_dps2 is not None and abs(s[n_accel] - setup.acceleration_dps2) > 0.0005):
            problems.append(f"${n_accel}={grbl_number(s[n_accel])} deg/s², the config says "
                            f"{setup.acceleration_dps2 if setup.acceleration_dps2 is not None else 'more than 0'}")
            fixes.append(f"${n_accel}={grbl_number(setup.acceleration_dps2 or 10.0)}")
        if problems:
            what = "GRBL, not configured as this bench" if fixes[0].startswith("$I=") else "GRBL set up as a bench, not as the config's"
            raise NotConfigured(f"{what} (GRBL {self.version}): " + "; ".join(problems),
                                "send to it, one line at a time (each answers ok): " + "  ".join(fixes))

    def identify(self) -> dict[str, str]:
        """What :meth:`start` read: GRBL's version and the bench's id from its build info."""
        _, _, ident = self.build_info.partition(":")
        axis = self.setup
        info = {"vendor": "GRBL", "model": f"stepper rotating bench ({axis.axis} axis)",
                "firmware": f"Grbl {self.version} [OPT:{self.options}]", "serial": ident or self.build_info,
                "settings": " ".join(f"${n}={grbl_number(self.settings[n])}"
                                     for n in (axis.setting(100), axis.setting(110), axis.setting(120)) if n in self.settings)}
        if self.notes:
            info["notes"] = "; ".join(self.notes)
        return info

    # ---- status -----------------------------------------------------------------------------------
    def _read_status(self) -> grbl.Status:
        st, _ = self.channel.status()
        if st.wco is not None:
            self._wco = st.wco
        self.last_status = st
        return st

    def _position(self, st: grbl.Status) -> float:
        """Machine position of the bench's axis (deg)."""
        k = self.setup.index
        if st.mpos is not None:
            return st.mpos[k]
        return st.wpos[k] + self._wco[k]

    def _rate_of(self, st: grbl.Status) -> float:
        if not st.moving or st.feed is None:
            return 0.0
        return math.copysign(st.feed / 60.0, self._rate_dps or 1.0)

    def status(self) -> dict:
        """State (``Idle`` ``Jog`` ``Run`` ``Hold`` ``Alarm`` ...), angle (deg, 0..360), position
        (deg, as counted since power-up) and rate (deg/s, GRBL's reported feed with the sign of
        the commanded direction). While turning, tops the jog queue up."""
        st = self._read_status()
        pos = self._position(st)
        if self._turning:
            if st.state == "Alarm":
                self._turning = False
                raise DeviceFault(f"{self.name}: GRBL is in ALARM while the bench should turn (reset while turning?)")
            if st.state == "Idle":
                self._note(f"the bench had stopped at {pos:.3f} deg (its jog queue ran out: no status read for "
                           f"{QUEUE_S:g} s or a jog cancelled by someone else); turning again at {self._rate_dps:+g} deg/s")
                self._queued_to = pos
            self._top_up(pos)
        return {"state": st.state, "angle_deg": pos % 360.0, "position_deg": pos, "rate_dps": self._rate_of(st)}

    def monitor_columns(self) -> list[str]:
        """Columns of :meth:`monitor` (deg, deg/s, declared by the kind)."""
        return ["angle", "rate"]

    def monitor(self) -> dict[str, float]:
        """Angle (deg, 0..360) and rate (deg/s) of the bench, logged every poll interval."""
        s = self.status()
        return {"angle": s["angle_deg"], "rate": s["rate_dps"]}

    # ---- turning ----------------------------------------------------------------------------------
    def feed_for_rate(self, rate_dps: float) -> float:
        """The jog feed (deg/min, as sent: 3 decimals) for ``rate_dps``; ValueError beyond the bench."""
        if not math.isfinite(rate_dps) or rate_dps == 0:
            raise ValueError(f"a rate of {rate_dps!r} deg/s is no speed to turn at (0 is a stop)")
        limit = min(self.setup.max_rate_dps, self.settings.get(self.setup.setting(110), math.inf) / 60.0)
        if abs(rate_dps) > limit + 1e-9:
            raise ValueError(f"{rate_dps:g} deg/s is beyond the bench's {limit:g} deg/s")
        return round(abs(rate_dps) * 60.0, 3)

    def set_rate(self, rate_dps: float) -> float:
        """Turn at ``rate_dps`` (signed) from :meth:`run` on, or at once if already turning (a
        jog cancel, Idle confirmed, new jogs). Returns the rate GRBL is told (deg/s)."""
        feed = self.feed_for_rate(rate_dps)
        self._rate_dps = math.copysign(feed / 60.0, rate_dps)
        if self._turning:
            pos = self._stop_jogging()
            self._turning = True
            self._queued_to = pos
            self._top_up(pos)
        return self._rate_dps

    def run(self) -> None:
        """Start turning at the rate of :meth:`set_rate` (no-op when already turning)."""
        if self._rate_dps == 0:
            raise ValueError("no rate set: call set_rate() first")
        if self._turning:
            return
        pos = self._position(self._read_status())
        self._turning = True
        self._queued_to = pos
        self._top_up(pos)

    def _top_up(self, pos: float) -> None:
        """Jog lines until :data:`QUEUE_S` s of motion lie ahead of ``pos`` (when less than
        :data:`REFILL_BELOW_S` s do)."""
        speed = abs(self._rate_dps)
        direction = 1.0 if self._rate_dps > 0 else -1.0
        ahead_s = max(0.0, (self._queued_to - pos) * direction) / speed
        if ahead_s >= REFILL_BELOW_S:
            return
        feed = grbl_number(speed * 60.0)
        while ahead_s < QUEUE_S - 1e-9:
            step = direction * speed * JOG_BLOCK_S
            self.channel.transact(f"$J=G91G21{self.setup.axis}{grbl_number(step)}F{feed}")
            self._queued_to += round(step, 3)
            ahead_s += JOG_BLOCK_S

    def stop(self) -> None:
        """Stop turning: jog cancel, Idle confirmed (:class:`InstrumentError` when it is not
        within the deceleration and :data:`STOP_MARGIN_S`)."""
        self._stop_jogging()

    def _stop_deadline_s(self) -> float:
        accel = self.settings.get(self.setup.setting(120), 10.0) or 10.0
        return abs(self._rate_dps) / accel + STOP_MARGIN_S

    def _stop_jogging(self) -> float:
        """Jog cancel and wait for Idle; the position (deg) where the axis stands."""
        self._turning = False
        self.channel.realtime(grbl.JOG_CANCEL)
        st = self._wait_at_rest(self._stop_deadline_s())
        if st.state != "Idle":
            raise InstrumentError(f"{self.name}: not Idle after a jog cancel but {st.state} "
                                  f"(feed {st.feed}) at {self._position(st):.3f} deg")
        return self._position(st)

    def _wait_at_rest(self, deadline_s: float) -> grbl.Status:
        """Status reads every :data:`POLL_S` until a state at rest (Idle, Alarm, Hold:0, Check,
        Sleep) or ``deadline_s`` of waiting; the last report."""
        waited = 0.0
        while True:
            st = self._read_status()
            if not st.moving and st.state != "Door" and not (st.state == "Hold" and st.substate != 0):
                return st
            if waited >= deadline_s:
                return st
            self.channel.pause(POLL_S)
            waited += POLL_S

    # ---- safe state -------------------------------------------------------------------------------
    def safe_state(self) -> str:
        """Stopped with nothing queued: jog cancel (0x85); if anything still moves or holds, feed
        hold then soft reset; confirmed by a report at rest (Idle or Alarm, feed 0) and an empty
        line answered ``ok`` at once. Returns what was done and confirmed."""
        self._turning = False
        ch = self.channel
        done = ["jog cancel (0x85)"]
        ch.realtime(grbl.JOG_CANCEL)
        st = self._read_status()
        if st.state == "Jog":  # the cancel decelerates it to Idle
            st = self._wait_at_rest(self._stop_deadline_s())
        if st.state not in ("Idle", "Alarm") or st.moving or (st.feed or 0.0) != 0.0:
            if st.moving:  # a cycle the cancel does not touch (G-code), or a jog that did not stop
                ch.realtime(grbl.FEED_HOLD)
                done.append("feed hold (!)")
                st = self._wait_at_rest(self._stop_deadline_s())
            ch.realtime(grbl.SOFT_RESET)  # empties the planner; a hold at rest: no alarm
            done.append("soft reset (0x18)")
            ch.read_until(lambda t: grbl.welcome_version(t) is not None, "a reset (0x18)",
                          max(1, math.ceil(self.boot_timeout_s / self.timeout_s)))
            st = self._read_status()
        if st.state not in ("Idle", "Alarm") or (st.feed or 0.0) != 0.0:
            raise InstrumentError(f"{self.name}: safe state not confirmed: {st.state}, feed {st.feed} after {', '.join(done)}")
        ch.resync()  # a line answered at once: nothing held; whatever was pending is read and dropped first
        return (f"{', then '.join(done)}: {st.state}, feed 0 at {self._position(st):.3f} deg; "
                f"the next line ($G) was answered at once (nothing held or queued)")
