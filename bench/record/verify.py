"""``bench inspect --verify``: check every chunk of a run file's streams and event log against its
Fletcher-32 checksum, and for chunks zeroed on disk (:mod:`bench.record.chunks`).

Each stream, ``/events`` and ``/events_blob`` is ``verified`` (every chunk checked and intact),
``failed`` (the row ranges of the damaged chunks, with their run times) or ``unverified`` (a
dataset without checksums: a file written before them). The attributes (status, procedure name,
start time, identities, units ...) and the procedure and config texts are checked against the
file's SHA-256 digest (:mod:`bench.record.digest`): a file without one (older versions) lists them
among what was not checked. The heartbeat carries no checksum and is listed as not checked. A file
shorter than HDF5 says (truncated) fails, whatever its chunks say.

Units: run times in s; rows of ``/events_blob`` are bytes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from bench.record import layout
from bench.record.chunks import BadChunk, ChunkMap, ExcludedRows, excluded_rows, find_damage, has_checksum
from bench.record.digest import check_digest
from bench.record.reader import _checked_rows, _column_order, _open_run, _size_limit, _stream_groups, event_datasets

VERIFIED, FAILED, UNVERIFIED = "verified", "failed", "unverified"


@dataclass
class PartCheck:
    """One stream (``kind`` ``stream``, ``name`` its key) or event dataset (``kind`` ``events``,
    ``name`` its path): ``rows`` (the most of any of its datasets; bytes for ``/events_blob``),
    ``chunks`` checked, datasets with a checksum out of ``datasets``, the damaged chunks and the
    row ranges they cover (``damage``)."""

    name: str
    kind: str
    rows: int
    chunks: int
    datasets: int
    checksummed: int
    bad: list[BadChunk] = field(default_factory=list)
    damage: list[ExcludedRows] = field(default_factory=list)

    @property
    def status(self) -> str:
        if self.bad:
            return FAILED
        return VERIFIED if self.checksummed == self.datasets else UNVERIFIED

    @property
    def unit(self) -> str:
        return "bytes" if self.name == layout.absolute(layout.EVENTS_BLOB) else "rows"


@dataclass
class FileCheck:
    """The verification of a whole run file: every part (:class:`PartCheck`), the datasets not
    checked (no chunks, no checksum) and the reader's warnings (a truncated file)."""

    path: Path
    parts: list[PartCheck]
    not_checked: list[str]
    warnings: list[str] = field(default_factory=list)
    attributes: str = "absent"
    """The attributes and texts against the file's digest: ``verified``, ``changed``, ``absent`` (no
    digest: an older file), or why they could not be read."""
    truncated: str = ""
    """Why the file is shorter than HDF5 says (a truncated file), else ``""``."""

    @property
    def status(self) -> str:
        """``failed`` if any chunk is damaged, the attributes changed or the file is truncated, else
        ``unverified`` if any part has no checksums, else ``verified``."""
        states = {p.status for p in self.parts}
        if FAILED in states or self.truncated or self.attributes not in ("verified", "absent"):
            return FAILED
        return UNVERIFIED if UNVERIFIED in states or not self.parts else VERIFIED

    @property
    def chunks(self) -> int:
        return sum(p.chunks for p in self.parts)

    @property
    def damaged_chunks(self) -> int:
        return sum(len(p.bad) for p in self.parts)


def verify_run_file(path: Path) -> FileCheck:
    """Read every chunk of every stream and of the event log of the run file at ``path``.
    Raises :class:`~bench.errors.InputError` when the file is not a readable run file (damaged
    metadata included)."""
    path = Path(path)
    with _open_run(path) as (f, warnings):
        try:
            attributes = check_digest(f)
        except Exception as exc:  # noqa: BLE001 - a damaged attribute makes h5py raise anything
            attributes = f"unreadable ({type(exc).__name__}: {exc})"
        limit = _size_limit(path)
        chunks = ChunkMap(f, path)
        groups = {key: {n: g[n] for n in _column_order(g)} for key, g in _stream_groups(f).items()}
        parts = [_check_part(key, "stream", datasets, limit, chunks) for key, datasets in groups.items()]
        events, blob = event_datasets(f)
        parts.append(_check_part(events.name, "events", {events.name: events}, limit, chunks, time_field="t_s"))
        parts.append(_check_part(blob.name, "events", {blob.name: blob}, limit, chunks))
        checked = {events.name, blob.name} | {ds.name for datasets in groups.values() for ds in datasets.values()}
        if attributes != "absent":
            checked |= {layout.absolute(layout.PROCEDURE_TEXT), layout.absolute(layout.CONFIG_TEXT)}
        rest: list[str] = [] if attributes != "absent" else ["the attributes (no digest: a file of an older bench)"]
        f.visititems(lambda _n, obj: rest.append(obj.name) if isinstance(obj, h5py.Dataset) and obj.name not in checked else None)
        truncated = next((w for w in warnings if "truncated" in w), "")
        return FileCheck(path, parts, sorted(rest), list(warnings), attributes, truncated)


