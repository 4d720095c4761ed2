"""Play a transcript of the real GRBL 1.1h firmware against the simulator, exchange by exchange.

The host bytes of the transcript go to :class:`bench.sim.stepper_bench.StepperBenchSim` in order;
everything the simulator answers is compared with what the firmware answered. Lines are compared
byte for byte. Status reports too, with two exceptions that come from time, not from the protocol:

* the firmware in grbl-sim runs slower than the wall clock, and by how much depends on the load
  of the machine (0.25-0.7x here), so the transcript's times say little about the firmware's own.
  The simulator's clock is therefore set by the firmware's answers: before a ``?`` whose recorded
  report is taken while moving, the simulator runs until its axis is where the firmware's was;
  before one taken at rest, until it is at rest; a cancel, hold or reset sent while moving is
  applied at the moment that makes the simulator stop (or, for a reset, stand) where the
  firmware did. Positions, states, fields and counters must then agree exactly.
* the reported rate (``FS:``) of a firmware accelerating or decelerating is the speed of the last
  step segment it has prepared (stepper.c ``st_get_realtime_rate``), up to ~60 ms ahead of the
  position; the simulator reports the speed at the position. During such ramps the rate may
  differ by :data:`RAMP_FEED_TOLERANCE_MM_MIN`; at rest and cruising it must be equal.

:func:`play` returns the list of differences (empty: the transcript passes).
"""

from __future__ import annotations

import copy
import math
import re
from dataclasses import dataclass

from bench.clock import VirtualClock
from bench.sim.stepper_bench import StepperBenchSim, bench_eeprom
from tests.golden.expected_exchange import ExpectedExchangePort
from tests.golden.grbl_transcript import Transcript

GRBL_SIM_PINS = "PXYZRHS"
"""grbl-sim reads every input pin as triggered (``Pn:PXYZRHS`` in every report)."""
BENCH_EEPROM = dict(steps_per_deg=894.33, max_rate_deg_min=210.0, accel_deg_s2=10.0, build_info="STEPPER_BENCH:EC2-01")
"""The EEPROM the transcripts marked ``eeprom: bench`` started from (configure-bench.txt)."""
RAMP_FEED_TOLERANCE_MM_MIN = 60.0
"""10 deg/s² for 0.1 s: the most the firmware's prepared segments run ahead of its position."""
REPORT = re.compile(r"^<(?P<state>[A-Za-z]+(?::\d)?)\|(?P<pos>[MW]Pos:[-0-9.,]+)(?P<mid>(?:\|Bf:[0-9,]+)?)\|FS:(?P<feed>\d+),(?P<spindle>\d+)(?P<rest>.*)>\r\n$")
MOVING = ("Run", "Jog", "Hold:1", "Home")
STOPPING_BYTES = (b"\x85", b"!", b"\x18")


@dataclass
class Exchange:
    host: bytes
    firmware: bytes


REALTIME = frozenset(b"?!~\x18") | frozenset(range(0x80, 0x100))


def _tokens(data: bytes) -> list[bytes]:
    """Host bytes as GRBL takes them: each realtime byte on its own, lines with their end."""
    out: list[bytes] = []
    line = bytearray()
    for b in data:
        if b in REALTIME:
            out.append(bytes([b]))
        else:
            line.append(b)
            if b == 0x0A:
                out.append(bytes(line))
                line.clear()
    if line:
        out.append(bytes(line))
    return out


def exchanges(tr: Transcript, start_s: float | None = None, end_s: float | None = None) -> tuple[bytes, list[Exchange]]:
    """(the firmware's power-up output, [host bytes and the firmware bytes after them]), host
    bytes cut into GRBL's units (a realtime byte, a line); answers go with the last unit before
    them. grbl-sim reads no input in its first simulated second, so host bytes written before its
    welcome message are answered after it: the power-up output is everything up to the first
    welcome message. ``start_s``/``end_s``: only the events in that time span."""
    events = [e for e in tr.events if (start_s is None or e.t_s >= start_s) and (end_s is None or e.t_s < end_s)]
    boot = bytearray()
    if start_s is None:
        for k, e in enumerate(events):
            if e.direction == "<":
                boot += e.data
                if b"['$' for help]" in e.data:
                    events = events[:k + 1] + events[k + 1:]
                    events = [x for j, x in enumerate(events) if not (x.direction == "<" and j <= k)]
                    break
    out: list[Exchange] = []
    for e in events:
        if e.direction == ">":
            out.extend(Exchange(tok, b"") for tok in _tokens(e.data))
        elif out:
            out[-1].firmware += e.data
    return bytes(boot), out


