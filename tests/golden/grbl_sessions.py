"""The scripted raw sessions recorded from the real GRBL 1.1h firmware (machine-local).

``BENCH_GRBL_SIM=... python -m tests.grbl_firmware record docs/golden/grbl-transcripts`` plays each
session below against the firmware (tests/grbl_firmware.py) and writes what both sides sent
(tests/golden/grbl_transcript.py). The host bytes are written here by hand, as a person at a
terminal would type them; nothing is taken from the project's driver or simulator. The tests
(tests/golden/test_grbl_transcripts.py) then play every transcript against the simulator and
read every firmware line with the driver's parsers.

Rates are the ESTCube-2 bench's (thesis 4.2.1: 0.1 to 3 deg/s; section 5: at most about
3.5 deg/s). The bench's settings (``$100`` steps per degree, ``$110`` max rate, ``$120``
acceleration) are those of docs/stepper-bench.md.
"""

from __future__ import annotations

import tempfile
import threading
import time
from pathlib import Path
from typing import Callable

import serial

from tests.golden.grbl_transcript import write_transcript
from tests.grbl_firmware import GrblFirmware

BENCH_SETTINGS = (b"$100=894.330\n", b"$110=210.000\n", b"$120=10.000\n")
"""Steps per degree, max rate (deg/min = 3.5 deg/s) and acceleration (deg/s^2) of the bench."""
BUILD_INFO = b"$I=STEPPER_BENCH:EC2-01\n"
ESTCUBE_RATES_DPS = (0.1, 0.2, 0.5, 0.7, 1.0, 2.0, 2.5, 3.0, 3.5)
OK = b"ok\r\n"
BLANK_EEPROM = "blank (a freshly flashed board)"
BENCH_EEPROM = ("bench (the EEPROM configure-bench.txt left: $100=894.330, $110=210.000, $120=10.000, "
                "build info STEPPER_BENCH:EC2-01)")


class Raw:
    """A terminal on the firmware's port: write bytes, wait for what should come back."""

    def __init__(self, fw: GrblFirmware):
        self.fw = fw
        self.port = serial.Serial(fw.port, 115200, timeout=0.05)
        self._stop = False
        self._reader = threading.Thread(target=self._drain, daemon=True)
        self._reader.start()

    def _drain(self) -> None:  # the relay records; the host side only has to be read
        while not self._stop:
            try:
                self.port.read(4096)
            except (serial.SerialException, OSError, TypeError):
                return

    def send(self, data: bytes, expect: bytes | None = OK, timeout_s: float = 10.0, quiet_s: float = 0.3) -> bytes:
        """Write ``data``; wait for ``expect`` in what comes back (or ``quiet_s`` without it)."""
        start = len(self.fw.received())
        self.port.write(data)
        if expect is not None:
            if not self.fw.wait_for(expect, timeout_s, start):
                raise RuntimeError(f"{data!r}: no {expect!r} within {timeout_s} s; got {self.fw.received()[start:]!r}")
        else:
            time.sleep(quiet_s)
        time.sleep(0.05)
        return self.fw.received()[start:]

    def status(self) -> bytes:
        return self.send(b"?", expect=b">\r\n", timeout_s=5.0)

    def until_state(self, state: bytes, timeout_s: float = 60.0, every_s: float = 0.25) -> bytes:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            got = self.status()
            if b"<" + state in got:
                return got
            time.sleep(every_s)
        raise RuntimeError(f"no {state!r} within {timeout_s} s")

    def wait(self, seconds: float) -> None:
        time.sleep(seconds)

    def close(self) -> None:
        self._stop = True
        self.port.close()


def boot(raw: Raw) -> None:
    if not raw.fw.wait_for(b"['$' for help]\r\n", 10.0):
        raise RuntimeError("no welcome message")
    raw.wait(1.2)  # grbl-sim reads no input during its first simulated second