def _check_part(name: str, kind: str, datasets: dict[str, h5py.Dataset], limit: int, chunks: ChunkMap,
                time_field: str | None = None) -> PartCheck:
    """Check every chunk of ``datasets`` (column -> dataset) of one stream or event dataset."""
    rows = {n: _checked_rows(ds, limit) for n, ds in datasets.items()}
    bad: list[BadChunk] = []
    times = None
    n_chunks = 0
    for n, ds in datasets.items():
        is_time = kind == "stream" and n == layout.TIME
        a, found = find_damage(ds, rows[n], chunks, is_time=is_time, keep=is_time or time_field is not None)
        bad += found
        if is_time:
            times = a
        elif time_field is not None and a is not None:
            times = np.asarray(a[time_field], dtype=np.float64)
        step = int(ds.chunks[0]) if ds.chunks is not None else max(rows[n], 1)
        n_chunks += -(-rows[n] // step)
    column = layout.TIME if kind == "stream" else name.rsplit("/", 1)[-1]
    return PartCheck(name, kind, max(rows.values(), default=0), n_chunks, len(datasets),
                     sum(has_checksum(ds) for ds in datasets.values()), bad, excluded_rows(name, bad, times, column))


def render_verification(check: FileCheck) -> list[str]:
    """The lines ``bench inspect --verify`` prints: a verdict, one line per stream and event
    dataset, each damaged range under its part, and the datasets not checked."""
    total = check.chunks
    if check.truncated:
        head = f"FAILED: the file is truncated ({check.damaged_chunks:,} of {total:,} chunks damaged)"
    elif check.status == FAILED and not check.damaged_chunks:
        head = "FAILED: the attributes or texts changed since they were written (their SHA-256 digest differs)"
    elif check.status == FAILED:
        head = f"FAILED: {check.damaged_chunks:,} of {total:,} chunks damaged"
    elif check.status == UNVERIFIED:
        plain = [p.name for p in check.parts if p.status == UNVERIFIED]
        head = (f"UNVERIFIED: {len(plain)} of {len(check.parts)} streams and event datasets have no checksums "
                "(written before checksums); their data cannot be verified")
    else:
        head = f"verified: all {total:,} chunks pass their Fletcher-32 checksums"
        if check.attributes == "verified":
            head += ", the attributes and texts their SHA-256 digest"
    lines = [f"{check.path}: {head}"]
    lines += [f"  warning: {w}" for w in check.warnings]
    label = "attributes and texts"
    width = max([len(_label(p)) for p in check.parts] + [len(label)])
    for p in check.parts:
        lines.append(f"  {_label(p):<{width}}  {p.rows:>12,} {p.unit:<5}  {p.chunks:>7,} chunks  {p.status.upper() if p.status == FAILED else p.status}")
        for d in p.damage:
            lines.append(f"      {d.rows_text(p.unit)}: {d.reason}")
    if check.attributes != "absent":
        shown = "CHANGED" if check.attributes == "changed" else check.attributes
        lines.append(f"  {label:<{width}}  {'':>12} {'':<5}  {'SHA-256':>14}  {shown}")
    if check.not_checked:
        lines.append(f"  not checked (not chunked, no checksum): {', '.join(check.not_checked)}")
    return lines


def _label(p: PartCheck) -> str:
    return f"stream {p.name}" if p.kind == "stream" else p.name


def verification_json(check: FileCheck) -> dict[str, Any]:
    """``bench inspect --verify --json``: the verdict and every part (fields in docs/run-file.md)."""
    from bench.record.summary_json import json_ready

    def part(p: PartCheck) -> dict[str, Any]:
        return {"name": p.name, "rows": p.rows, "chunks": p.chunks, "status": p.status, "damaged_chunks": len(p.bad),
                "damage": [{k: v for k, v in d.json().items() if k != "stream"} for d in p.damage]}

    return json_ready({
        "file": str(check.path),
        "status": check.status,
        "chunks": check.chunks,
        "damaged_chunks": check.damaged_chunks,
        "streams": [part(p) for p in check.parts if p.kind == "stream"],
        "events": [part(p) for p in check.parts if p.kind == "events"],
        "attributes": check.attributes,
        "truncated": check.truncated,
        "not_checked": check.not_checked,
        "warnings": check.warnings,
    })