def make_sim(tr: Transcript) -> tuple[StepperBenchSim, VirtualClock]:
    clock = VirtualClock()
    eeprom = bench_eeprom(**BENCH_EEPROM) if tr.eeprom.startswith("bench") else None
    return StepperBenchSim(clock, None, eeprom, pins=GRBL_SIM_PINS), clock


def _report_position(line: bytes) -> float | None:
    m = REPORT.match(line.decode("ascii", "replace"))
    return float(m["pos"].split(":")[1].split(",")[0]) if m else None


def _lines(data: bytes) -> list[bytes]:
    return [ln for ln in re.split(rb"(?<=\n)", data) if ln]


def same_line(expected: bytes, got: bytes, ramp: bool) -> bool:
    if expected == got:
        return True
    me, mg = REPORT.match(expected.decode("ascii", "replace")), REPORT.match(got.decode("ascii", "replace"))
    if not (me and mg and ramp):
        return False
    same = all(me[k] == mg[k] for k in ("state", "pos", "mid", "spindle", "rest"))
    return same and abs(int(me["feed"]) - int(mg["feed"])) <= RAMP_FEED_TOLERANCE_MM_MIN


# ---- finding the simulator's time from the firmware's answers -------------------------------------
def _path(sim: StepperBenchSim, t_end_s: float, n: int = 400):
    """(t, x of the bench axis, speed) sampled along the simulator's planned motion."""
    segs = sim.motion.profile()
    x = sim.motion.position_mm()[sim.axis]
    out = [(sim.t, x, sim.motion.speed)]
    for s in segs:
        for k in range(1, n + 1):
            dt = s.duration_s * k / n
            out.append((s.t_s + dt, x + s.unit[sim.axis] * (s.v * dt + 0.5 * s.a * dt * dt), s.v + s.a * dt))
        x += s.unit[sim.axis] * (s.v * s.duration_s + 0.5 * s.a * s.duration_s ** 2)
    return out


def _first_time(sim: StepperBenchSim, f, target: float, pts=None) -> float | None:
    """First run time from now at which ``f(x, v)`` reaches ``target`` along the planned motion."""
    pts = pts if pts is not None else _path(sim, 0.0)
    if not pts:
        return None
    f0 = f(pts[0][1], pts[0][2])
    sign = 1.0 if target >= f0 else -1.0
    prev = pts[0]
    for p in pts[1:]:
        if sign * (f(p[1], p[2]) - target) >= 0:
            # linear interpolation between samples
            a, b = sign * (f(prev[1], prev[2]) - target), sign * (f(p[1], p[2]) - target)
            w = 0.0 if b == a else -a / (b - a)
            return prev[0] + w * (p[0] - prev[0])
        prev = p
    return None


def _step_middle(sim: StepperBenchSim, printed: float) -> float:
    """The position (deg) half a step past the step a report printed as ``printed``, coming from
    where the axis is now: where the simulator counts exactly that step."""
    spmm = sim.motion.limits.steps_per_mm[sim.axis]
    direction = 1.0 if printed >= sim.motion.position_mm()[sim.axis] else -1.0
    return (round(printed * spmm) + 0.5 * direction) / spmm


def _run_until_at(sim: StepperBenchSim, clock: VirtualClock, position: float) -> None:
    """Run until the axis is at ``position``; when that is where it comes to rest, until the
    moment it stops (the firmware still reports the moving state for $1 ms after its last step)."""
    t = _first_time(sim, lambda x, v: x, _step_middle(sim, position))
    if t is not None and t > clock.now():
        clock.sleep_until(t)
        sim.pending_bytes(t)
        return
    spmm = sim.motion.limits.steps_per_mm[sim.axis]
    for _ in range(10000):
        if not sim.motion.running or round(position * spmm) == sim.motion.position_steps()[sim.axis]:
            return
        t = sim.motion.next_event_s()
        if t is None:
            return
        clock.sleep_until(max(t, clock.now()))
        sim.pending_bytes(clock.now())


