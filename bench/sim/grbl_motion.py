"""GRBL 1.1's motion planner and its execution, for the simulated stepper bench.

What gnea/grbl ``planner.c`` (``plan_buffer_line``, ``planner_recalculate``) and ``stepper.c`` do,
in continuous time: each motion is a block from the previous target to a new one, in whole steps
(``lround(target·steps/mm)``); its acceleration and top rate are the axes' ``$12x``/``$11x``
limited along its direction; its entry speed is limited by the junction with the block before
(junction deviation ``$11``; straight on: unlimited; reversed: zero) and by both blocks' nominal
speeds; the last block always plans to stop at its end, so motion ends in a stop when nothing
follows in time. Execution is trapezoidal: accelerate, cruise, decelerate to the next block's
entry speed. A feed hold or jog cancel decelerates at the block's acceleration until at rest
(across block ends if needed).

Units: mm (the bench's degrees), s, mm/s, mm/s²; rates given in mm/min are converted on entry.
The model is checked against the firmware's own step log (docs/golden/grbl-transcripts/profile-*).
GRBL executes step segments prepared ahead (5 of them, 10 ms each, longer at low step rates so
that each holds 1.25 steps): a hold or cancel starts decelerating only after them, and the rate it
reports (``FS:``) is the speed at the end of them; both are modelled (:meth:`Motion.lag_s`).
What it leaves out: AMASS and the step timer's integer periods (a rate error below 1e-4 at the
bench's step rates), arcs (G2/G3) and homing.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

N_AXIS = 3
BLOCK_BUFFER_SIZE = 16
"""grbl/planner.h: 16 blocks on a 328p, one of them always free: 15 usable (``[OPT:V,15,128]``)."""
PLANNER_BLOCKS = BLOCK_BUFFER_SIZE - 1
MINIMUM_FEED_RATE_MM_MIN = 1.0
"""grbl/config.h MINIMUM_FEED_RATE (mm/min)."""
MINIMUM_JUNCTION_SPEED_MM_MIN = 0.0
"""grbl/config.h MINIMUM_JUNCTION_SPEED (mm/min)."""
SEGMENT_BUFFER_SIZE = 6
"""grbl/stepper.h: step segments prepared ahead of the one executing (one slot stays free)."""
DT_SEGMENT_S = 0.01
"""stepper.c DT_SEGMENT: 1/ACCELERATION_TICKS_PER_SECOND (100) s per segment."""
REQ_MM_INCREMENT_SCALAR = 1.25
"""stepper.c: a segment holds at least 1.25 steps (longer segments at low step rates)."""
_EPS_MM = 1e-9
_EPS_V = 1e-9


@dataclass
class AxisLimits:
    """Per-axis settings the planner reads: steps/mm ($100-102), max rate mm/min ($110-112),
    acceleration mm/s² ($120-122); junction deviation mm ($11)."""

    steps_per_mm: tuple[float, float, float]
    max_rate_mm_min: tuple[float, float, float]
    accel_mm_s2: tuple[float, float, float]
    junction_deviation_mm: float


def _limit_by_axis_maximum(max_values: tuple[float, ...], unit: list[float]) -> float:
    """grbl planner.c limit_value_by_axis_maximum: the largest value along ``unit`` that keeps
    every axis within its own maximum."""
    limit = math.inf
    for m, u in zip(max_values, unit):
        if u != 0.0:
            limit = min(limit, abs(m / u))
    return limit


@dataclass
class Block:
    steps: tuple[int, int, int]
    """Signed step counts of the block per axis."""
    start_steps: tuple[int, int, int]
    millimeters: float
    unit: tuple[float, float, float]
    accel: float
    """mm/s²."""
    nominal: float
    """mm/s."""
    max_entry: float
    """mm/s: limit of the entry speed from the junction and the neighbours' nominal speeds."""
    jog: bool = False
    entry: float = 0.0
    """Planned entry speed (mm/s)."""
    done: float = 0.0
    """Distance executed (mm)."""

    def steps_at(self, distance_mm: float) -> list[int]:
        """Steps executed per axis after ``distance_mm`` of the block (whole steps, toward zero)."""
        frac = 1.0 if self.millimeters <= 0 else min(1.0, max(0.0, distance_mm / self.millimeters))
        return [s0 + int(math.copysign(math.floor(abs(n) * frac + 1e-9), n)) for s0, n in zip(self.start_steps, self.steps)]


