"""What a run's mode means for the people who read it: a dry-run or a replay is never acceptance
evidence, and every view says so at a glance.

A run file's ``mode`` attribute (``bench.record.layout.MODES``) is ``hardware`` (real instruments),
``sim`` (a dry-run: simulated instruments behind the same drivers), ``replay`` (a recorded run
re-executed against its recorded answers) or ``imported`` (measured data another program wrote).
Only a ``hardware`` run is evidence that a unit passed a test. ``bench run``'s summary, ``bench
runs``, ``bench inspect``, ``bench watch``, ``bench report``, the web station and ``bench unit`` all
take their words and banners from here, so they cannot drift apart.

Light on purpose (no imports): every layer may use it.
"""

from __future__ import annotations

HARDWARE = "hardware"
SIM = "sim"
REPLAY = "replay"
IMPORTED = "imported"
MODES = (HARDWARE, SIM, REPLAY, IMPORTED)
"""The run-file modes (as ``bench.record.layout.MODES``)."""

MODE_WORDS = {HARDWARE: "real", SIM: "DRY-RUN", REPLAY: "REPLAY", IMPORTED: "imported"}
"""The mode as a column shows it: short, and loud for what is not evidence."""

BANNERS = {
    SIM: "DRY-RUN: simulated instruments, not acceptance evidence",
    REPLAY: "REPLAY: a recorded run re-executed against its recorded answers, not acceptance evidence",
    IMPORTED: "IMPORTED: measured data written by another program, not a run of this station",
}
"""The banner at the top of every page, report and terminal view of a run that is not a run on
real instruments. A hardware run has none."""

FILTER_ALIASES = {"real": HARDWARE, "hardware": HARDWARE, "sim": SIM, "dry-run": SIM, "dryrun": SIM, "dry_run": SIM,
                  "simulated": SIM, "replay": REPLAY, "imported": IMPORTED}
"""What ``bench runs --mode`` and the web's mode filter accept, and the stored mode each means."""


def is_evidence(mode: str | None) -> bool:
    """Whether a run of ``mode`` can be acceptance evidence: only a run on real instruments."""
    return (mode or "") == HARDWARE


def mode_word(mode: str | None) -> str:
    """``real``, ``DRY-RUN``, ``REPLAY``, ``imported``; an unknown mode as it is (``?`` if empty)."""
    m = mode or ""
    return MODE_WORDS.get(m, m or "?")


def banner(mode: str | None) -> str:
    """The banner for a run of ``mode``: ``""`` for a hardware run, else one line saying what the
    run is and that it is not acceptance evidence (an unknown mode says that too)."""
    m = mode or ""
    if m == HARDWARE:
        return ""
    return BANNERS.get(m, f"mode {m or 'unknown'!s}: not a run on real instruments, not acceptance evidence")


def verdict_text(verdict: str | None, mode: str | None) -> str:
    """A verdict as lists show it: ``passed`` for a real run, ``passed (dry-run)`` for a dry-run,
    ``passed (replay)``…, so a simulated pass never reads like a real one; ``-`` without a verdict."""
    if not verdict:
        return "-"
    if is_evidence(mode):
        return verdict
    return f"{verdict} ({(mode_word(mode)).lower()})"


def parse_mode(value: str | None) -> str | None:
    """A mode filter (:data:`FILTER_ALIASES`) as the stored mode; None stays None. ``ValueError``
    with the accepted words for anything else (callers turn it into their located input error)."""
    if value is None or not value.strip():
        return None
    m = FILTER_ALIASES.get(value.strip().lower())
    if m is None:
        raise ValueError(f"expected one of real, dry-run, replay, imported (or hardware, sim), got {value!r}")
    return m
