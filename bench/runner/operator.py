"""Where the operator's answers to prompts come from: a terminal, an answers file, or a dry-run.

Answers files (``--answers answers.yaml``) map prompt ids to answers, for CI and for runs where
nobody sits at the terminal::

    mount_unit: yes
    start_shaker_z: yes

Every answer must be one of the accepted answers (:data:`CHOICES`, with the synonyms of
:data:`AFFIRMATIVE` and :data:`NEGATIVE`); a file with another one is refused before the run.

At a terminal the question shows its accepted answers and what "no" does (``Close the door
[yes/no; no aborts the run]``); anything else is asked again by the prompt step
(``bench.runner.steps.prompt``) until the prompt's timeout: a typo never ends a run. A "no" typed by
a person is confirmed before the run aborts (:meth:`Operator.confirm_abort`: type ``abort``); from an
answers file it aborts at once, as declared. The terminal is read in ticks of :data:`ANSWER_TICK_S` of wall
time; between ticks a ``keepalive`` callback runs on the caller's thread, so the run keeps its
heartbeat (and, on the wall clock, the lab under watch) while the operator thinks. Every answer is
recorded in the run file with its source, so a replay can give the same ones.
"""

from __future__ import annotations

import os
import select
import sys
import time
from pathlib import Path
from typing import Callable, Protocol

from bench.errors import BenchError, InputError
from bench.yamlsrc import load_yaml

CHOICES = ("yes", "no")
"""The accepted answers, as a question shows them (``[yes/no]``)."""
AFFIRMATIVE = ("y", "yes", "ok", "done", "confirmed", "true")
"""Answers that confirm a prompt (case and surrounding white space ignored)."""
NEGATIVE = ("n", "no", "false")
"""Answers that decline a prompt (case and surrounding white space ignored): the run aborts."""
CONFIRM_ABORT = "abort"
"""What a person types to confirm that their "no" stops the run."""
ANSWER_TICK_S = 0.25
"""Wall time (s) between two looks at the terminal while waiting for an answer; the keepalive
runs this often (the run file's heartbeat needs one flush per second)."""
NON_INTERACTIVE_SOURCES = ("file", "dry-run")
"""Answer sources that would give the same answer again: an invalid one is not asked again."""


def answer_verdict(answer: str) -> str | None:
    """``"yes"`` (:data:`AFFIRMATIVE`), ``"no"`` (:data:`NEGATIVE`) or None: not an accepted answer."""
    a = answer.strip().lower()
    return "yes" if a in AFFIRMATIVE else ("no" if a in NEGATIVE else None)


def question(text: str, *, no_aborts: bool = False) -> str:
    """The question as shown and recorded: the text and its accepted answers, ``text [yes/no]``,
    and with ``no_aborts`` what "no" does: ``text [yes/no; no aborts the run]``."""
    return f"{text} [{'/'.join(CHOICES)}{'; no aborts the run' if no_aborts else ''}]"


def confirm_abort_question(key: str) -> str:
    """What a person who answered "no" at prompt ``key`` is asked before the run aborts."""
    return (f"'no' at {key!r} stops the run: the instruments go to their safe state and the run ends aborted. "
            f"Type '{CONFIRM_ABORT}' to stop it, anything else to answer the question again:")


def accepted_answers() -> str:
    """The accepted answers for messages: ``yes, no``."""
    return ", ".join(CHOICES)


class NoAnswer(BenchError):
    """Nobody answered: the prompt's time ran out (``timed_out``) or the terminal was closed."""

    def __init__(self, reason: str, timed_out: bool):
        super().__init__(reason)
        self.timed_out = timed_out


class Asker(Protocol):
    """A person who can be asked: shows a question, then gives the lines they type."""

    def show(self, text: str) -> None:
        """Show the question ``text`` (with its accepted answers)."""

    def read_line(self, timeout_s: float) -> str | None:
        """The next line typed (without its newline), None if none within ``timeout_s`` (s);
        raises ``EOFError`` once the input has ended."""


class LineReader:
    """Lines from a file descriptor (a terminal, a pipe), read without ever blocking longer than the
    timeout asked: ``select`` on the descriptor, then ``os.read`` of what is there."""

    def __init__(self, fd: int):
        self.fd = fd
        self._buf = b""
        self._eof = False

    def read_line(self, timeout_s: float) -> str | None:
        """See :meth:`Asker.read_line`; ``timeout_s`` in s of wall time."""
        deadline = time.monotonic() + max(0.0, timeout_s)
        while True:
            if b"\n" in self._buf:
                line, _, self._buf = self._buf.partition(b"\n")
                return line.decode("utf-8", errors="replace").rstrip("\r")
            if self._eof:
                if self._buf:
                    line, self._buf = self._buf, b""
                    return line.decode("utf-8", errors="replace")
                raise EOFError("end of input")
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            ready, _, _ = select.select([self.fd], [], [], remaining)
            if not ready:
                return None
            chunk = os.read(self.fd, 4096)
            if chunk:
                self._buf += chunk
            else:
                self._eof = True


