"""Terminal progress of a run (rich): step n/N, current step, run time, ETA, key readings."""

from __future__ import annotations

import time

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

from bench.procedure import Procedure, Step

UPDATE_PERIOD_WALL_S = 0.1


def _fmt_s(seconds: float) -> str:
    seconds = max(0.0, seconds)
    h, rem = divmod(int(round(seconds)), 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}"


class RichProgress:
    """Progress bar over the procedure's estimated run time; throttled to 10 updates per wall second."""

    def __init__(self, console: Console):
        self.console = console
        self._progress = Progress(
            TextColumn("[bold]{task.fields[stepinfo]}"),
            BarColumn(),
            TextColumn("{task.fields[clock]}"),
            TimeRemainingColumn(),
            TextColumn("{task.fields[readings]}"),
            console=console,
            transient=False,
        )
        self._task = None
        self._total = 0.0
        self._last = 0.0
        self._stepinfo = ""

    def start(self, procedure: Procedure, total_s: float) -> None:
        self._total = max(total_s, 1e-9)
        self.console.print(f"[bold]{procedure.title}[/] ({procedure.path}), {len(procedure.steps)} steps, about {_fmt_s(total_s)} of procedure time")
        self._progress.start()
        self._task = self._progress.add_task("run", total=self._total, stepinfo="", clock="", readings="")

    def step(self, n: int, total: int, step: Step) -> None:
        self._stepinfo = f"step {n}/{total} {step.name}"
        self._update(None, "", force=True)

    def advance(self, run_time_s: float, readings: str = "") -> None:
        self._update(run_time_s, readings)

    def _update(self, run_time_s: float | None, readings: str, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self._last < UPDATE_PERIOD_WALL_S:
            return
        self._last = now
        fields = {"stepinfo": self._stepinfo}
        if run_time_s is not None:
            fields["clock"] = f"{_fmt_s(run_time_s)} / {_fmt_s(self._total)}"
            fields["readings"] = readings
            self._progress.update(self._task, completed=min(run_time_s, self._total), **fields)
        else:
            self._progress.update(self._task, **fields)

    def message(self, text: str) -> None:
        self._progress.console.print(text)

    def stop(self, run_time_s: float) -> None:
        if self._task is not None:
            self._update(run_time_s, "", force=True)
        self._progress.stop()
