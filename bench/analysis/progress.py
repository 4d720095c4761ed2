"""Progress of long analyses on stderr (never stdout, which carries ``--json``).

``Progress`` is the ``progress`` callable the analyses take (``diagnose(..., progress=...)``): each
call says what is being done now. Nothing is printed during the first ``delay_s`` seconds (quick
analyses stay silent). On a terminal one line is rewritten in place (at most 10 times a second) and
erased at the end; otherwise (CI logs, pipes) a line is printed when the message changes, at most
once a second, and an unchanged message is repeated every 10 s. A background heartbeat keeps the
elapsed time going through phases that report nothing (reading a file, drawing the report)::

    with Progress("diagnose") as say:
        say("reading run.h5")
        ds = load_dataset(path)
        result = diagnose(ds, progress=say)
"""

from __future__ import annotations

import os
import sys
import threading
import time
from typing import Callable, Iterable, Iterator, TextIO, TypeVar

T = TypeVar("T")

DELAY_S = 2.0
"""Nothing is shown before an analysis has run this long (s)."""
TTY_INTERVAL_S = 0.1
"""Shortest interval between repaints of the terminal line (s)."""
LOG_INTERVAL_S = 1.0
"""Shortest interval between lines when stderr is not a terminal (s)."""
LOG_REPEAT_S = 10.0
"""An unchanged message is repeated this often when stderr is not a terminal (s)."""


class Progress:
    """A ``progress(message)`` sink for one analysis, printing ``"<label>: <message> (<elapsed> s)"``."""

    def __init__(self, label: str, stream: TextIO | None = None, *, tty: bool | None = None,
                 delay_s: float = DELAY_S, heartbeat: bool = True, clock: Callable[[], float] = time.monotonic):
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        if tty is None:
            try:
                tty = self.stream.isatty() and os.environ.get("TERM") != "dumb"
            except (AttributeError, ValueError):
                tty = False
        self.tty = bool(tty)
        self.delay_s = delay_s
        self.clock = clock
        self.start = clock()
        self.message = ""
        self._shown = ""
        self._last = -1e300
        self._dirty = False  # a terminal line is on screen
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if heartbeat:
            self._thread = threading.Thread(target=self._beat, name=f"progress-{label}", daemon=True)
            self._thread.start()

    def __call__(self, message: str) -> None:
        with self._lock:
            self.message = message
            if not self._stop.is_set():
                self._maybe_emit()

    def _maybe_emit(self) -> None:
        now = self.clock()
        if not self.message or now - self.start < self.delay_s:
            return
        if self.tty:
            if now - self._last < TTY_INTERVAL_S:
                return
        else:
            wait = LOG_INTERVAL_S if self.message != self._shown else LOG_REPEAT_S
            if now - self._last < wait:
                return
        self._last = now
        self._shown = self.message
        text = f"{self.label}: {self.message} ({now - self.start:.0f} s)"
        try:
            if self.tty:
                width = _columns()
                self.stream.write("\r" + text[: width - 1] + "\x1b[K")
                self._dirty = True
            else:
                self.stream.write(text + "\n")
            self.stream.flush()
        except (OSError, ValueError):  # a closed or broken stderr must not stop the analysis
            pass

    def _beat(self) -> None:
        interval = TTY_INTERVAL_S * 5 if self.tty else LOG_INTERVAL_S
        while not self._stop.wait(interval):
            self._tick()

    def _tick(self) -> None:
        """One heartbeat. Checked under the lock: once :meth:`close` has run, nothing more is
        written, even by a heartbeat thread that woke too late for ``close``'s join (a loaded
        machine), so the command's own last line (an error, a result) stays the last."""
        with self._lock:
            if not self._stop.is_set():
                self._maybe_emit()

    def close(self) -> None:
        """Stop the heartbeat and erase the terminal line (log lines stay)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        with self._lock:
            if self._dirty:
                try:
                    self.stream.write("\r\x1b[K")
                    self.stream.flush()
                except (OSError, ValueError):
                    pass
                self._dirty = False

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def each(items: Iterable[T], progress: Callable[[str], None] | None, what: str) -> Iterator[T]:
    """Iterate ``items``, telling ``progress`` "<what>: i/n" before each item (nothing when
    ``progress`` is None). For loops over candidates, grid values, methods."""
    seq = list(items)
    for i, item in enumerate(seq):
        if progress is not None:
            progress(f"{what}: {i}/{len(seq)} evaluated")
        yield item


def _columns() -> int:
    try:
        return max(os.get_terminal_size(sys.stderr.fileno()).columns, 20)
    except (OSError, ValueError, AttributeError):
        return 80
