"""The run-file layout has one definition, ``bench/record/layout.py``: everything the writer creates is
named there, the reader finds what the writer wrote through the same names, the committed sessions
match it, and no module that opens run files spells an HDF5 path or attribute name itself."""

from __future__ import annotations

import re
from datetime import datetime, timezone
from pathlib import Path

import h5py
import numpy as np
import pytest

from bench.errors import InputError
from bench.record import Column, RunRecorder, layout, read_run_summary, read_stream

ROOT = Path(__file__).resolve().parents[1]
SESSIONS = sorted((ROOT / "tests" / "sessions").glob("*.h5"))

BOARD = [Column("counter", "1", "u2"), Column("gyro", "deg/s", "f8", (3,))]
MONITOR = [Column("air_temp", "degC"), Column("pressure", "Torr")]
GAUGE = [Column("pressure", "Torr", "f4")]


def _write_run(runs: Path) -> tuple[Path, list[str]]:
    """A run with every kind of object: an instrument, an instrument's only stream, a monitor and a
    second named stream of one instrument, events with data, closed normally."""
    rec = RunRecorder.create(runs, procedure_name="layout", procedure_text="name: layout\n", procedure_path="p.yaml",
                             config_text="lab: sim\n", config_path="c.yaml", mode=layout.MODE_SIM, operator="tester",
                             software_version="0", started_utc=datetime(2026, 1, 2, 3, 4, 5, tzinfo=timezone.utc))
    rec.add_instrument("acs_board", {"vendor": "x", "serial": "1"})
    keys = [rec.add_stream("acs_board", BOARD, rate_hz=100.0),
            rec.add_stream("tvac", MONITOR, layout.MONITOR_STREAM, rate_hz=1.0),
            rec.add_stream("tvac", GAUGE, "gauge")]
    rec.event(layout.EVENT_RUN_START, "runner", "1 step", t_s=0.0)
    rec.start()
    rec.event(layout.EVENT_STEP_START, "wait", "soak", t_s=0.0, step=0)
    rec.append(keys[0], np.arange(5) / 100.0, counter=np.arange(5), gyro=np.zeros((5, 3)))
    rec.append(keys[1], np.array([0.0, 1.0]), air_temp=np.array([20.0, 21.0]), pressure=np.array([1e-5, 1e-6]))
    rec.append(keys[2], np.array([0.5]), pressure=np.array([1e-6], dtype=np.float32))
    rec.event("command", "acs_board", "START", t_s=0.5, step=0, data=b"\x01\x02")
    rec.event(layout.EVENT_STEP_END, "wait", "passed", t_s=1.0, step=0)
    rec.close(layout.STATUS_COMPLETED)
    return rec.path, keys


def _named_by_layout(f: h5py.File) -> dict[str, set[str]]:
    """Every object path of ``f`` that the layout names, with the attributes the layout allows on it.

    Stream groups are recognised as the layout defines them (a group under ``streams`` holding a
    ``time`` dataset, one or two levels down), their columns from their ``columns`` attribute."""
    text_attrs = {layout.ATTR_ENCODING, layout.ATTR_LENGTH_BYTES}
    named: dict[str, set[str]] = {
        layout.PROCEDURE: set(), layout.CONFIG: set(), layout.PROCEDURE_TEXT: text_attrs, layout.CONFIG_TEXT: text_attrs,
        layout.INSTRUMENTS: set(), layout.STREAMS: set(), layout.EVENTS: {layout.ATTR_UNITS},
        layout.EVENTS_BLOB: {layout.ATTR_UNITS}, layout.HEARTBEAT: {layout.ATTR_UNITS, layout.ATTR_FIELDS},
    }
    for name, g in f[layout.INSTRUMENTS].items():
        named[layout.instrument_path(name)] = set(g.attrs)  # identity strings: free-form by design
    for inst, g in f[layout.STREAMS].items():
        subs = [layout.stream_key(inst)] if layout.TIME in g else [layout.stream_key(inst, s) for s in g]
        if layout.TIME not in g:
            named[layout.stream_path(inst)] = set()
        for key in subs:
            group = f[layout.stream_path(key)]
            named[layout.stream_path(key)] = set(layout.STREAM_ATTRS)
            columns = str(group.attrs[layout.ATTR_COLUMNS]).split(layout.COLUMN_SEPARATOR)
            assert columns[0] == layout.TIME
            named[layout.column_path(key, layout.TIME)] = {layout.ATTR_UNITS, layout.ATTR_DESCRIPTION}
            for c in columns[1:]:
                named[layout.column_path(key, c)] = {layout.ATTR_UNITS}
    return named


