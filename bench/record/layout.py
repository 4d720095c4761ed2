"""The run-file layout: the one definition of every HDF5 path, attribute name, status and mode
value, event column and stream name of a bench run file.

``docs/run-file.md`` describes the layout; this module is its source of truth. The writer
(:mod:`bench.record.writer` and the modules it is made of), the reader (:mod:`bench.record.reader`),
``bench watch``, ``bench replay`` and every other module that opens run files take the names from
here and never spell a path or attribute name themselves; ``tests/test_recorder.py`` checks that
every object and attribute the writer creates is named here.

Paths are relative to the file's root, as h5py takes them (``f[layout.STREAMS]``);
:func:`absolute` gives the ``/streams`` form used in messages. Stream keys are ``<instrument>`` or
``<instrument>/<stream>`` (:func:`stream_key`), the path of a stream ``streams/<key>``
(:func:`stream_path`).

Units of the values stored under these names: run times in s since the start of the run, wall times
in s since the Unix epoch, sizes and offsets in bytes, rates in Hz.
"""

from __future__ import annotations

from datetime import datetime, timezone

import numpy as np

FORMAT_VERSION = 1
"""Version of the run-file layout (root attribute :data:`ATTR_FORMAT_VERSION`). Additions old readers
can ignore keep it; changing or removing an item increments it. Readers refuse higher versions."""

# ---- objects under the root --------------------------------------------------------------------
PROCEDURE = "procedure"
"""Group holding the procedure text (dataset :data:`TEXT`)."""
CONFIG = "config"
"""Group holding the lab config text (dataset :data:`TEXT`)."""
TEXT = "text"
"""Name of the text dataset in :data:`PROCEDURE` and :data:`CONFIG`: one fixed-length utf-8 byte string."""
PROCEDURE_TEXT = f"{PROCEDURE}/{TEXT}"
CONFIG_TEXT = f"{CONFIG}/{TEXT}"
INSTRUMENTS = "instruments"
"""Group of one empty group per instrument, its attributes the identity strings (:func:`instrument_path`)."""
STREAMS = "streams"
"""Group of the recorded streams (:func:`stream_path`)."""
EVENTS = "events"
"""Compound dataset (n,) of :data:`EVENT_DTYPE`: the event log."""
EVENTS_BLOB = "events_blob"
"""uint8 dataset (m,): event messages (utf-8) and data bytes, addressed by the event rows."""
HEARTBEAT = "heartbeat"
"""float64 dataset (2,): :data:`HEARTBEAT_FIELDS` of the last flush."""

REQUIRED = (PROCEDURE_TEXT, CONFIG_TEXT, INSTRUMENTS, STREAMS, EVENTS, EVENTS_BLOB, HEARTBEAT)
"""Objects every run file has from its creation on; a file lacking one is not a run file."""

HEARTBEAT_FIELDS = ("wall_unix", "run_time_s")
"""Meaning of the two heartbeat values: wall time of the last flush (s since epoch), run time reached (s)."""

# ---- root attributes ----------------------------------------------------------------------------
ATTR_FORMAT_VERSION = "format_version"
ATTR_SOFTWARE_VERSION = "software_version"
ATTR_PROCEDURE_NAME = "procedure_name"
ATTR_PROCEDURE_PATH = "procedure_path"
ATTR_CONFIG_PATH = "config_path"
ATTR_OPERATOR = "operator"
ATTR_HOST = "host"
ATTR_MODE = "mode"
ATTR_STARTED_UTC = "started_utc"
"""ISO 8601 UTC, e.g. ``2026-11-23T01:02:03Z`` (:data:`UTC_FORMAT`)."""
ATTR_ENDED_UTC = "ended_utc"
"""ISO 8601 UTC; ``""`` until the file is closed."""
ATTR_STATUS = "status"
ATTR_ABORT_REASON = "abort_reason"
ATTR_ROWS_TOTAL = "rows_total"
"""Rows over all streams (int64), written when the file is closed."""
ATTR_DIGEST = "attrs_sha256"
"""``sha256:<hex>`` of every attribute and text of the file (:mod:`bench.record.digest`), written when
the file enters SWMR mode and again when it is finalised; absent in files of older versions."""

