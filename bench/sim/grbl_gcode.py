"""GRBL 1.1's g-code parser (gnea/grbl ``gcode.c`` ``gc_execute_line``), for the simulated bench.

Parses one line as GRBL has it after its own filtering (spaces and comments gone, upper case),
checks it in GRBL's order and returns GRBL's status code (``report.h`` STATUS_*), the parser's
new state and what to execute (a line, a dwell, a program end). ``$J=`` jog lines go through the
same parser with GRBL's jog restrictions.

Modelled: G0 G1 G4 G10 L2/L20 G17-G19 G20 G21 G28 G30 (and .1) G40 G43.1 G49 G53 G54-G59 G61 G80
G90 G91 G91.1 G92 G92.1 G93 G94, M0 M1 M2 M30 M3 M4 M5 M8 M9, words F I J K L N P R S T X Y Z.
Not modelled (answered ``error:20``, unsupported command, which real GRBL does not say): arcs
(G2/G3) and probing (G38.x); the bench needs neither.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field

import struct

# report.h status codes
OK = 0
EXPECTED_COMMAND_LETTER = 1
BAD_NUMBER_FORMAT = 2
NEGATIVE_VALUE = 4
INVALID_JOG_COMMAND = 16
UNSUPPORTED_COMMAND = 20
MODAL_GROUP_VIOLATION = 21
UNDEFINED_FEED_RATE = 22
COMMAND_VALUE_NOT_INTEGER = 23
AXIS_COMMAND_CONFLICT = 24
WORD_REPEATED = 25
NO_AXIS_WORDS = 26
INVALID_LINE_NUMBER = 27
VALUE_WORD_MISSING = 28
UNSUPPORTED_COORD_SYS = 29
G53_INVALID_MOTION_MODE = 30
AXIS_WORDS_EXIST = 31
UNUSED_WORDS = 36
G43_DYNAMIC_AXIS_ERROR = 37
MAX_VALUE_EXCEEDED = 38

MAX_INT_DIGITS = 8  # nuts_bolts.c
MAX_LINE_NUMBER = 10000000  # gcode.h
MAX_TOOL_NUMBER = 255  # gcode.h
MM_PER_INCH = 25.40
N_COORD = 6  # G54..G59
AXES = "XYZ"
TOOL_LENGTH_AXIS = 2  # config.h TOOL_LENGTH_OFFSET_AXIS Z_AXIS

# modal values as gcode.h numbers them
MOTION_SEEK, MOTION_LINEAR, MOTION_NONE = 0, 1, 80
_F32_STRUCT = struct.Struct("<f")


def f32(x: float) -> float:
    """``x`` rounded to single precision (the AVR's ``float``)."""
    return _F32_STRUCT.unpack(_F32_STRUCT.pack(x))[0]


def read_float(line: str, i: int) -> tuple[float, int] | None:
    """nuts_bolts.c read_float: a number at ``line[i]`` (sign, up to 8 significant digits kept,
    one decimal point); (value, index after it) or None when there is no digit."""
    n = len(line)
    neg = False
    if i < n and line[i] in "+-":
        neg = line[i] == "-"
        i += 1
    intval, exp, ndigit, isdec = 0, 0, 0, False
    while i < n:
        c = line[i]
        if "0" <= c <= "9":
            ndigit += 1
            if ndigit <= MAX_INT_DIGITS:
                if isdec:
                    exp -= 1
                intval = intval * 10 + (ord(c) - 48)
            elif not isdec:
                exp += 1
        elif c == "." and not isdec:
            isdec = True
        else:
            break
        i += 1
    if not ndigit:
        return None
    f = f32(intval)
    if f != 0:
        while exp <= -2:
            f = f32(f * f32(0.01))
            exp += 2
        if exp < 0:
            f = f32(f * f32(0.1))
        elif exp > 0:
            while exp > 0:
                f = f32(f * 10.0)
                exp -= 1
    return (-float(f) if neg else float(f)), i


@dataclass
class Modal:
    motion: int = MOTION_SEEK  # gc_init clears the state: G0
    feed_rate_mode: int = 0  # 0 G94, 1 G93
    units: int = 0  # 0 G21 mm, 1 G20 inches
    distance: int = 0  # 0 G90, 1 G91
    plane: int = 0  # 0 G17, 1 G18, 2 G19
    coord_select: int = 0  # 0 = G54
    program_flow: int = 0
    spindle: int = 0  # 0 M5, 1 M3 (CW), 2 M4 (CCW)
    coolant: int = 0  # 0 M9, 1 M8
    tool_length: int = 0


@dataclass
class ParserState:
    """gc_state: modal groups, position (mm, machine coordinates of the program), offsets."""

    modal: Modal = field(default_factory=Modal)
    position: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    coord_system: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    coord_offset: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    tool_length_offset: float = 0.0
    feed_rate: float = 0.0
    spindle_speed: float = 0.0
    tool: int = 0
    line_number: int = 0


@dataclass
class Action:
    """What an accepted line asks the machine to do, in order."""

    lines: list[tuple[list[float], float, bool]] = field(default_factory=list)
    """(target mm, feed mm/min, rapid) per planned line."""
    dwell_s: float = 0.0
    sync: bool = False
    """Wait until all motion is done before going on (dwell, program flow)."""
    program_flow: int = 0
    """0, or 3 (M0 pause), 2 (M2) / 30 (M30) program end."""
    wco_changed: bool = False
    coord_data: dict[int, list[float]] = field(default_factory=dict)
    """EEPROM coordinate data written (index 0-5 G54-G59, 6 G28, 7 G30)."""
    spindle_changed: bool = False


def execute_line(line: str, state: ParserState, coord_data: dict[int, list[float]], *, jog: bool = False) -> tuple[int, ParserState, Action]:
    """Check ``line`` (GRBL-filtered) against ``state``; (status, new state, action). On an error
    the state is returned unchanged. ``coord_data``: the EEPROM coordinate systems (read only)."""
    new = copy.deepcopy(state)
    act = Action()
    status = _parse(line, state, new, act, coord_data, jog)
    if status != OK:
        return status, state, Action()
    return OK, new, act


def _parse(line: str, st: ParserState, new: ParserState, act: Action, coord_data, jog: bool) -> int:
    m = copy.deepcopy(st.modal)
    if jog:
        m.motion = MOTION_LINEAR
        m.feed_rate_mode = 0
    axis_command = 0  # 0 none, 1 non-modal, 2 motion, 3 tool length
    non_modal = 0
    command_words: set[int] = set()
    values: dict[str, float] = {}
    axis_words = 0
    i = 3 if jog else 0
    n = len(line)
    while i < n:
        letter = line[i]
        if not ("A" <= letter <= "Z"):
            return EXPECTED_COMMAND_LETTER
        r = read_float(line, i + 1)
        if r is None:
            return BAD_NUMBER_FORMAT
        value, i = r
        int_value = int(math.trunc(value))
        mantissa = int(round(100 * (value - int_value)))
        if letter == "G":
            if int_value in (10, 28, 30, 92) or int_value in (4, 53):
                if int_value in (10, 28, 30, 92) and mantissa == 0:
                    if axis_command:
                        return AXIS_COMMAND_CONFLICT
                    axis_command = 1
                group = 0
                non_modal = int_value
                if int_value in (28, 30, 92):
                    if mantissa not in (0, 10):
                        return UNSUPPORTED_COMMAND
                    non_modal += mantissa
                    mantissa = 0
            elif int_value in (0, 1, 2, 3, 38, 80):
                if int_value != 80:
                    if axis_command:
                        return AXIS_COMMAND_CONFLICT
                    axis_command = 2
                group = 1
                if int_value in (2, 3, 38):
                    return UNSUPPORTED_COMMAND  # arcs and probing are not modelled
                m.motion = int_value
            elif int_value in (17, 18, 19):
                group, m.plane = 2, int_value - 17
            elif int_value in (90, 91):
                if mantissa == 0:
                    group, m.distance = 3, int_value - 90
                else:
                    group = 4
                    if mantissa != 10 or int_value == 90:
                        return UNSUPPORTED_COMMAND
                    mantissa = 0
            elif int_value in (93, 94):
                group, m.feed_rate_mode = 5, 94 - int_value
            elif int_value in (20, 21):
                group, m.units = 6, 21 - int_value
            elif int_value == 40:
                group = 7
            elif int_value in (43, 49):
                group = 8
                if axis_command:
                    return AXIS_COMMAND_CONFLICT
                axis_command = 3
                if int_value == 49:
                    m.tool_length = 0
                elif mantissa == 10:
                    m.tool_length = 1
                else:
                    return UNSUPPORTED_COMMAND
                mantissa = 0
            elif 54 <= int_value <= 59:
                group, m.coord_select = 12, int_value - 54
            elif int_value == 61:
                group = 13
                if mantissa != 0:
                    return UNSUPPORTED_COMMAND
            else:
                return UNSUPPORTED_COMMAND
            if mantissa > 0:
                return COMMAND_VALUE_NOT_INTEGER
            if group in command_words:
                return MODAL_GROUP_VIOLATION
            command_words.add(group)
        elif letter == "M":
            if mantissa > 0:
                return COMMAND_VALUE_NOT_INTEGER
            if int_value in (0, 1, 2, 30):
                group = 104
                if int_value == 0:
                    m.program_flow = 3
                elif int_value != 1:
                    m.program_flow = int_value
            elif int_value in (3, 4, 5):
                group = 107
                m.spindle = {3: 1, 4: 2, 5: 0}[int_value]
            elif int_value in (8, 9):
                group = 108
                m.coolant = 1 if int_value == 8 else 0
            else:
                return UNSUPPORTED_COMMAND
            if group in command_words:
                return MODAL_GROUP_VIOLATION
            command_words.add(group)
        else:
            if letter not in "FIJKLNPRSTXYZ":
                return UNSUPPORTED_COMMAND
            if letter == "T" and value > MAX_TOOL_NUMBER:
                return MAX_VALUE_EXCEEDED
            if letter in values:
                return WORD_REPEATED
            if letter in "FNPTS" and value < 0.0:
                return NEGATIVE_VALUE
            values[letter] = value
            if letter in AXES:
                axis_words |= 1 << AXES.index(letter)
    # ---- step 3: checks ------------------------------------------------------------------------
    if axis_words and not axis_command:
        axis_command = 2
    if "N" in values and math.trunc(values["N"]) > MAX_LINE_NUMBER:
        return INVALID_LINE_NUMBER
    f = values.get("F", 0.0)
    if jog:
        if "F" not in values:
            return UNDEFINED_FEED_RATE
        if m.units == 1:
            f *= MM_PER_INCH
    elif m.feed_rate_mode == 1:
        if axis_command == 2 and m.motion not in (MOTION_NONE, MOTION_SEEK) and "F" not in values:
            return UNDEFINED_FEED_RATE
    elif st.modal.feed_rate_mode == 0:
        if "F" in values:
            if m.units == 1:
                f *= MM_PER_INCH
        else:
            f = st.feed_rate
    s = values.get("S", st.spindle_speed)
    if non_modal == 4:
        if "P" not in values:
            return VALUE_WORD_MISSING
    xyz = [values.get(a, 0.0) for a in AXES]
    if m.units == 1:
        xyz = [x * MM_PER_INCH if axis_words & (1 << k) else x for k, x in enumerate(xyz)]
    if axis_command == 3 and m.tool_length == 1 and axis_words ^ (1 << TOOL_LENGTH_AXIS):
        return G43_DYNAMIC_AXIS_ERROR
    block_coord = list(st.coord_system)
    if 12 in command_words and m.coord_select != st.modal.coord_select:
        block_coord = list(coord_data.get(m.coord_select, [0.0, 0.0, 0.0]))
    ijk = [0.0, 0.0, 0.0]
    used = set(values)
    if non_modal == 10:
        if not axis_words:
            return NO_AXIS_WORDS
        if "P" not in values or "L" not in values:
            return VALUE_WORD_MISSING
        sel = int(math.trunc(values["P"]))
        if sel > N_COORD:
            return UNSUPPORTED_COORD_SYS
        L = int(math.trunc(values["L"]))
        if L not in (2, 20) or (L == 2 and "R" in values):
            return UNSUPPORTED_COMMAND
        used -= {"L", "P"}
        sel = sel - 1 if sel > 0 else m.coord_select
        ijk = list(coord_data.get(sel, [0.0, 0.0, 0.0]))
        for k in range(3):
            if axis_words & (1 << k):
                ijk[k] = (st.position[k] - st.coord_offset[k] - xyz[k]) if L == 20 else xyz[k]
                if L == 20 and k == TOOL_LENGTH_AXIS:
                    ijk[k] -= st.tool_length_offset
        act.coord_data[sel] = ijk
    elif non_modal == 92:
        if not axis_words:
            return NO_AXIS_WORDS
        for k in range(3):
            if axis_words & (1 << k):
                xyz[k] = st.position[k] - block_coord[k] - xyz[k] - (st.tool_length_offset if k == TOOL_LENGTH_AXIS else 0.0)
            else:
                xyz[k] = st.coord_offset[k]
    else:
        if axis_command != 3 and axis_words:
            for k in range(3):
                if not axis_words & (1 << k):
                    xyz[k] = st.position[k]
                elif non_modal != 53:
                    if m.distance == 0:
                        xyz[k] += block_coord[k] + st.coord_offset[k] + (st.tool_length_offset if k == TOOL_LENGTH_AXIS else 0.0)
                    else:
                        xyz[k] += st.position[k]
        if non_modal in (28, 30):
            ijk = list(coord_data.get(6 if non_modal == 28 else 7, [0.0, 0.0, 0.0]))
            if axis_words:
                for k in range(3):
                    if not axis_words & (1 << k):
                        ijk[k] = st.position[k]
            else:
                axis_command = 0
        elif non_modal == 53 and m.motion not in (MOTION_SEEK, MOTION_LINEAR):
            return G53_INVALID_MOTION_MODE
    if m.motion == MOTION_NONE:
        if axis_words:
            return AXIS_WORDS_EXIST
    elif axis_command == 2:
        if m.motion == MOTION_SEEK:
            if not axis_words:
                axis_command = 0
        else:
            if f == 0.0:
                return UNDEFINED_FEED_RATE
            if not axis_words:
                axis_command = 0
    used -= {"N", "F"} if jog else {"N", "F", "S", "T"}
    if axis_command:
        used -= set(AXES)
    if non_modal == 4:
        used.discard("P")
    if used:
        return UNUSED_WORDS
    # ---- step 4: execute ----------------------------------------------------------------------
    if jog:
        if command_words - {0, 3, 6}:
            return INVALID_JOG_COMMAND
        if non_modal not in (0, 53):
            return INVALID_JOG_COMMAND
        # GRBL plans the jog to the block's target even without axis words: that target is then
        # the machine origin (gc_block.values.xyz left zero), where it goes.
        act.lines.append((list(xyz), f, False))
        new.position = list(xyz)
        return OK
    new.line_number = int(math.trunc(values.get("N", 0)))
    new.modal.feed_rate_mode = m.feed_rate_mode
    new.feed_rate = f
    if s != st.spindle_speed:
        new.spindle_speed = s
    new.tool = int(math.trunc(values.get("T", st.tool)))
    if m.spindle != st.modal.spindle:
        act.spindle_changed = True
    new.modal.spindle = m.spindle
    new.modal.coolant = m.coolant
    if non_modal == 4:
        act.sync = True
        act.dwell_s = values["P"]
    new.modal.plane = m.plane
    new.modal.units = m.units
    if axis_command == 3:
        new.modal.tool_length = m.tool_length
        tlo = xyz[TOOL_LENGTH_AXIS] if m.tool_length == 1 else 0.0
        if tlo != st.tool_length_offset:
            new.tool_length_offset = tlo
            act.wco_changed = True
    if m.coord_select != st.modal.coord_select:
        new.modal.coord_select = m.coord_select
        new.coord_system = block_coord
        act.wco_changed = True
    new.modal.distance = m.distance
    if non_modal == 10:
        if sel == new.modal.coord_select:
            new.coord_system = list(ijk)
            act.wco_changed = True
    elif non_modal in (28, 30):
        if axis_command:
            act.lines.append((list(xyz), f, True))
        act.lines.append((list(ijk), f, True))
        new.position = list(ijk)
    elif non_modal in (38, 40):  # G28.1 / G30.1: store the position
        act.coord_data[6 if non_modal == 38 else 7] = list(st.position)
    elif non_modal == 92:
        new.coord_offset = list(xyz)
        act.wco_changed = True
    elif non_modal == 102:  # G92.1
        new.coord_offset = [0.0, 0.0, 0.0]
        act.wco_changed = True
    new.modal.motion = m.motion
    if m.motion != MOTION_NONE and axis_command == 2:
        act.lines.append((list(xyz), f, m.motion == MOTION_SEEK))
        new.position = list(xyz)
    if m.program_flow:
        act.sync = True
        act.program_flow = m.program_flow
        if m.program_flow in (2, 30):
            new.modal.motion = MOTION_LINEAR
            new.modal.plane = 0
            new.modal.distance = 0
            new.modal.feed_rate_mode = 0
            new.modal.coord_select = 0
            new.modal.spindle = 0
            new.modal.coolant = 0
            new.coord_system = list(coord_data.get(0, [0.0, 0.0, 0.0]))
            act.wco_changed = True
    new.modal.program_flow = 0
    return OK