class TerminalAsker(LineReader):
    """The operator at the controlling terminal: questions on stdout, answers from stdin."""

    def show(self, text: str) -> None:
        """Print the question on stdout (no newline: the answer is typed after it)."""
        sys.stdout.write(f"{text} ")
        sys.stdout.flush()


class Operator:
    """Answers prompts. ``answers``: id -> answer (from a file); ``ask``: a person who can be asked
    (an :class:`Asker`; None when nobody can be). A dry-run without either confirms automatically."""

    def __init__(self, answers: dict[str, str] | None = None, ask: Asker | None = None):
        self.answers = dict(answers or {})
        self._ask = ask

    @classmethod
    def from_file(cls, path: Path, ask: Asker | None = None) -> "Operator":
        """Read an answers file (a YAML mapping of prompt ids to answers); every problem, including
        an answer that is not accepted (:func:`answer_verdict`), is a located :class:`InputError`."""
        src = load_yaml(path, "answers file")
        if not isinstance(src.root.value, dict):
            raise InputError("expected a mapping of prompt ids to answers (e.g. 'mount_unit: yes')", src.root.location)
        answers = {}
        for key, node in src.root.value.items():
            v = node.value
            if isinstance(v, bool):
                v = "yes" if v else "no"
            if not isinstance(v, (str, int, float)) or answer_verdict(str(v)) is None:
                raise InputError(f"{v!r} is not an accepted answer (accepted: {accepted_answers()})", node.location, key)
            answers[key] = str(v)
        return cls(answers, ask)

    @staticmethod
    def terminal() -> TerminalAsker | None:
        """The operator at the controlling terminal, if stdin is one."""
        if not sys.stdin or not sys.stdin.isatty():
            return None
        return TerminalAsker(sys.stdin.fileno())

    last_person: str | None = None
    """Who gave the last answer, when the asker knows (a browser's operator field); else None: the
    run's operator."""

    def can_answer(self, key: str, simulated: bool) -> bool:
        return key in self.answers or self._ask is not None or simulated

    def ask(self, key: str, text: str, simulated: bool, *, keepalive: Callable[[], None] | None = None,
            deadline: float | None = None, show: Callable[[str], None] | None = None, no_aborts: bool = False) -> tuple[str, str]:
        """One answer to prompt ``key`` and its source: ``file``, ``operator`` or ``dry-run``.

        A person is shown :func:`question` ``(text, no_aborts=no_aborts)`` (through ``show`` if given, e.g. above a
        progress display) and read in ticks of :data:`ANSWER_TICK_S`; ``keepalive()`` runs after every
        tick without an answer (it may raise, e.g. to abort). ``deadline``: ``time.monotonic()`` value
        (s) after which :class:`NoAnswer` is raised; the end of the input raises it too. Raises
        :class:`InputError` when nobody can answer (no file entry, no terminal, not a dry-run).
        """
        if key in self.answers:
            return self.answers[key], "file"
        if self._ask is not None:
            (show or self._ask.show)(question(text, no_aborts=no_aborts))
            return self._read(keepalive, deadline), "operator"
        if simulated:
            return "yes", "dry-run"
        raise InputError(f"prompt {key!r} needs an answer: run on a terminal or give --answers FILE with '{key}: yes'", None, "--answers")

    def _read(self, keepalive: Callable[[], None] | None, deadline: float | None) -> str:
        """The person's next line, read in ticks of :data:`ANSWER_TICK_S` (``keepalive()`` between
        them) until ``deadline`` (:class:`NoAnswer` after it, or when the input ends)."""
        assert self._ask is not None
        while True:
            tick = ANSWER_TICK_S
            if deadline is not None:
                tick = min(tick, deadline - time.monotonic())
                if tick <= 0:
                    raise NoAnswer("no answer in time", timed_out=True)
            try:
                line = self._ask.read_line(tick)
            except EOFError:
                raise NoAnswer("the terminal's input ended", timed_out=False) from None
            if line is not None:
                return line.strip()
            if keepalive is not None:
                keepalive()

    def confirm_abort(self, key: str, *, keepalive: Callable[[], None] | None = None, deadline: float | None = None,
                      show: Callable[[str], None] | None = None) -> tuple[bool, str]:
        """Ask the person who answered "no" at prompt ``key`` whether the run really stops:
        ``(True, line)`` when they type :data:`CONFIRM_ABORT`, ``(False, line)`` for anything else
        (the question is asked again). Nobody to ask (an answers file, a dry-run): ``(True, "")``."""
        if self._ask is None:
            return True, ""
        (show or self._ask.show)(confirm_abort_question(key))
        line = self._read(keepalive, deadline)
        return line.strip().lower() == CONFIRM_ABORT, line