# unit under test and station (format 1 additions: absent in older files, read as "")
ATTR_UNIT_SERIAL = "unit_serial"
"""Serial number of the unit under test (``bench run --unit SN``); ``""`` when none was given."""
ATTR_UNIT_PART = "unit_part"
"""Part number of the unit under test (``--part``); ``""`` when not given."""
ATTR_UNIT_REVISION = "unit_revision"
"""Revision of the unit under test (``--revision``); ``""`` when not given."""
ATTR_STATION = "station"
"""Name of the test station (lab config ``station:``; default the host name)."""
ATTR_OPERATOR_ORIGIN = "operator_origin"
"""Where the operator's name came from: ``cli LOGIN@TTY`` or ``web ADDRESS`` (bench.operators); absent in
older files, read as ``""``."""
IDENTITY_ATTRS = (ATTR_UNIT_SERIAL, ATTR_UNIT_PART, ATTR_UNIT_REVISION, ATTR_STATION)
"""Optional root attributes naming what was tested where."""
CREATION_ATTRS = (*IDENTITY_ATTRS, ATTR_OPERATOR_ORIGIN)
"""Optional root attributes a run file may be created with (``RunRecorder.create(identity=...)``)."""

# identity of an instrument: attributes of /instruments/<name>. The instrument reports its own
# (``identify()``: vendor, model, serial, firmware ... free-form); the lab config's declarations sit
# next to them under their own names (format 1 additions: absent in older files, read as "")
ATTR_REPORTED_SERIAL = "serial"
"""Instrument attribute: the serial number the instrument reports."""
ATTR_REPORTED_FIRMWARE = "firmware"
"""Instrument attribute: the firmware the instrument reports."""
ATTR_CONFIG_SERIAL = "config_serial"
"""Instrument attribute: the serial number the lab config gives (``serial:``)."""
ATTR_CONFIG_FIRMWARE = "config_firmware"
"""Instrument attribute: the firmware the lab config expects (``firmware:``)."""
ATTR_CALIBRATION_DUE = "calibration_due"
"""Instrument attribute: the calibration due date the lab config gives (``calibration_due:``), ``YYYY-MM-DD`` (UTC)."""
INSTRUMENT_CONFIG_ATTRS = (ATTR_CONFIG_SERIAL, ATTR_CONFIG_FIRMWARE, ATTR_CALIBRATION_DUE)
"""Instrument attributes taken from the lab config; written only for what the config declares."""

ROOT_ATTRS = (
    ATTR_FORMAT_VERSION, ATTR_SOFTWARE_VERSION, ATTR_PROCEDURE_NAME, ATTR_PROCEDURE_PATH, ATTR_CONFIG_PATH,
    ATTR_OPERATOR, ATTR_HOST, ATTR_MODE, ATTR_STARTED_UTC, ATTR_ENDED_UTC, ATTR_STATUS, ATTR_ABORT_REASON,
)
"""Root attributes written when the file is created, in that order."""
ROOT_ATTRS_AT_CLOSE = (ATTR_ROWS_TOTAL, ATTR_ENDED_UTC, ATTR_ABORT_REASON, ATTR_STATUS, ATTR_DIGEST)
"""Root attributes (re)written when the file is closed, after SWMR mode ended (the digest is also
written when the file enters SWMR mode)."""

UTC_FORMAT = "%Y-%m-%dT%H:%M:%SZ"
"""``strftime`` format of :data:`ATTR_STARTED_UTC` and :data:`ATTR_ENDED_UTC`."""

MODE_SIM = "sim"
MODE_HARDWARE = "hardware"
MODE_REPLAY = "replay"
MODE_IMPORTED = "imported"
MODES = (MODE_SIM, MODE_HARDWARE, MODE_REPLAY, MODE_IMPORTED)
"""Values of :data:`ATTR_MODE`."""

STATUS_RUNNING = "running"
"""Status from creation until the file is closed (being written, or the writer died)."""
STATUS_COMPLETED = "completed"
STATUS_ABORTED = "aborted"
STATUS_FAILED = "failed"
STATUSES_FINAL = (STATUS_COMPLETED, STATUS_ABORTED, STATUS_FAILED)
"""Statuses the writer sets when it closes the file."""
STATUS_CRASHED = "crashed"
"""Never stored: the reader's name for a :data:`STATUS_RUNNING` file whose heartbeat is stale."""
STATUS_WAITING = "waiting"
"""Never stored: what ``bench inspect`` and ``bench watch`` show for a :data:`STATUS_RUNNING` file
with a fresh heartbeat whose last :data:`EVENT_PROMPT` has no answer yet (the run waits for the
operator; ``RunSummary.live_status``, while ``RunSummary.status`` stays ``running``)."""