# ---- the sessions ---------------------------------------------------------------------------
def boot_blank_eeprom(raw: Raw) -> None:
    """A freshly flashed board: error:7 and the default settings before the welcome message;
    then what it answers to identification and the read-only $ commands."""
    boot(raw)
    raw.send(b"$I\n")
    raw.send(b"$$\n")
    raw.send(b"$G\n")
    raw.send(b"$#\n")
    raw.send(b"$N\n")
    raw.send(b"$\n")
    raw.status()
    raw.send(b"$i\n")
    raw.send(b"$ I\n")
    raw.send(b"\n")
    raw.send(b"\r\n", expect=None, quiet_s=0.5)


def configure_bench(raw: Raw) -> None:
    """A plain GRBL set up as the bench: steps per degree, max rate, acceleration, build info."""
    boot(raw)
    for line in BENCH_SETTINGS:
        raw.send(line)
    raw.send(BUILD_INFO)
    raw.send(b"$I\n")
    raw.send(b"$$\n")


def boot_bench_eeprom(raw: Raw) -> None:
    """Power-up of the configured bench: only the welcome message; its identity and settings."""
    boot(raw)
    raw.send(b"$I\n")
    raw.send(b"$$\n")
    raw.status()
    raw.send(b"\x18", expect=b"['$' for help]\r\n")  # soft reset at rest: the welcome message only
    raw.status()


def states(raw: Raw) -> None:
    """`?` in every state the bench can meet: Idle, Hold:0 at rest (lines held until ~), Jog and
    its cancel, Run, Hold:1/Hold:0 and resume, Check, Alarm after a reset in motion, unlock."""
    boot(raw)
    raw.status()
    raw.send(b"!", expect=None)
    raw.status()  # Hold:0 at rest
    raw.send(b"$I\n", expect=None, quiet_s=1.5)  # held: no answer
    raw.send(b"~", expect=OK)  # resume: the held line is answered now
    raw.status()
    raw.send(b"$J=G91G21X20.000F120.000\n")
    raw.wait(0.5)
    raw.status()
    raw.wait(0.5)
    raw.status()
    raw.send(b"\x85", expect=None, quiet_s=0.05)
    raw.until_state(b"Idle")
    raw.send(b"G91G1X10.000F120.000\n")
    raw.wait(0.5)
    raw.status()
    raw.send(b"!", expect=None, quiet_s=0.05)
    raw.status()
    raw.until_state(b"Hold:0")
    raw.send(b"~", expect=None, quiet_s=0.05)
    raw.status()
    raw.until_state(b"Idle")
    raw.send(b"$C\n")
    raw.status()
    raw.send(b"G1X5F60\n")
    raw.send(b"$C\n", expect=b"['$' for help]\r\n")
    raw.status()
    raw.send(b"$J=G91G21X50.000F120.000\n")
    raw.wait(0.5)
    raw.status()
    raw.send(b"\x18", expect=b"to unlock]\r\n")
    raw.status()
    raw.send(b"$J=G91G21X1.000F60.000\n", expect=b"\r\n")
    raw.send(b"G1X1F60\n", expect=b"\r\n")
    raw.send(b"$I\n")
    raw.send(b"$X\n")
    raw.status()
    raw.send(b"$J=G91G21X-2.000F120.000\n")
    raw.wait(0.3)
    raw.send(b"!", expect=None, quiet_s=0.05)  # a feed hold cancels a jog
    raw.until_state(b"Idle")
    raw.send(b"~", expect=None)
    raw.status()


def rotation_rates(raw: Raw) -> None:
    """A jog at each ESTCube rate (0.1-3.5 deg/s, 60 s of motion each), three status reports
    while turning, then a jog cancel and the reports until Idle."""
    boot(raw)
    for r in ESTCUBE_RATES_DPS:
        raw.send(b"$J=G91G21X%.3fF%.3f\n" % (r * 60.0, r * 60.0))
        for _ in range(3):
            raw.wait(0.4)
            raw.status()
        raw.send(b"\x85", expect=None, quiet_s=0.02)
        raw.until_state(b"Idle", every_s=0.1)