def _run_until_rest(sim: StepperBenchSim, clock: VirtualClock, limit_s: float = 3600.0) -> None:
    for _ in range(1000):
        sim.pending_bytes(clock.now())
        if sim.state not in ("Run", "Jog") and not (sim.state == "Hold" and not sim.hold_complete) and sim._reset_until is None:
            return
        t = sim._next_event()
        if t is None or t - clock.now() > limit_s:
            return
        clock.sleep_until(max(t, clock.now() + 1e-6))


def _rest_steps_if_stopped_at(motion, t_c: float, axis: int) -> int:
    """Where (steps) a copy of ``motion`` comes to rest when told to stop at run time ``t_c``."""
    m = copy.deepcopy(motion)
    for _ in range(10000):
        if not m.running or m.t >= t_c:
            break
        m.advance(t_c)
    m.stop_smoothly()
    for _ in range(10000):
        if not m.running:
            break
        m.advance(m.t + 3600.0)
    return m.position_steps()[axis]


def _stop_time(sim: StepperBenchSim, host: bytes, rest_position: float) -> float | None:
    """When to apply a cancel, hold or reset so that the simulator ends where the firmware did:
    the earliest moment, found by bisection on a copy of the simulator's motion."""
    if host == b"\x18":
        return _first_time(sim, lambda x, v: x, _step_middle(sim, rest_position))
    if not sim.motion.blocks:
        return None
    target = round(rest_position * sim.motion.limits.steps_per_mm[sim.axis])
    segs = sim.motion.profile()
    return stop_moment(sim, sim.t, (segs[-1].t_s + segs[-1].duration_s) if segs else sim.t, target)


def stop_moment(sim: StepperBenchSim, lo: float, hi: float, target: int) -> float:
    """Within run times [lo, hi], the middle of the moments at which a cancel or hold makes the
    simulator's axis come to rest exactly on step ``target``."""
    axis = sim.axis
    direction = 1 if not sim.motion.blocks or sim.motion.blocks[0].unit[axis] >= 0 else -1
    rest = lambda t: direction * _rest_steps_if_stopped_at(sim.motion, t, axis)  # noqa: E731

    def first(level: int) -> float:  # earliest time whose rest reaches ``level`` (direction-signed)
        a, b = lo, hi
        if rest(a) >= level:
            return a
        for _ in range(60):
            mid = 0.5 * (a + b)
            a, b = (a, mid) if rest(mid) >= level else (mid, b)
        return b

    return 0.5 * (first(direction * target) + first(direction * target + 1))


def _next_rest_position(exs: list[Exchange], i: int) -> float | None:
    for ex in exs[i:]:
        for line in _lines(ex.firmware):
            m = REPORT.match(line.decode("ascii", "replace"))
            if m and m["state"] not in MOVING:
                return float(m["pos"].split(":")[1].split(",")[0])
    return None


