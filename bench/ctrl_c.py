"""Ctrl-C that a finaliser cannot swallow, for commands that loop until the user presses it.

Python turns SIGINT into :class:`KeyboardInterrupt` wherever the main thread is when the signal is
handled. If that is inside a finaliser (a weakref callback, ``__del__``, a clean-up the garbage
collector runs), the exception cannot leave it: Python prints "Exception ignored in …" and drops
it, and a loop that only ends on ``KeyboardInterrupt`` (``bench watch``) goes on as if Ctrl-C had
never been pressed. That is how ``tests/test_watch.py::test_ctrl_c_ends_the_live_view_quietly``
hung for its 180 s in CI (the interrupt landed in ``WeakValueDictionary``'s callback).

:func:`ctrl_c_noted` installs, for the duration of a ``with`` block, a SIGINT handler that notes
the press before raising ``KeyboardInterrupt`` as Python's own does: the loop checks
:attr:`CtrlC.pressed` once per turn, so a press that was swallowed ends it at the next turn; the
"Exception ignored" traceback Python would print for it is not printed (:data:`sys.unraisablehook`;
every other unraisable exception goes to the hook found on entry). It changes nothing where SIGINT is not Python's default handler (ignored in a background job, or a
handler of the caller's) or outside the main thread (only the main thread may set handlers).
"""

from __future__ import annotations

import signal
import sys
import threading
from contextlib import contextmanager
from types import FrameType
from typing import Any, Iterator


class CtrlC:
    """Whether Ctrl-C (SIGINT) was pressed inside a :func:`ctrl_c_noted` block."""

    def __init__(self) -> None:
        self.pressed = False
        self._old_unraisablehook = sys.unraisablehook

    def _handle(self, _signum: int, _frame: FrameType | None) -> None:
        self.pressed = True
        raise KeyboardInterrupt

    def _unraisable(self, unraisable: Any) -> None:
        """A finaliser dropped our ``KeyboardInterrupt``: already noted, nothing to print."""
        if self.pressed and isinstance(unraisable.exc_value, KeyboardInterrupt):
            return
        self._old_unraisablehook(unraisable)


@contextmanager
def ctrl_c_noted() -> Iterator[CtrlC]:
    """A block in which Ctrl-C raises ``KeyboardInterrupt`` as usual and is also noted in the
    yielded :class:`CtrlC` (``pressed``), so it is not lost when the interrupt is raised inside a
    finaliser. Python's default handler comes back after the block."""
    noted = CtrlC()
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield noted
        return
    signal.signal(signal.SIGINT, noted._handle)
    sys.unraisablehook = noted._unraisable
    try:
        yield noted
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        if sys.unraisablehook == noted._unraisable:
            sys.unraisablehook = noted._old_unraisablehook