@dataclass
class Segment:
    """A piece of the motion: from ``t_s`` on, velocity ``v`` (mm/s, along the axes as ``unit``)
    changing at ``a`` (mm/s²), for ``duration_s``."""

    t_s: float
    v: float
    a: float
    duration_s: float
    unit: tuple[float, float, float]


class Motion:
    """The planner's blocks and the motion executing them (one per simulated firmware)."""

    def __init__(self, limits: AxisLimits, t0: float = 0.0):
        self.limits = limits
        self.blocks: deque[Block] = deque()
        self.t = t0
        self.speed = 0.0
        """Current speed along the executing block (mm/s)."""
        self.steps = [0, 0, 0]
        """Machine position in steps (sys_position) at the start of the executing block."""
        self.plan_steps = [0, 0, 0]
        """The planner's position (pl.position): target of the last block, in steps."""
        self.prev_unit = [0.0, 0.0, 0.0]
        self.prev_nominal = 0.0
        self.stopping = False
        """Decelerating to rest for a feed hold or jog cancel."""
        self.stop_at: float | None = None
        """Run time the deceleration of a requested hold starts (after the prepared segments)."""
        self.running = False
        """Blocks are being executed (GRBL's cycle); False while idle or held."""

    # ---- planning ---------------------------------------------------------------------------
    def full(self) -> bool:
        return len(self.blocks) >= PLANNER_BLOCKS

    def target_steps(self, target_mm: list[float]) -> list[int]:
        return [int(math.floor(x * s + 0.5)) if x >= 0 else -int(math.floor(-x * s + 0.5))
                for x, s in zip(target_mm, self.limits.steps_per_mm)]

    def buffer_line(self, target_mm: list[float], feed_mm_min: float, *, rapid: bool = False, jog: bool = False) -> bool:
        """Plan a line to ``target_mm`` (machine mm); False when it has no step (an empty block)."""
        lim = self.limits
        target = self.target_steps(target_mm)
        delta_steps = [t - p for t, p in zip(target, self.plan_steps)]
        if not any(delta_steps):
            return False
        delta_mm = [d / s for d, s in zip(delta_steps, lim.steps_per_mm)]
        mm = math.sqrt(sum(d * d for d in delta_mm))
        unit = [d / mm for d in delta_mm]
        accel = _limit_by_axis_maximum(lim.accel_mm_s2, unit)
        rapid_rate = _limit_by_axis_maximum(lim.max_rate_mm_min, unit)
        rate = rapid_rate if rapid else min(feed_mm_min, rapid_rate)
        nominal = max(rate, MINIMUM_FEED_RATE_MM_MIN) / 60.0
        if not self.blocks:
            junction = 0.0
        else:
            cos_theta = -sum(p * u for p, u in zip(self.prev_unit, unit))
            if cos_theta > 0.999999:
                junction = MINIMUM_JUNCTION_SPEED_MM_MIN / 60.0
            elif cos_theta < -0.999999:
                junction = math.inf
            else:
                ju = [u - p for u, p in zip(unit, self.prev_unit)]
                n = math.sqrt(sum(x * x for x in ju))
                ju = [x / n for x in ju]
                j_accel = _limit_by_axis_maximum(lim.accel_mm_s2, ju)
                sin_half = math.sqrt(0.5 * (1.0 - cos_theta))
                junction = math.sqrt(max((MINIMUM_JUNCTION_SPEED_MM_MIN / 60.0) ** 2,
                                         j_accel * lim.junction_deviation_mm * sin_half / (1.0 - sin_half)))
        max_entry = min(junction, nominal, self.prev_nominal)
        self.blocks.append(Block(tuple(delta_steps), tuple(self.plan_steps), mm, tuple(unit), accel, nominal, max_entry, jog))
        self.prev_nominal = nominal
        self.prev_unit = unit
        self.plan_steps = target
        self._replan()
        return True

    def _replan(self) -> None:
        """Entry speeds: backward from a stop at the end of the last block, then forward from the
        speed the executing block has now."""
        blocks = list(self.blocks)
        if not blocks:
            return
        nxt = 0.0
        for b in reversed(blocks[1:]):
            b.entry = min(b.max_entry, math.sqrt(nxt * nxt + 2.0 * b.accel * b.millimeters))
            nxt = b.entry
        first = blocks[0]
        first.entry = self.speed
        prev_v, prev = self.speed, first
        remaining = first.millimeters - first.done
        for b in blocks[1:]:
            b.entry = min(b.entry, math.sqrt(prev_v * prev_v + 2.0 * prev.accel * remaining))
            prev_v, prev, remaining = b.entry, b, b.millimeters

    def sync_position(self) -> None:
        """After a jog cancel or reset: the planner starts from where the axes are."""
        self.plan_steps = list(self.position_steps())

    # ---- control ----------------------------------------------------------------------------
    def start(self, t_s: float) -> None:
        """Cycle start at run time ``t_s``: execute the queued blocks (from rest, or on from a
        completed hold)."""
        self.t = t_s
        if self.blocks:
            self.running = True
            self.stopping = False
            self.stop_at = None
            self._replan()

    def stop_smoothly(self) -> None:
        """Feed hold / jog cancel: decelerate to rest at the block's acceleration once the step
        segments already prepared have run (:meth:`lag_s`)."""
        if self.running and not self.stopping and self.stop_at is None:
            self.stop_at = self.t + self.lag_s()

    def segment_s(self, speed: float, accel: float = 0.0) -> float:
        """Duration of one step segment (s) at ``speed`` (mm/s) along the executing block, speeding
        up at ``accel`` (mm/s²): 10 ms, or as many 10 ms as it takes to hold 1.25 steps."""
        if not self.blocks:
            return DT_SEGMENT_S
        b = self.blocks[0]
        steps_per_mm = max(abs(u) * spm for u, spm in zip(b.unit, self.limits.steps_per_mm))
        d = REQ_MM_INCREMENT_SCALAR / steps_per_mm
        if accel > 0:
            need = (-speed + math.sqrt(speed * speed + 2.0 * accel * d)) / accel
        elif speed > _EPS_V:
            need = d / speed
        else:
            return DT_SEGMENT_S
        return DT_SEGMENT_S * max(1, math.ceil(need / DT_SEGMENT_S - 1e-9))

    def lag_s(self) -> float:
        """How far (s) the prepared step segments reach ahead of the executing one."""
        b = self.blocks[0] if self.blocks else None
        accelerating = b is not None and not self.stopping and self.speed < b.nominal - _EPS_V
        return self.lag_of_speed(self.speed, accelerating)

    def lag_of_speed(self, speed: float, accelerating: bool = False) -> float:
        accel = self.blocks[0].accel if (accelerating and self.blocks) else 0.0
        return (SEGMENT_BUFFER_SIZE - 1) * self.segment_s(speed, accel)

    def reported_speed(self) -> float:
        """The rate GRBL reports (stepper.c st_get_realtime_rate): the planned speed (mm/s) at the
        end of the prepared segments."""
        if not self.running or not self.blocks:
            return 0.0
        target = self.t + self.lag_s()
        with self._looking_ahead() as popped:
            for _ in range(10000):
                if not self.blocks or self.t >= target:
                    break
                b = self.blocks[0]
                a, dt = self._phase(b)
                if self.stopping and self.speed <= _EPS_V:
                    break
                if dt > target - self.t:
                    self._apply(b, a, target - self.t, full=False)
                    break
                if self._apply(b, a, dt):
                    popped.append(self.blocks.popleft())
                    self._replan_from_running()
            return self.speed if self.blocks else 0.0

    def flush(self) -> None:
        """Drop every queued block (jog cancel done, reset); the position stays where it is."""
        self.steps = self.position_steps()
        self.blocks.clear()
        self.speed = 0.0
        self.running = False
        self.stopping = False
        self.stop_at = None
        self.sync_position()

    def kill(self) -> None:
        """Reset: the steppers stop at once (position kept as counted: GRBL's ALARM:3 case)."""
        self.flush()

    # ---- execution --------------------------------------------------------------------------
    def _phase(self, b: Block) -> tuple[float, float]:
        """(acceleration mm/s², how long it lasts s) of the executing block from now on."""
        if self.stop_at is not None and not self.stopping:
            if self.t >= self.stop_at - 1e-12:
                self.stopping, self.stop_at = True, None
            else:
                a, dt = self._planned_phase(b)
                return a, min(dt, self.stop_at - self.t)
        return self._planned_phase(b)

    def _planned_phase(self, b: Block) -> tuple[float, float]:
        v, d = self.speed, b.millimeters - b.done
        if self.stopping:
            if v <= _EPS_V:
                return 0.0, 0.0
            t_stop = v / b.accel
            d_stop = v * t_stop - 0.5 * b.accel * t_stop * t_stop
            if d_stop <= d + _EPS_MM:
                return -b.accel, t_stop
            return -b.accel, _time_to_cover(v, -b.accel, d)
        nxt = self.blocks[1].entry if len(self.blocks) > 1 else 0.0
        ve = min(nxt, math.sqrt(v * v + 2.0 * b.accel * d))
        dec = max(0.0, (v * v - ve * ve) / (2.0 * b.accel))
        if d <= dec + _EPS_MM:
            return -b.accel, _time_to_cover(v, -b.accel, d)
        if v < b.nominal - _EPS_V:
            vp = min(b.nominal, math.sqrt((2.0 * b.accel * d + v * v + ve * ve) / 2.0))
            if vp - v <= _EPS_V:
                return -b.accel, _time_to_cover(v, -b.accel, d)
            return b.accel, (vp - v) / b.accel
        if v > b.nominal + _EPS_V:
            return -b.accel, (v - b.nominal) / b.accel
        cruise = d - (b.nominal ** 2 - ve * ve) / (2.0 * b.accel)
        return 0.0, max(0.0, cruise) / max(b.nominal, _EPS_V)

    def next_event_s(self) -> float | None:
        """Run time of the next block end or stop, None when nothing moves."""
        if not self.running or not self.blocks:
            return None
        saved = self._save()
        t = self.t
        try:
            for _ in range(10000):
                b = self.blocks[0]
                a, dt = self._phase(b)
                if self._apply(b, a, dt):
                    return self.t
                if self.stopping and self.speed <= _EPS_V:
                    return self.t
        finally:
            self._restore(saved)
        return t

    def advance(self, t_s: float) -> list[str]:
        """Execute until run time ``t_s`` or the first event, whichever is first; returns the
        events at :attr:`t` (``block`` done, ``stopped`` at rest after a hold or cancel,
        ``idle`` when the last block ended)."""
        events: list[str] = []
        for _ in range(100000):
            if not self.running or not self.blocks:
                break
            b = self.blocks[0]
            a, dt = self._phase(b)
            if self.stopping and self.speed <= _EPS_V:
                self.speed = 0.0
                self.running = False
                events.append("stopped")
                return events
            if self.t >= t_s and dt > 0:
                break
            dt_cap = min(dt, max(0.0, t_s - self.t))
            if self._apply(b, a, dt_cap, full=dt_cap >= dt):
                self.blocks.popleft()
                self.steps = list(b.steps_at(b.millimeters))
                events.append("block")
                if not self.blocks:
                    self.speed = 0.0
                    self.running = False
                    self.stopping = False
                    events.append("idle")
                else:
                    self._replan_from_running()
                return events
            if self.stopping and self.speed <= _EPS_V:
                self.speed = 0.0
                self.running = False
                events.append("stopped")
                return events
        self.t = max(self.t, t_s) if not self.running else self.t
        return events

    def _replan_from_running(self) -> None:
        if self.stopping:
            return
        self._replan()

    def _apply(self, b: Block, a: float, dt: float, full: bool = True) -> bool:
        """Move ``dt`` s at acceleration ``a`` along block ``b``; True when the block ended."""
        v0 = self.speed
        s = v0 * dt + 0.5 * a * dt * dt
        d = b.millimeters - b.done
        self.t += dt
        self.speed = max(0.0, v0 + a * dt)
        if s >= d - _EPS_MM or (full and not self.stopping and d - s <= 1e-7):
            b.done = b.millimeters
            return True
        b.done += max(0.0, s)
        return False

    @contextmanager
    def _looking_ahead(self) -> Iterator[list[Block]]:
        """Run the planner forward to look ahead, then put everything back: the caller appends the
        blocks it finishes to the yielded list; on exit they are queued again, the motion state is
        restored and the queue re-planned (unless stopping)."""
        saved = self._save()
        popped: list[Block] = []
        try:
            yield popped
        finally:
            for b in reversed(popped):
                self.blocks.appendleft(b)
            self._restore(saved)
            if not self.stopping:
                self._replan()

    def _save(self):
        return (self.t, self.speed, self.running, self.stopping, self.stop_at, [b.done for b in self.blocks])

    def _restore(self, saved) -> None:
        self.t, self.speed, self.running, self.stopping, self.stop_at, done = saved
        for b, d in zip(self.blocks, done):
            b.done = d

    # ---- reading ----------------------------------------------------------------------------
    def position_steps(self) -> list[int]:
        """Machine position in steps now (sys_position)."""
        if self.blocks and (self.running or self.blocks[0].done > 0):
            return self.blocks[0].steps_at(self.blocks[0].done)
        return list(self.steps)

    def position_mm(self) -> list[float]:
        """Machine position (mm) now, between steps (the stage's continuous angle)."""
        if self.blocks and (self.running or self.blocks[0].done > 0):
            b = self.blocks[0]
            return [s0 / spm + u * b.done for s0, spm, u in zip(b.start_steps, self.limits.steps_per_mm, b.unit)]
        return [s / spm for s, spm in zip(self.steps, self.limits.steps_per_mm)]

    def velocity(self) -> tuple[float, tuple[float, float, float]]:
        """Speed (mm/s) and direction of the executing block."""
        if self.running and self.blocks:
            return self.speed, self.blocks[0].unit
        return 0.0, (0.0, 0.0, 0.0)

    def profile(self) -> list[Segment]:
        """The motion from now on if nothing else is commanded: segments until at rest."""
        out: list[Segment] = []
        if not self.running or not self.blocks:
            return out
        with self._looking_ahead() as popped:
            for _ in range(10000):
                if not self.blocks:
                    break
                b = self.blocks[0]
                a, dt = self._phase(b)
                t0, v0 = self.t, self.speed
                ended = self._apply(b, a, dt)
                out.append(Segment(t0, v0, a, self.t - t0, b.unit))
                if ended:
                    popped.append(self.blocks.popleft())
                    if not self.blocks:
                        break
                    self._replan_from_running()
                elif self.stopping and self.speed <= _EPS_V:
                    break
        return out


def _time_to_cover(v: float, a: float, d: float) -> float:
    """Time to travel ``d`` from speed ``v`` at acceleration ``a`` (a < 0: until at rest at the latest)."""
    if d <= 0:
        return 0.0
    if a == 0:
        return d / v if v > 0 else math.inf
    disc = v * v + 2.0 * a * d
    if disc <= 0:
        return -v / a
    return (-v + math.sqrt(disc)) / a
