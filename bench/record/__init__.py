"""Run recording: one crash-safe HDF5 file per run (SWMR), and reading it back (see docs/run-file.md).

The file's layout (every path, attribute name, status value and event column) is defined once, in
:mod:`bench.record.layout`; the writer, the reader and every other module that opens run files
take the names from there.
"""

from bench.record import layout
from bench.record.destination import check_destination, run_file_name
from bench.record.layout import EVENT_DTYPE, EVENT_KINDS, FORMAT_VERSION
from bench.record.reader import (
    EventRow,
    InstrumentIdentity,
    RunSummary,
    StepSummary,
    StreamSummary,
    read_run_summary,
    read_stream,
    render_summary,
)
from bench.record.streams import Column
from bench.record.writer import RunRecorder

__all__ = [
    "EVENT_DTYPE",
    "EVENT_KINDS",
    "FORMAT_VERSION",
    "Column",
    "EventRow",
    "InstrumentIdentity",
    "RunRecorder",
    "RunSummary",
    "StepSummary",
    "StreamSummary",
    "check_destination",
    "layout",
    "read_run_summary",
    "read_stream",
    "render_summary",
    "run_file_name",
]