def rate_changes(raw: Raw) -> None:
    """Rate changes while turning: jogs streamed back to back (1 deg/s, then 0.2 deg/s queued
    behind it: the planner blends them without stopping), then a cancel and a restart at a new
    rate, then a reversal."""
    boot(raw)
    raw.send(b"$J=G91G21X2.000F60.000\n")
    raw.send(b"$J=G91G21X2.000F60.000\n")
    raw.send(b"$J=G91G21X1.000F12.000\n")
    for _ in range(12):
        raw.wait(0.5)
        raw.status()
    raw.until_state(b"Idle", every_s=0.5)
    raw.send(b"$J=G91G21X30.000F60.000\n")
    raw.wait(0.6)
    raw.status()
    raw.send(b"\x85", expect=None, quiet_s=0.02)
    raw.until_state(b"Idle", every_s=0.1)
    raw.send(b"$J=G91G21X30.000F150.000\n")
    raw.wait(0.6)
    raw.status()
    raw.send(b"\x85", expect=None, quiet_s=0.02)
    raw.until_state(b"Idle", every_s=0.1)
    raw.send(b"$J=G91G21X-30.000F120.000\n")
    raw.wait(0.6)
    raw.status()
    raw.send(b"\x85", expect=None, quiet_s=0.02)
    raw.until_state(b"Idle", every_s=0.1)


def errors(raw: Raw) -> None:
    """Each error the bench's driver can meet, at rest and while jogging, and the invented
    commands of the old bench protocol ($N=, $RUN, $STOP, $S, $WARP) as GRBL answers them."""
    boot(raw)
    for line in (b"$N=300\n", b"$RUN\n", b"$STOP\n", b"$S\n", b"$WARP\n",
                 b"$J=G91G21X1.000\n", b"$J=G91G1X1.000F60.000\n", b"$JX1\n", b"$J=G91G21F60.000\n",
                 b"$100=abc\n", b"$100=-1\n", b"$20=1\n", b"$H\n", b"$999=1\n", b"$110=3000000\n",
                 b"$J=G91G21X" + b"1" * 90 + b"F60\n", b"G99\n", b"G1X1\n", b"G0G1X1\n", b"$J=G91G21X1.000F0\n"):
        raw.send(line, expect=b"\r\n")
    raw.send(b"$J=G91G21X30.000F120.000\n")
    raw.wait(0.3)
    for line in (b"$$\n", b"$I\n", b"G1X1F60\n", b"$100=800\n", b"$X\n", b"$J=G91G21X1.000F60.000\n"):
        raw.send(line, expect=b"\r\n")
    raw.send(b"\x85", expect=None, quiet_s=0.02)
    raw.until_state(b"Idle", every_s=0.1)


SESSIONS: dict[str, tuple[Callable[[Raw], None], str, str]] = {
    # name: (session, EEPROM to start from: "blank" | "bench", title)
    "boot-blank-eeprom": (boot_blank_eeprom, "blank", "power-up with a blank EEPROM; identification and read-only commands"),
    "configure-bench": (configure_bench, "blank", "a plain GRBL 1.1h configured as the stepper bench"),
    "boot-bench-eeprom": (boot_bench_eeprom, "bench", "power-up of the configured bench; soft reset at rest"),
    "states": (states, "bench", "status reports in every state; holds, cancels, check mode, alarm and unlock"),
    "rotation-rates": (rotation_rates, "bench", "jogging at each ESTCube-2 rate, cancelled"),
    "rate-changes": (rate_changes, "bench", "rate changes while turning: streamed jogs, cancel and restart, reversal"),
    "errors": (errors, "bench", "every error the driver can meet, at rest and while jogging"),
}


EEPROM_IMAGE = Path(tempfile.gettempdir()) / "grbl-bench-eeprom.dat"
"""Where configure-bench leaves the bench's EEPROM for the sessions that start from it."""


def _record(fw: GrblFirmware, session: Callable[[Raw], None], path: Path, title: str, eeprom: str,
            notes: list[str] | None = None) -> None:
    """Play ``session`` on ``fw``, stop it, write the transcript to ``path``."""
    raw = Raw(fw)
    try:
        session(raw)
        raw.wait(0.3)
    finally:
        raw.close()
        fw.stop()
    write_transcript(path, fw.events, title=title, eeprom=eeprom, notes=notes or [])
    print(f"recorded {path.stem}", flush=True)