def play(tr: Transcript, sim: StepperBenchSim | None = None, clock: VirtualClock | None = None) -> list[str]:
    """Differences between the transcript's firmware bytes and the simulator's (empty: passes)."""
    if sim is None:
        sim, clock = make_sim(tr)
    problems: list[str] = []
    boot, exs = exchanges(tr)
    got = sim.take_output(clock.now())
    if got != boot:
        problems.append(f"{tr.name}: boot: firmware {boot!r}, simulator {got!r}")
    for i, ex in enumerate(exs):
        expected = _lines(ex.firmware)
        moving = sim.state in ("Run", "Jog") or (sim.state == "Hold" and not sim.hold_complete)
        if ex.host == b"?" and expected:
            state_m = REPORT.match(expected[0].decode("ascii", "replace"))
            if state_m and state_m["state"] in MOVING:
                _run_until_at(sim, clock, _report_position(expected[0]))
            elif state_m:
                _run_until_rest(sim, clock)
        elif ex.host in STOPPING_BYTES and moving:
            rest = _next_rest_position(exs, i + 1)
            t = _stop_time(sim, ex.host, rest) if rest is not None else None
            if t is not None and t > clock.now():
                clock.sleep_until(t)
                sim.pending_bytes(t)
        m = sim.motion
        ramp = m.running and (m.stopping or m.stop_at is not None or abs(m.reported_speed() - m.speed) > 1e-6
                              or abs(m.speed - (m.blocks[0].nominal if m.blocks else 0.0)) > 1e-6)
        sim.receive(ex.host)
        out = sim.take_output(clock.now())
        for _ in range(50):  # answers that come later (a held line, ALARM's 500 ms, a full planner)
            if ex.host == b"?" or len(_lines(out)) >= len(expected):
                break
            t = sim.next_output_time()
            if t is None or t - clock.now() > 120.0:
                break
            clock.sleep_until(max(t, clock.now()))
            out += sim.take_output(clock.now())
        got_lines = _lines(out)
        if len(got_lines) != len(expected) or not all(same_line(e, g, ramp or sim.state == "Hold") for e, g in zip(expected, got_lines)):
            problems.append(f"{tr.name}: exchange {i} ({ex.host!r} at {tr.events and '':s}): firmware {ex.firmware!r}, simulator {out!r}")
    return problems


# ---- the driver against a scripted peer playing a transcript --------------------------------------
def transcript_port(exs: list[Exchange], baudrate: int = 115200) -> ExpectedExchangePort:
    """A pyserial-like port playing the firmware's side of a transcript (the scripted peer of
    tests/golden/expected_exchange.py): the host must write the transcript's host units in order;
    the firmware bytes after each become readable once it is written. Pushed lines the driver did
    not read before its next write (a ``[MSG:...]`` after the welcome) may stay unread, as they did."""
    return ExpectedExchangePort([(ex.host, ex.firmware or None) for ex in exs], baudrate=baudrate, unread_ok=True)


_JOG = re.compile(rb"^\$J=G91G21[XYZ](?P<dist>-?\d+\.\d+)F(?P<feed>\d+\.\d+)\n$")


def driver_calls(exs: list[Exchange], start_units: int) -> list[tuple]:
    """The driver calls that wrote the host units after :meth:`StepperBench.start`'s first
    ``start_units``: ``("monitor",)``, ``("set_rate", deg/s)``, ``("run",)``, ``("stop",)``,
    ``("safe_state",)``, told apart by the bytes (a jog line carries its rate)."""

    def rate_of(host: bytes) -> float:
        m = _JOG.match(host)
        return math.copysign(float(m["feed"]) / 60.0, float(m["dist"]))

    hosts = [ex.host for ex in exs]
    calls: list[tuple] = []
    turning = False
    i = start_units
    while i < len(hosts):
        h = hosts[i]
        if h == b"?":
            i += 1
            if not turning and i < len(hosts) and _JOG.match(hosts[i]):
                calls += [("set_rate", rate_of(hosts[i])), ("run",)]
                turning = True
            else:
                calls.append(("monitor",))
            while i < len(hosts) and _JOG.match(hosts[i]):
                i += 1
        elif h == b"\x85":
            i += 1
            while i < len(hosts) and hosts[i] == b"?":
                i += 1
            if i < len(hosts) and _JOG.match(hosts[i]):
                calls.append(("set_rate", rate_of(hosts[i])))
                while i < len(hosts) and _JOG.match(hosts[i]):
                    i += 1
            elif i < len(hosts) and hosts[i] == b"$G\n":
                calls.append(("safe_state",))
                turning = False
                i += 1
            else:
                calls.append(("stop",))
                turning = False
        else:
            raise AssertionError(f"host unit {i} {h!r} is no call of the driver's")
    return calls


def start_units(exs: list[Exchange]) -> int:
    """How many host units :meth:`StepperBench.start` wrote: up to and including ``$$``."""
    return next(k for k, ex in enumerate(exs) if ex.host == b"$$\n") + 1
