"""Where the operator's answers to prompts come from: a terminal, an answers file, or a dry-run.

Answers files (``--answers answers.yaml``) map prompt ids to answers, for CI and for runs where
nobody sits at the terminal::

    mount_unit: yes
    start_shaker_z: yes

Every answer is recorded in the run file with its source, so a replay can give the same ones.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Callable

from bench.errors import InputError
from bench.yamlsrc import load_yaml


class Operator:
    """Answers prompts. ``answers``: id -> answer (from a file); ``ask``: a function that asks a
    person (None when nobody can be asked). A dry-run without either confirms automatically."""

    def __init__(self, answers: dict[str, str] | None = None, ask: Callable[[str], str] | None = None):
        self.answers = dict(answers or {})
        self._ask = ask

    @classmethod
    def from_file(cls, path: Path, ask: Callable[[str], str] | None = None) -> "Operator":
        """Read an answers file (a YAML mapping of prompt ids to answers); located errors."""
        src = load_yaml(path, "answers file")
        if not isinstance(src.root.value, dict):
            raise InputError("expected a mapping of prompt ids to answers (e.g. 'mount_unit: yes')", src.root.location)
        answers = {}
        for key, node in src.root.value.items():
            v = node.value
            if isinstance(v, bool):
                v = "yes" if v else "no"
            if not isinstance(v, (str, int, float)):
                raise InputError("expected an answer such as yes or no", node.location, key)
            answers[key] = str(v)
        return cls(answers, ask)

    @staticmethod
    def terminal() -> Callable[[str], str] | None:
        """A prompt on the controlling terminal, if stdin is one."""
        if not sys.stdin or not sys.stdin.isatty():
            return None
        return lambda text: input(f"{text} [yes/no] ")

    def can_answer(self, key: str, simulated: bool) -> bool:
        return key in self.answers or self._ask is not None or simulated

    def ask(self, key: str, text: str, simulated: bool) -> tuple[str, str]:
        """(answer, source): source is ``file``, ``operator`` or ``dry-run``."""
        if key in self.answers:
            return self.answers[key], "file"
        if self._ask is not None:
            try:
                return self._ask(text).strip() or "no", "operator"
            except EOFError:
                return "no", "operator (end of input)"
        if simulated:
            return "yes", "dry-run"
        raise InputError(f"prompt {key!r} needs an answer: run on a terminal or give --answers FILE with '{key}: yes'", None, "--answers")
