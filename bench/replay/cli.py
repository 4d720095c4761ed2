"""``bench replay RUN.h5 [--procedure P.yaml] [--runs-dir DIR] [--no-board-check]``.

Wiring in ``bench/cli.py``: ``add_replay_parser(sub)`` in ``build_parser`` and
``if args.command == "replay": return cmd_replay(args, console)`` in ``main``.
Exit codes: 0 the replay matches, 1 it diverged (report of the first divergence and a count of
the rest), 2 the file cannot be replayed or ``--runs-dir`` cannot take the replay's file (one line).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from typing import TYPE_CHECKING

from bench.cli_common import epilog
from bench.errors import EXIT_FAILED, EXIT_OK

if TYPE_CHECKING:
    from rich.console import Console


def add_replay_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``bench replay`` to the CLI's subparsers."""
    rp = subparsers.add_parser(
        "replay", help="re-execute a recorded run against its recorded instrument answers and compare",
        description="Re-execute a recorded run (dry-run or hardware) with the same drivers against backends that "
                    "answer from the recording, and compare commands, step outcomes, checks and streams "
                    "(docs/replay.md); a dry-run's board samples are checked against a re-simulation. The texts "
                    "in the run file are read from a private temporary directory, never from the paths they "
                    "were recorded at. The replay is recorded too, to RUNS_DIR.",
        epilog=epilog("bench replay runs/20261123T101500Z_startup_profile.h5",
                      "bench replay RUN.h5 --procedure procedures/startup_profile.yaml --runs-dir /tmp/replays",
                      ok="the replay matches the recording",
                      failed="it diverged: the first divergence (step, instrument, expected vs got bytes) and a count of the rest",
                      bad="the file cannot be replayed (not a run file, no recorded exchanges, bad --procedure) or --runs-dir cannot take the replay's file: one line"))
    rp.add_argument("run_file", type=Path, help="run file (.h5) from bench run, with --sim or on hardware")
    rp.add_argument("--procedure", type=Path, default=None,
                    help="replay this procedure instead of the one stored in the run file (default: the stored one)")
    rp.add_argument("--runs-dir", type=Path, default=Path("runs"), help="where the replay's own run file goes (default: runs/)")
    rp.add_argument("--no-board-check", action="store_true",
                    help="do not re-simulate a dry-run's board samples to check the recorded ones (about twice as fast; "
                         "a board value changed in the file then goes unnoticed: the replay sends the board's recorded rows)")
    return rp


def cmd_replay(args: argparse.Namespace, console: Console) -> int:
    import logging

    from bench.record import check_destination
    from bench.replay.recording import load_recording

    logging.getLogger("canopen").setLevel(logging.CRITICAL)  # SDO aborts become typed errors in the report

    # a runs directory that cannot take the replay's file is bad input (exit 2), refused before
    # the replay, never a failed write mid-replay (exit 1 means "diverged"); the replay's file is
    # about the size of the recording
    check_destination(args.runs_dir, args.run_file.stat().st_size if args.run_file.is_file() else 0)
    rec = load_recording(args.run_file)  # a damaged file is refused before the runner and drivers are imported
    from bench.replay.run import replay

    result = replay(rec, args.procedure, args.runs_dir, check_board=not getattr(args, "no_board_check", False))
    console.print(result.report(), markup=False, highlight=False, soft_wrap=True)
    return EXIT_OK if result.ok else EXIT_FAILED