def record_all(binary: Path, outdir: Path, only: list[str] | None = None) -> None:
    """Record every session (or those named in ``only``) into ``outdir/NAME.txt``; the
    configured EEPROM image is made by ``configure-bench`` first."""
    for name, (session, eeprom, title) in SESSIONS.items():
        if only and name not in only and name != "configure-bench":
            continue
        fw = GrblFirmware(binary, eeprom=EEPROM_IMAGE if eeprom == "bench" else None)
        _record(fw, session, outdir / f"{name}.txt", title, BLANK_EEPROM if eeprom == "blank" else BENCH_EEPROM)
        if name == "configure-bench":
            EEPROM_IMAGE.write_bytes(fw.eeprom())
        fw.cleanup()


# ---- motion profiles in the firmware's own time ------------------------------------------------
PROFILE_STEP_S = 0.005
"""grbl-sim reports the axis positions (steps) every this many s of its own simulated time."""


def profile_jog_complete(raw: Raw) -> None:
    """A 2-degree jog at the bench's top rate (3.5 deg/s) run to its end: acceleration, cruise,
    deceleration."""
    boot(raw)
    raw.send(b"$J=G91G21X2.000F210.000\n")
    raw.until_state(b"Idle", every_s=0.3)


def profile_jog_cancel(raw: Raw) -> None:
    """A jog at 2 deg/s cancelled (0x85) while cruising: the deceleration to rest."""
    boot(raw)
    raw.send(b"$J=G91G21X30.000F120.000\n")
    raw.wait(2.0)
    raw.send(b"\x85", expect=None, quiet_s=0.02)
    raw.until_state(b"Idle", every_s=0.3)


def profile_jog_junction(raw: Raw) -> None:
    """Jogs streamed back to back: 1 deg at 1 deg/s, then 0.5 deg at 0.2 deg/s, then 0.5 deg back
    at 0.5 deg/s (the planner's junctions: a slow-down without a stop, then a reversal)."""
    boot(raw)
    raw.send(b"$J=G91G21X1.000F60.000\n")
    raw.send(b"$J=G91G21X0.500F12.000\n")
    raw.send(b"$J=G91G21X-0.500F30.000\n")
    raw.until_state(b"Idle", every_s=0.5)


def profile_feed_hold(raw: Raw) -> None:
    """A G1 move held (!) while cruising, then resumed (~) and run to its end."""
    boot(raw)
    raw.send(b"G91G1X3.000F150.000\n")
    raw.wait(1.5)
    raw.send(b"!", expect=None, quiet_s=0.02)
    raw.until_state(b"Hold:0", every_s=0.3)
    raw.send(b"~", expect=None, quiet_s=0.02)
    raw.until_state(b"Idle", every_s=0.3)


PROFILES: dict[str, tuple[Callable[[Raw], None], str]] = {
    "profile-jog-complete": (profile_jog_complete, "a 2 deg jog at 3.5 deg/s run to its end, with the firmware's step log"),
    "profile-jog-cancel": (profile_jog_cancel, "a jog at 2 deg/s cancelled while cruising, with the firmware's step log"),
    "profile-jog-junction": (profile_jog_junction, "three streamed jogs (slow-down, reversal), with the firmware's step log"),
    "profile-feed-hold": (profile_feed_hold, "a G1 move held and resumed, with the firmware's step log"),
}


def record_profiles(binary: Path, outdir: Path, only: list[str] | None = None) -> None:
    """Record each profile session with grbl-sim's step log (``NAME.steps``: its simulated time,
    s, and the X, Y, Z positions in steps every :data:`PROFILE_STEP_S`)."""
    for name, (session, title) in PROFILES.items():
        if only and name not in only:
            continue
        steps = (outdir / f"{name}.steps").resolve()
        fw = GrblFirmware(binary, eeprom=EEPROM_IMAGE, step_file=steps, report_step_s=PROFILE_STEP_S)
        _record(fw, session, outdir / f"{name}.txt", title, BENCH_EEPROM,
                [f"step log: {name}.steps (grbl_sim.exe -s {name}.steps -r {PROFILE_STEP_S:g})"])
        fw.cleanup()
