"""Terminal progress of a run (rich), laid out for the terminal's width (80 columns included):

* line 1: ``DRY-RUN`` (a simulated run) or ``PAUSED``, ``step n/N`` and the step's name, whole
  (it continues on the next line rather than being cut);
* line 2: the bar over the procedure's estimated run time, run time / estimate, and the wall time
  left;
* line 3: the latest readings, each with its units (``gyro +0.012 -0.004 +5.001 deg/s``), cut with
  "…" only at the end of the terminal line.

Messages (prompts, notices) print above it. Throttled to 10 updates per wall second.
"""

from __future__ import annotations

import time
from typing import Any

from rich.console import Console, Group, RenderableType
from rich.progress import Progress
from rich.text import Text

from bench.procedure import Procedure, Step
from bench.quantity_format import fmt_hms

UPDATE_PERIOD_WALL_S = 0.1
BAR_MIN = 10
"""Narrowest bar (characters); below it the bar is left out."""


class _Lines(Progress):
    """A rich ``Progress`` (live display, prints above it) that draws :meth:`RichProgress.view`."""

    def __init__(self, owner: "RichProgress", console: Console):
        self.owner = owner  # before rich's own set-up, which renders once already
        self._width_of = console
        super().__init__(console=console, transient=False)

    def get_renderables(self):  # noqa: ANN201 - rich's own signature
        yield self.owner.view(self._width_of.width)


class RichProgress:
    """Progress over the procedure's estimated run time (s), on the terminal while the run goes."""

    def __init__(self, console: Console, *, dry_run: bool = False):
        self.console = console
        self.dry_run = dry_run
        self._total = 0.0
        self._last = 0.0
        self._stepinfo = ""
        self._run_time = 0.0
        self._readings = ""
        self._started = 0.0
        self._run_time_at_start = 0.0
        self.paused = False
        """Set by ``bench run`` when the run is paused (Ctrl-Z): the first line says so."""
        self._progress = _Lines(self, console)

    def start(self, procedure: Procedure, total_s: float) -> None:
        self._total = max(total_s, 1e-9)
        self.console.print(f"[bold]{procedure.title}[/] ({procedure.path}), {len(procedure.steps)} steps, about {fmt_hms(total_s)} of procedure time")
        self._started = time.monotonic()
        self._progress.start()

    def step(self, n: int, total: int, step: Step) -> None:
        self._stepinfo = f"step {n}/{total} {step.name}"
        self._refresh(force=True)

    def advance(self, run_time_s: float, readings: str = "") -> None:
        self._run_time = float(run_time_s)
        if readings:
            self._readings = readings
        self._refresh()

    def _refresh(self, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self._last < UPDATE_PERIOD_WALL_S:
            return
        self._last = now
        self._progress.refresh()

    def message(self, text: str) -> None:
        self._progress.console.print(text)

    def stop(self, run_time_s: float) -> None:
        self._run_time = float(run_time_s)
        self._progress.refresh()
        self._progress.stop()

    # ---- the view ------------------------------------------------------------------------------
    def _wall_left_s(self) -> float | None:
        """Wall time (s) left at the pace so far; None before any progress."""
        done = min(self._run_time, self._total)
        elapsed = time.monotonic() - self._started
        if done <= 0 or elapsed <= 0:
            return None
        return (self._total - done) * elapsed / done

    def view(self, width: int) -> RenderableType:
        """The three lines for a terminal ``width`` characters wide."""
        head = Text(no_wrap=False, overflow="fold")
        if self.paused:
            head.append(" PAUSED ", style="bold black on yellow")
            head.append(" ")
        if self.dry_run:
            head.append(" DRY-RUN ", style="bold black on yellow")
            head.append(" ")
        head.append(self._stepinfo or "starting", style="bold")
        frac = min(1.0, max(0.0, self._run_time / self._total)) if self._total else 0.0
        clock = f" {fmt_hms(self._run_time)} / {fmt_hms(self._total)} run time"
        left = self._wall_left_s()
        if left is not None and frac < 1.0:
            clock += f", {fmt_hms(left)} left"
        bar_width = width - len(clock) - 2
        line2 = Text()
        if bar_width >= BAR_MIN:
            filled = int(round(frac * bar_width))
            line2.append("━" * filled, style="green" if not self.paused else "yellow")
            line2.append("━" * (bar_width - filled), style="grey23")
            line2.append(" ")
        line2.append(clock.strip() if bar_width < BAR_MIN else clock.lstrip())
        parts: list[Any] = [head, line2]
        if self._readings:
            parts.append(Text(self._readings, no_wrap=True, overflow="ellipsis", style="dim"))
        return Group(*parts)