# ---- attributes of datasets and groups ----------------------------------------------------------
ATTR_UNITS = "units"
"""Units of a dataset (pint syntax, ``1`` for dimensionless); free text on the event datasets."""
ATTR_DESCRIPTION = "description"
"""What a dataset holds, in words (the ``time`` column of a stream)."""
ATTR_FIELDS = "fields"
"""Comma-separated meaning of the values of :data:`HEARTBEAT` (:data:`HEARTBEAT_FIELDS`)."""
ATTR_ENCODING = "encoding"
"""Encoding of a text dataset, :data:`TEXT_ENCODING`."""
ATTR_LENGTH_BYTES = "length_bytes"
"""Length (bytes) of a text dataset's text; numpy drops trailing NULs, the reader pads back to it."""
TEXT_ENCODING = "utf-8"

# ---- streams ------------------------------------------------------------------------------------
TIME = "time"
"""Column (dataset) of every stream: float64 run time of each row, s. Reserved as a column name."""
TIME_UNITS = "s"
MONITOR_STREAM = "monitor"
"""Stream name of a polled instrument's readings (:func:`monitor_key`)."""
IMPORTED_STREAM = "imported"
"""Key of the one stream of a run file written by ``bench import`` (mode :data:`MODE_IMPORTED`)."""
COLUMN_SEPARATOR = ","
"""Separator of the column names in :data:`ATTR_COLUMNS`."""

ATTR_INSTRUMENT = "instrument"
"""Stream group attribute: the instrument name."""
ATTR_STREAM = "stream"
"""Stream group attribute: the stream name, ``""`` for an instrument's only stream."""
ATTR_COLUMNS = "columns"
"""Stream group attribute: column names in declaration order, :data:`TIME` first, comma-separated."""
ATTR_RATE_HZ_NOMINAL = "rate_hz_nominal"
"""Stream group attribute: the declared sample rate (Hz), when declared."""
ATTR_ROWS = "rows"
"""Stream group attribute written at close: rows present in every column."""
ATTR_ROWS_APPENDED = "rows_appended"
"""Stream group attribute written at close: rows the runner handed to the recorder."""

STREAM_ATTRS = (ATTR_INSTRUMENT, ATTR_STREAM, ATTR_COLUMNS, ATTR_RATE_HZ_NOMINAL, ATTR_ROWS, ATTR_ROWS_APPENDED)
"""Every attribute a stream group can carry."""


def stream_key(instrument: str, stream: str = "") -> str:
    """Key of a stream: ``instrument``, or ``instrument/stream`` when the instrument has several."""
    return f"{instrument}/{stream}" if stream else instrument


def split_stream_key(key: str) -> tuple[str, str]:
    """``(instrument, stream)`` of a stream key; ``stream`` is ``""`` for an instrument's only stream."""
    instrument, _, stream = key.partition("/")
    return instrument, stream


def monitor_key(instrument: str) -> str:
    """Key of a polled instrument's monitor stream, ``<instrument>/monitor``."""
    return stream_key(instrument, MONITOR_STREAM)


def stream_path(key: str) -> str:
    """Path of the group of stream ``key`` (:func:`stream_key`): ``streams/<key>``."""
    return f"{STREAMS}/{key}"


def monitor_path(instrument: str) -> str:
    """Path of a polled instrument's monitor stream: ``streams/<instrument>/monitor``."""
    return stream_path(monitor_key(instrument))


def column_path(key: str, column: str) -> str:
    """Path of one column dataset of stream ``key``: ``streams/<key>/<column>``."""
    return f"{stream_path(key)}/{column}"


def instrument_path(name: str) -> str:
    """Path of an instrument's identity group: ``instruments/<name>``."""
    return f"{INSTRUMENTS}/{name}"


def absolute(path: str) -> str:
    """``/path``: a path as messages and the docs write it."""
    return path if path.startswith("/") else f"/{path}"


# ---- events -------------------------------------------------------------------------------------
EVENT_DTYPE = np.dtype(
    [
        ("t_s", "<f8"),
        ("wall_unix", "<f8"),
        ("kind", "S16"),
        ("source", "S32"),
        ("step", "<i4"),
        ("msg_off", "<u8"),
        ("msg_len", "<u4"),
        ("data_off", "<u8"),
        ("data_len", "<u4"),
    ]
)
"""Row of :data:`EVENTS`: run time ``t_s`` (s), ``wall_unix`` (s since epoch), ``kind`` (ASCII),
``source`` (utf-8, cut), ``step`` (0-based, :data:`NO_STEP` outside steps), and the message and data
bytes as offset/length (bytes) into :data:`EVENTS_BLOB`."""
EVENT_FIELDS = tuple(EVENT_DTYPE.names or ())
EVENT_KIND_BYTES = EVENT_DTYPE["kind"].itemsize
"""Longest event kind (ASCII bytes)."""
EVENT_SOURCE_BYTES = EVENT_DTYPE["source"].itemsize
"""Longest event source (utf-8 bytes); longer ones are cut."""
NO_STEP = -1
"""``step`` of an event outside any step."""

