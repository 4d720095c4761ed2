"""Run recording: one crash-safe HDF5 file per run (SWMR), and reading it back (see docs/run-file.md)."""

from bench.record.reader import (
    EventRow,
    RunSummary,
    StepSummary,
    StreamSummary,
    read_run_summary,
    read_stream,
    render_summary,
)
from bench.record.writer import (
    EVENT_DTYPE,
    EVENT_KINDS,
    FORMAT_VERSION,
    Column,
    RunRecorder,
    check_destination,
    run_file_name,
)

__all__ = [
    "EVENT_DTYPE",
    "EVENT_KINDS",
    "FORMAT_VERSION",
    "Column",
    "EventRow",
    "RunRecorder",
    "RunSummary",
    "StepSummary",
    "StreamSummary",
    "check_destination",
    "read_run_summary",
    "read_stream",
    "render_summary",
    "run_file_name",
]