def _assert_only_layout_names(f: h5py.File) -> None:
    named = _named_by_layout(f)
    present: list[str] = []
    f.visit(present.append)
    assert sorted(set(present) - set(named)) == [], "objects the layout does not name"
    assert sorted(set(named) - set(present)) == [], "objects the layout names but the file lacks"
    for path in present:
        extra = set(f[path].attrs) - named[path]
        assert not extra, f"attributes of /{path} the layout does not name: {sorted(extra)}"
    root_names = set(layout.ROOT_ATTRS) | set(layout.ROOT_ATTRS_AT_CLOSE) | set(layout.IDENTITY_ATTRS)  # identity: optional
    assert set(f.attrs) <= root_names, f"root attributes the layout does not name: {sorted(set(f.attrs) - root_names)}"
    assert set(layout.ROOT_ATTRS) <= set(f.attrs)
    assert f[layout.EVENTS].dtype == layout.EVENT_DTYPE
    assert f.attrs[layout.ATTR_FORMAT_VERSION] <= layout.FORMAT_VERSION


def test_every_object_and_attribute_the_writer_creates_is_named_by_the_layout(tmp_path: Path) -> None:
    path, keys = _write_run(tmp_path)
    with h5py.File(path, "r") as f:
        _assert_only_layout_names(f)
        assert set(f.attrs) == set(layout.ROOT_ATTRS) | set(layout.ROOT_ATTRS_AT_CLOSE)
        assert f.attrs[layout.ATTR_STATUS] == layout.STATUS_COMPLETED
        for key in keys:
            assert {layout.ATTR_ROWS, layout.ATTR_ROWS_APPENDED} <= set(f[layout.stream_path(key)].attrs)
        assert f[layout.HEARTBEAT].attrs[layout.ATTR_FIELDS] == ",".join(layout.HEARTBEAT_FIELDS)
    assert keys == ["acs_board", layout.monitor_key("tvac"), layout.stream_key("tvac", "gauge")]
    assert layout.monitor_path("tvac") == layout.stream_path(keys[1]) == "streams/tvac/monitor"


def test_reader_finds_what_the_writer_wrote_through_the_layout(tmp_path: Path) -> None:
    path, keys = _write_run(tmp_path)
    s = read_run_summary(path)
    assert sorted(st.key for st in s.streams) == sorted(keys)
    assert s.status == layout.STATUS_COMPLETED and s.attrs[layout.ATTR_MODE] == layout.MODE_SIM
    assert [(st.name, st.outcome) for st in s.steps] == [("soak", "passed")]
    assert s.instruments == {"acs_board": {"vendor": "x", "serial": "1"}}
    mon = read_stream(path, layout.monitor_key("tvac"))
    assert list(mon) == [layout.TIME, "air_temp", "pressure"]
    np.testing.assert_array_equal(mon[layout.TIME], [0.0, 1.0])


@pytest.mark.parametrize("required", layout.REQUIRED)
def test_reader_requires_exactly_the_layout_objects(tmp_path: Path, required: str) -> None:
    path, _keys = _write_run(tmp_path)
    with h5py.File(path, "r+") as f:
        del f[required]
    with pytest.raises(InputError, match=re.escape(f"{layout.absolute(required)} is missing")):
        read_run_summary(path)


@pytest.mark.parametrize("session", SESSIONS, ids=lambda p: p.stem)
def test_committed_sessions_match_the_layout(session: Path) -> None:
    with h5py.File(session, "r") as f:
        _assert_only_layout_names(f)


# Modules that open run files (they import h5py or bench.record) must take HDF5 names from the
# layout: a string literal as an attribute name, as the name of a created object, as a top-level
# path of the run file, or as a monitor stream key means a second definition of the layout.
_Q = "[\"']"
_LITERAL_ACCESS = [
    re.compile(rf"\.attrs(\[|\.get\()\s*{_Q}"),
    re.compile(rf"{_Q}\w+{_Q}\s+(not\s+)?in\s+[\w.]*\battrs\b"),
    re.compile(rf"\b(create_group|create_dataset|require_group)\(\s*{_Q}"),
    re.compile(rf"\[\s*{_Q}/?(procedure|config|streams|events|events_blob|heartbeat|instruments)(/[^\"']*)?{_Q}\s*\]"),
    re.compile(rf"{_Q}\w+/monitor{_Q}"),
]


def test_no_module_spells_run_file_names_itself() -> None:
    found = []
    for py in sorted((ROOT / "bench").rglob("*.py")):
        if py.name == "layout.py" and py.parent.name == "record":
            continue
        text = py.read_text(encoding="utf-8")
        if "h5py" not in text and "bench.record" not in text:
            continue
        for no, line in enumerate(text.splitlines(), 1):
            if any(p.search(line) for p in _LITERAL_ACCESS):
                found.append(f"{py.relative_to(ROOT)}:{no}: {line.strip()}")
    assert not found, "use the names of bench/record/layout.py:\n" + "\n".join(found)