EVENT_RUN_START = "run_start"
"""Start of the run; its message says how many steps the procedure has (``N steps``)."""
EVENT_STEP_START = "step_start"
"""A step starts: message the step name, source the step type."""
EVENT_STEP_END = "step_end"
"""A step ends: message ``outcome`` or ``outcome: detail``."""
EVENT_KINDS = (
    EVENT_RUN_START, EVENT_STEP_START, EVENT_STEP_END, "command", "reply", "stream",
    "error", "fault", "abort", "note", "safe_state", "run_end",
)
"""Event kinds written by the runner (others up to :data:`EVENT_KIND_BYTES` ASCII bytes are accepted)."""
STEP_EVENT_KINDS = (EVENT_RUN_START, EVENT_STEP_START, EVENT_STEP_END)
"""The events the step list is built from."""
TRAFFIC_EVENT_KINDS = ("command", "reply")
"""Instrument traffic: every frame sent (``command``) and received (``reply``), source the
instrument. Kept whole for replay; ``bench inspect`` and ``bench watch`` summarise it per
instrument and list the other ("meaningful") events."""
EVENT_PROMPT = "prompt"
"""The runner asks the operator: source ``operator``, message the question, data JSON ``id``,
``text``, ``choices`` (accepted answers), ``attempt`` (1, 2, ...), ``timeout_s`` (s of wall time).
Until the next ``operator`` event (the answer), a step end, ``abort`` or ``run_end``, the run waits
for the operator (:data:`STATUS_WAITING`)."""
PROMPT_CLOSING_KINDS = ("operator", EVENT_STEP_END, "abort", "run_end")
"""Events after which a :data:`EVENT_PROMPT` no longer waits."""
EVENT_CHECK = "check"
"""A check's result: source the check name, message ``outcome: statistic of signal = value``, data
JSON ``name``, ``signal``, ``statistic``, ``window``, ``value``, ``min``, ``max``, ``reference``,
``max_difference``, ``outcome``, ``basis``."""

OUTCOME_PASSED = "passed"
OUTCOME_FAILED = "failed"
OUTCOME_RECORDED = "recorded"
"""Outcome of a check without limits (no ``min``, ``max`` or ``max_difference``): its value is
stored, no verdict is given (neither passed nor failed)."""
CHECK_OUTCOMES = (OUTCOME_PASSED, OUTCOME_FAILED, OUTCOME_RECORDED)
"""Outcomes of a check step (first word of its ``step_end`` message and ``outcome`` of its event)."""
EVENT_CONFIG_SOURCES = "config_sources"
"""The files the lab config named and its loader read (sensor models, calibration files), logged
once when the run file is created (source ``runner``, message the config's name): data JSON
``path`` (the config's absolute path, its directory resolved) and ``sources`` (resolved absolute
path -> text), as the ``procedure`` event holds the procedure's. A replay reads them from here;
files written before it lack it."""
EVENT_OPERATOR = "operator"
"""An operator's answer; the message is a JSON object (a prompt step: source ``prompt``)."""
EVENT_CONTROL = "control"
"""An operator's control action taken from outside the runner's terminal (the web station): source
the origin (``web 127.0.0.1``), message JSON ``action`` (``pause``, ``resume``, ``stop``),
``origin``, ``message``. Not an answer: a prompt still waits after it."""
SOURCE_CALIBRATION = "calibration"
"""Source of the :data:`EVENT_OPERATOR` event confirming a run on an instrument past its calibration
due date; message JSON: ``instrument``, ``calibration_due``, ``date`` (UTC, of the run), ``answer``,
``source`` (``operator`` or ``--accept-overdue-calibration``), ``operator`` (who)."""


def utc_text(t: datetime) -> str:
    """``t`` as :data:`UTC_FORMAT` (a naive datetime is taken as UTC)."""
    return as_utc(t).strftime(UTC_FORMAT)


def as_utc(t: datetime) -> datetime:
    """``t`` in UTC; a naive datetime is taken as UTC."""
    return t.replace(tzinfo=timezone.utc) if t.tzinfo is None else t.astimezone(timezone.utc)
