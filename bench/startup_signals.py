"""Terminating signals (SIGINT, SIGTERM, SIGHUP) while ``bench run`` starts up: one line, and no
half-made run file.

Until the runner's own handlers take over (operator stop → safe state), a first signal raises
:class:`StoppedDuringStartup` where the program is, except inside :meth:`StartupSignals.held`
blocks (creating or finalising the run file), where it is noted and raised by
:meth:`StartupSignals.raise_pending` after the block. Later signals are only noted: the clean-up
of the first one is not cut short. Light on purpose (``signal``, ``sys``, ``_thread`` only):
``bench`` installs it before importing anything else (``bench/__main__.py``).

A signal can land while Python runs a finaliser (a weakref callback, ``__del__``, an SQLAlchemy or
h5py clean-up run by the garbage collector). An exception raised there cannot leave it: Python prints
"Exception ignored in … Traceback" and drops it, and the stop would be lost. While installed, the
guard therefore also hooks :data:`sys.unraisablehook`: its own :class:`StoppedDuringStartup`
dropped by a finaliser is swallowed silently and the signal is sent again to the main thread
(:func:`signal.pthread_kill`, from a short-lived thread), so it is raised in the program itself a
moment later (also interrupting a blocking call) and ends as documented (one line, exit 1). Every other unraisable exception goes to the hook found at
install.
"""

from __future__ import annotations

import _thread
import signal
import sys
from contextlib import contextmanager
from types import FrameType
from typing import Any, Iterator

STOP_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT", "SIGALRM", "SIGUSR2", "SIGXCPU", "SIGXFSZ",
                                 "SIGVTALRM", "SIGPROF") if hasattr(signal, n))
"""The signals that stop a run: every signal whose default action terminates the process and that a
program may catch (SIGHUP: the terminal or ssh session closed; SIGQUIT: Ctrl-\\; SIGXCPU/SIGXFSZ: a
resource limit). SIGUSR1 and SIGTSTP pause instead; SIGPIPE is ignored by Python (a write raises);
SIGKILL cannot be caught (the run file is then left ``crashed``, readable)."""


class StoppedDuringStartup(KeyboardInterrupt):
    """A terminating signal arrived before the run started. ``run_file``: the run file the start-up
    finalised as aborted, or None when none had been created."""

    def __init__(self, signal_name: str):
        super().__init__(signal_name)
        self.signal_name = signal_name
        self.run_file: Any = None

    def __str__(self) -> str:
        if self.run_file is None:
            return f"stopped during start-up by {self.signal_name}; no run file was created"
        return f"stopped during start-up by {self.signal_name}; run file {self.run_file} closed with status aborted"


def stop_within(exc: BaseException | None) -> StoppedDuringStartup | None:
    """The :class:`StoppedDuringStartup` that ``exc`` is, or was raised from or during (its
    ``__cause__``/``__context__`` chain), or None. A library can turn the stop into its own error:
    a pybind11 extension (scipy, matplotlib) imported while the signal lands raises
    ``ImportError: initialization failed`` from it; such an error is the stop, not a failure."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, StoppedDuringStartup):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


class StartupSignals:
    """The start-up handler of :data:`STOP_SIGNALS`; see the module docstring. An instance that was
    never installed (a run started from a thread, ``bench soak``) never raises."""

    current: "StartupSignals | None" = None
    """The installed instance, if any (one per process)."""

    def __init__(self) -> None:
        self.signum: int | None = None
        """The first stop signal received, or None."""
        self._held = 0
        self._raised = False
        self._handed_over = False
        self._old: dict[int, Any] = {}
        self._old_unraisablehook: Any = None
        self._main_thread = 0

    @classmethod
    def install(cls) -> "StartupSignals":
        """Install the handler for :data:`STOP_SIGNALS` (main thread only), or return the instance
        already installed."""
        if cls.current is not None:
            return cls.current
        guard = cls()
        guard._old = {s: signal.signal(s, guard._handle) for s in STOP_SIGNALS}
        guard._main_thread = _thread.get_ident()
        guard._old_unraisablehook = sys.unraisablehook
        sys.unraisablehook = guard._unraisable
        cls.current = guard
        return guard

    def uninstall(self) -> None:
        """Put back the handlers found at :meth:`install` where this one is still installed; after a
        stop signal, ignore further ones instead (the process is on its way out, and a second
        Ctrl-C must not turn into a traceback during its last lines)."""
        for s, old in self._old.items():
            if signal.getsignal(s) == self._handle:
                signal.signal(s, signal.SIG_IGN if self.signum is not None else old)
        self._old = {}
        if self._old_unraisablehook is not None and sys.unraisablehook == self._unraisable:
            sys.unraisablehook = self._old_unraisablehook
        self._old_unraisablehook = None
        if StartupSignals.current is self:
            StartupSignals.current = None

    @property
    def received(self) -> str:
        """Name of the first stop signal received (``SIGTERM`` …), or ""."""
        return signal.Signals(self.signum).name if self.signum is not None else ""

    @contextmanager
    def held(self) -> Iterator[None]:
        """A block a signal must not cut (creating or finalising the run file): a signal inside it is
        noted; call :meth:`raise_pending` after it."""
        self._held += 1
        try:
            yield
        finally:
            self._held -= 1

    def raise_pending(self) -> None:
        """Raise :class:`StoppedDuringStartup` for a signal noted in a :meth:`held` block (once)."""
        if self.signum is not None and not self._raised and not self._handed_over:
            self._raised = True
            raise StoppedDuringStartup(self.received)

    def hand_over(self) -> None:
        """The run is built: from now on signals are only noted (:attr:`signum`), for the runner's
        handlers to take over and act on."""
        self._handed_over = True

    def _unraisable(self, unraisable: Any) -> None:
        """:data:`sys.unraisablehook` while installed: a :class:`StoppedDuringStartup` raised inside a
        finaliser (and dropped there by Python) is delivered again to the program; the rest goes to
        the previous hook."""
        if isinstance(unraisable.exc_value, StoppedDuringStartup) and self.signum is not None:
            self._raised = False
            # sent from another thread: sent from here, the handler would run at once, inside this hook
            _thread.start_new_thread(signal.pthread_kill, (self._main_thread, self.signum))
            return
        (self._old_unraisablehook or sys.__unraisablehook__)(unraisable)

    def _handle(self, signum: int, _frame: FrameType | None) -> None:
        if self.signum is None:
            self.signum = signum
        if not self._held:
            self.raise_pending()
