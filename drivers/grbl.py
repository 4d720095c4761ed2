"""GRBL 1.1's serial protocol, as the firmware ships (gnea/grbl v1.1h, ``doc/markdown/interface.md``).

* Lines end with LF; each is answered by ``ok`` or ``error:N`` once GRBL has executed it (a motion
  line once the planner has room). This module streams by *send-response* (interface.md
  "Streaming Protocol: Simple Send-Response"): one line at a time, the next only after the
  answer, so the 128-byte receive buffer can never overflow and every answer belongs to the line
  before it.
* ``?`` ``!`` ``~`` 0x18 0x85 are realtime bytes: acted on when they arrive, never buffered; only
  ``?`` is answered, by a status report ``<State|MPos:x,y,z|FS:feed,speed|...>`` whose optional
  fields come in any order (:func:`parse_status`; unknown fields are kept, not interpreted).
* Pushed lines: ``ALARM:N``, ``[MSG:...]``, the welcome message ``Grbl 1.1h ['$' for help]``.
* After a timeout the channel is out of step: a late ``ok`` would be taken for the answer to the
  next line. :class:`GrblChannel` brings it back in step first with ``$G``, whose ``[GC:...]``
  line cannot be mistaken for a late answer: everything before it is read and discarded.

The error and alarm texts are GRBL's own tables (``doc/csv/error_codes_en_US.csv``,
``alarm_codes_en_US.csv``, v1.1+ codes), quoted in docs/golden/grbl.md and checked there.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import serial

from drivers.errors import DeviceFault, InstrumentError, InstrumentTimeout, ProtocolError
from drivers.transport import LineChannel

ERRORS: dict[int, tuple[str, str]] = {
    1: ('Expected command letter', 'G-code words consist of a letter and a value. Letter was not found.'),
    2: ('Bad number format', 'Missing the expected G-code word value or numeric value format is not valid.'),
    3: ('Invalid statement', "Grbl '$' system command was not recognized or supported."),
    4: ('Value < 0', 'Negative value received for an expected positive value.'),
    5: ('Setting disabled', 'Homing cycle failure. Homing is not enabled via settings.'),
    6: ('Value < 3 usec', 'Minimum step pulse time must be greater than 3usec.'),
    7: ('EEPROM read fail. Using defaults', 'An EEPROM read failed. Auto-restoring affected EEPROM to default values.'),
    8: ('Not idle', "Grbl '$' command cannot be used unless Grbl is IDLE. Ensures smooth operation during a job."),
    9: ('G-code lock', 'G-code commands are locked out during alarm or jog state.'),
    10: ('Homing not enabled', 'Soft limits cannot be enabled without homing also enabled.'),
    11: ('Line overflow', 'Max characters per line exceeded. Received command line was not executed.'),
    12: ('Step rate > 30kHz', "Grbl '$' setting value cause the step rate to exceed the maximum supported."),
    13: ('Check Door', 'Safety door detected as opened and door state initiated.'),
    14: ('Line length exceeded', 'Build info or startup line exceeded EEPROM line length limit. Line not stored.'),
    15: ('Travel exceeded', 'Jog target exceeds machine travel. Jog command has been ignored.'),
    16: ('Invalid jog command', "Jog command has no '=' or contains prohibited g-code."),
    17: ('Setting disabled', 'Laser mode requires PWM output.'),
    20: ('Unsupported command', 'Unsupported or invalid g-code command found in block.'),
    21: ('Modal group violation', 'More than one g-code command from same modal group found in block.'),
    22: ('Undefined feed rate', 'Feed rate has not yet been set or is undefined.'),
    23: ('Invalid gcode ID:23', 'G-code command in block requires an integer value.'),
    24: ('Invalid gcode ID:24', 'More than one g-code command that requires axis words found in block.'),
    25: ('Invalid gcode ID:25', 'Repeated g-code word found in block.'),
    26: ('Invalid gcode ID:26', 'No axis words found in block for g-code command or current modal state which requires them.'),
    27: ('Invalid gcode ID:27', 'Line number value is invalid.'),
    28: ('Invalid gcode ID:28', 'G-code command is missing a required value word.'),
    29: ('Invalid gcode ID:29', 'G59.x work coordinate systems are not supported.'),
    30: ('Invalid gcode ID:30', 'G53 only allowed with G0 and G1 motion modes.'),
    31: ('Invalid gcode ID:31', 'Axis words found in block when no command or current modal state uses them.'),
    32: ('Invalid gcode ID:32', 'G2 and G3 arcs require at least one in-plane axis word.'),
    33: ('Invalid gcode ID:33', 'Motion command target is invalid.'),
    34: ('Invalid gcode ID:34', 'Arc radius value is invalid.'),
    35: ('Invalid gcode ID:35', 'G2 and G3 arcs require at least one in-plane offset word.'),
    36: ('Invalid gcode ID:36', 'Unused value words found in block.'),
    37: ('Invalid gcode ID:37', 'G43.1 dynamic tool length offset is not assigned to configured tool length axis.'),
    38: ('Invalid gcode ID:38', 'Tool number greater than max supported value.'),
}
"""GRBL 1.1 ``error:N``: (v1.0 message, description), doc/csv/error_codes_en_US.csv."""

ALARMS: dict[int, tuple[str, str]] = {
    1: ('Hard limit', 'Hard limit has been triggered. Machine position is likely lost due to sudden halt. Re-homing is highly recommended.'),
    2: ('Soft limit', 'Soft limit alarm. G-code motion target exceeds machine travel. Machine position retained. Alarm may be safely unlocked.'),
    3: ('Abort during cycle', 'Reset while in motion. Machine position is likely lost due to sudden halt. Re-homing is highly recommended.'),
    4: ('Probe fail', 'Probe fail. Probe is not in the expected initial state before starting probe cycle when G38.2 and G38.3 is not triggered and G38.4 and G38.5 is triggered.'),
    5: ('Probe fail', 'Probe fail. Probe did not contact the workpiece within the programmed travel for G38.2 and G38.4.'),
    6: ('Homing fail', 'Homing fail. The active homing cycle was reset.'),
    7: ('Homing fail', 'Homing fail. Safety door was opened during homing cycle.'),
    8: ('Homing fail', 'Homing fail. Pull off travel failed to clear limit switch. Try increasing pull-off setting or check wiring.'),
    9: ('Homing fail', 'Homing fail. Could not find limit switch within search distances. Try increasing max travel, decreasing pull-off distance, or check wiring.'),
    10: ('Homing fail', 'Homing fail. Second dual axis limit switch failed to trigger within configured search distance after first. Try increasing trigger fail distance or check wiring.'),
}
"""GRBL 1.1 ``ALARM:N``: (v1.0 message, description), doc/csv/alarm_codes_en_US.csv."""

MEANINGS: dict[str, str] = {**{f"error:{k}": f"{m}: {d}" for k, (m, d) in ERRORS.items()},
                            **{f"ALARM:{k}": f"{m}: {d}" for k, (m, d) in ALARMS.items()}}
"""Answer word -> what the errors quote (``error:8`` -> ``Not idle: Grbl '$' command ...``)."""

STATUS_REPORT = b"?"
CYCLE_START = b"~"
FEED_HOLD = b"!"
SOFT_RESET = b"\x18"
JOG_CANCEL = b"\x85"
SYNC_LINE = "$G"
"""Sent to bring the channel back in step: its ``[GC:...]`` answer marks where the answers to the
lines sent before it end."""

_WELCOME = re.compile(r"^Grbl (?P<version>\d+\.\d+[a-z]?) \['\$' for help\]$")
_VER = re.compile(r"^\[VER:(?P<version>[^:\]]*):(?P<build>[^\]]*)\]$")
_OPT = re.compile(r"^\[OPT:(?P<codes>[^,\]]*),(?P<blocks>\d+),(?P<rx>\d+)\]$")
_SETTING = re.compile(r"^\$(?P<n>\d{1,3})=(?P<value>-?\d+(?:\.\d+)?)$")
_NUMBER = re.compile(r"^-?\d{1,10}(?:\.\d{1,6})?$")
STATES = ("Idle", "Run", "Hold", "Jog", "Alarm", "Door", "Check", "Home", "Sleep")


@dataclass
class Status:
    """One realtime status report. Positions in the machine's units (the bench: deg), rates in
    units per minute; None where the report did not carry the field."""

    state: str
    substate: int | None = None
    mpos: tuple[float, ...] | None = None
    wpos: tuple[float, ...] | None = None
    wco: tuple[float, ...] | None = None
    feed: float | None = None
    spindle: float | None = None
    pins: str = ""
    buffer: tuple[int, int] | None = None
    """``Bf:`` planner blocks and receive-buffer bytes available (when $10 asks for it)."""
    fields: dict[str, str] = field(default_factory=dict)
    """Every field as sent (name -> value), known or not."""

    @property
    def moving(self) -> bool:
        return self.state in ("Run", "Jog", "Home") or (self.state == "Hold" and self.substate == 1)


def welcome_version(line: str) -> str | None:
    """The version of a welcome message (``Grbl 1.1h ['$' for help]`` -> ``1.1h``), else None."""
    m = _WELCOME.match(line)
    return m["version"] if m else None


def _axes(text: str, line: str) -> tuple[float, ...]:
    parts = text.split(",")
    if not 1 <= len(parts) <= 6 or not all(_NUMBER.match(p) for p in parts):
        raise ProtocolError(f"GRBL status report with a malformed position {text!r}: {line!r}")
    return tuple(float(p) for p in parts)


def parse_status(line: str) -> Status:
    """A realtime status report, field by field (interface.md "Real-time Status Reports"): the
    state (with its sub-state) first, then ``Name:value`` fields in any order; unknown fields are
    kept in :attr:`Status.fields` and otherwise ignored. ProtocolError when it is not one."""
    if not (line.startswith("<") and line.endswith(">")):
        raise ProtocolError(f"not a GRBL status report: {line!r}")
    parts = line[1:-1].split("|")
    state, _, sub = parts[0].partition(":")
    if state not in STATES or (sub and not sub.isdigit()):
        raise ProtocolError(f"GRBL status report with an unknown state {parts[0]!r}: {line!r}")
    st = Status(state, int(sub) if sub else None)
    for p in parts[1:]:
        name, sep, value = p.partition(":")
        if not sep or not name.isalpha():
            raise ProtocolError(f"GRBL status report with a malformed field {p!r}: {line!r}")
        st.fields[name] = value
        if name == "MPos":
            st.mpos = _axes(value, line)
        elif name == "WPos":
            st.wpos = _axes(value, line)
        elif name == "WCO":
            st.wco = _axes(value, line)
        elif name in ("FS", "F"):
            nums = _axes(value, line)
            st.feed = nums[0]
            st.spindle = nums[1] if len(nums) > 1 else None
        elif name == "Pn":
            st.pins = value
        elif name == "Bf":
            nums = _axes(value, line)
            if len(nums) == 2:
                st.buffer = (int(nums[0]), int(nums[1]))
    if st.mpos is None and st.wpos is None:
        raise ProtocolError(f"GRBL status report without a position: {line!r}")
    return st


def parse_settings(lines: list[str]) -> dict[int, float]:
    """``$$`` answer lines -> {setting number: value}; other lines are ignored."""
    out: dict[int, float] = {}
    for line in lines:
        m = _SETTING.match(line)
        if m:
            out[int(m["n"])] = float(m["value"])
    return out


def parse_build_info(lines: list[str]) -> tuple[str, str, str]:
    """``$I`` answer lines -> (version, build info string, options line); ProtocolError without
    a ``[VER:...]`` line."""
    version = build = options = None
    for line in lines:
        if (m := _VER.match(line)) is not None:
            version, build = m["version"], m["build"]
        elif line.startswith("[OPT:"):
            options = line[5:-1]
    if version is None:
        raise ProtocolError(f"$I answered without a [VER:...] line: {lines!r}")
    return version, build, options or ""


class GrblChannel(LineChannel):
    """The send-response line protocol of GRBL with realtime queries and resynchronisation."""

    def __init__(self, port: serial.SerialBase, timeout_s: float, name: str, on_traffic=None):
        super().__init__(port, timeout_s, name, on_traffic, meanings=MEANINGS)
        self.in_step = True
        """False after a timeout: a late answer may still come, so :meth:`transact` resyncs first."""
        self.discarded: list[str] = []
        """Lines read and dropped while bringing the channel back in step."""
        self.pushed: list[str] = []
        """Pushed lines (``[MSG:...]``, welcome messages) read while waiting for something else."""

    def transact(self, line: str) -> list[str]:
        if not self.in_step:
            self.resync()
        try:
            return super().transact(line)
        except InstrumentTimeout:
            self.in_step = False
            raise

    def resync(self) -> None:
        """Send ``$G`` and drop every line before its ``[GC:...]`` answer (late ``ok``/``error``
        of lines that timed out); in step again after its ``ok``. InstrumentTimeout if it fails."""
        self._write((SYNC_LINE + "\n").encode("ascii"), SYNC_LINE)
        budget = self._budget()
        while True:
            try:
                text, budget = self._read_line(SYNC_LINE, budget)
            except InstrumentTimeout:
                raise InstrumentTimeout(f"{self.name}: out of step after a timeout and $G was not answered "
                                        f"within {self.timeout_s:g} s (a held or busy GRBL?)") from None
            if text.startswith("[GC:"):
                break
            self.discarded.append(text)
        text, budget = self._read_line(SYNC_LINE, budget)
        if text != "ok":
            raise ProtocolError(f"{self.name}: $G answered {self._described(text)} while resynchronising")
        self.in_step = True

    def realtime(self, byte: bytes) -> None:
        """A realtime byte that has no answer (``!``, ``~``, 0x18, 0x85)."""
        self.send_realtime(byte)

    def status(self) -> tuple[Status, str]:
        """Send ``?``; (the report, its line). Lines that come before the report: pushed messages
        are kept in :attr:`pushed`, an ``ok``/``error:N`` means the channel was out of step, an
        ``ALARM:N`` raises DeviceFault (after the report has been read)."""
        self.send_realtime(STATUS_REPORT)
        budget = self._budget()
        alarms: list[str] = []
        while True:
            text, budget = self._read_line("?", budget)
            if text.startswith("<"):
                break
            if text == "ok" or text.startswith("error:"):
                self.in_step = False
                self.discarded.append(text)
            elif text.startswith("ALARM:"):
                alarms.append(text)
            else:
                self.pushed.append(text)
        report = parse_status(text)
        if alarms:
            raise DeviceFault(f"{self.name} raised {', '.join(self._described(a) for a in alarms)}")
        return report, text

    def read_until(self, predicate, what: str, empty_reads: int) -> tuple[list[str], str]:
        """Read lines until one satisfies ``predicate``; (the lines before it, that line). Waits
        for up to ``empty_reads`` read timeouts without a byte (a board that is still booting)."""
        lines: list[str] = []
        quiet = 0
        while True:
            try:
                text, _ = self._read_line(what, self._budget())
            except InstrumentTimeout:
                quiet += 1
                if quiet >= empty_reads:
                    raise
                continue
            if predicate(text):
                return lines, text
            lines.append(text)

    def pause(self, seconds: float) -> None:
        """Let ``seconds`` pass on the link's clock (a read with that timeout, expecting nothing;
        bytes that arrive meanwhile are kept for the next read). Wall time on hardware, run time
        on a simulator."""
        old = self.port.timeout
        try:
            self.port.timeout = seconds
            chunk = self.port.read(1)
        except serial.SerialException as exc:
            raise InstrumentError(f"{self.name}: waiting on the port failed: {exc}") from None
        finally:
            self.port.timeout = old
        self._rx += chunk
