"""What a replay takes from a recorded run file: the instrument conversation per link, the board's
data stream, the operator's answers, and the procedure and config that were in force.

Commands and replies are grouped into :class:`Exchange` objects (one command and the replies that
followed it on the same link, until the next command of that link), indexed once per link, so a
backend answers a request by popping the next exchange: no searching during the replay.
"""

from __future__ import annotations

import hashlib
import json
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np
import yaml

from bench.errors import InputError
from bench.record import layout, read_run_summary, read_stream
from bench.record.reader import EventRow, RunSummary

MODBUS_RE = re.compile(r"^(read|write) \d+")
"""Event names of the chamber's Modbus controller; every other ``tvac`` event is its serial gauge."""

REPLAY_NEEDS = "the run's parameters and sub-procedures ('procedure' event)"


@dataclass
class Exchange:
    """One recorded command and the replies that followed it on its link."""

    t_s: float
    step: int
    name: str
    data: bytes
    replies: list[tuple[float, str, bytes]] = field(default_factory=list)


def link_of(driver: str, message: str) -> str:
    """Which link of an instrument an event belongs to: ``controller`` / ``gauge`` for the chamber
    (told apart by the event names: Modbus events are ``read N`` / ``write N``), ``""`` otherwise."""
    if driver == "tvac":
        return "controller" if MODBUS_RE.match(message) else "gauge"
    return ""


@dataclass
class Recording:
    """A source run file, read once."""

    path: Path
    summary: RunSummary
    sha256: str
    mode: str
    status: str
    parameters: dict
    sources: dict[str, str]
    answers: list[tuple[str, str, str]]
    """(prompt id, answer, source) in the order asked."""
    prelude_recorded: bool
    """Whether the traffic of opening the instruments is in the file (a ``lab_open`` event marks its end)."""
    end_t_s: float
    clock: str = "virtual"
    """``virtual`` (a dry-run: command times are reproducible and compared) or ``wall`` (hardware or
    ``--realtime``: commands are compared in order only)."""

    def links(self, drivers: dict[str, str]) -> dict[tuple[str, str], list[Exchange]]:
        """(instrument, link) -> exchanges in order. ``drivers``: instrument -> driver name."""
        out: dict[tuple[str, str], list[Exchange]] = {}
        for e in self.summary.events:
            if e.kind not in ("command", "reply") or e.source not in drivers:
                continue
            key = (e.source, link_of(drivers[e.source], e.message))
            seq = out.setdefault(key, [])
            if e.kind == "command":
                seq.append(Exchange(e.t_s, e.step, e.message, e.data))
            elif seq:
                seq[-1].replies.append((e.t_s, e.message, e.data))
        return out

    def stream(self, key: str) -> dict[str, np.ndarray] | None:
        if key not in {s.key for s in self.summary.streams}:
            return None
        return read_stream(self.path, key)


def load_recording(path: Path) -> Recording:
    """Read ``path`` for a replay. :class:`InputError` (one line) when it is not a run file, is of
    another format version, or lacks what a replay needs."""
    path = Path(path)
    _check_version(path)
    summary = read_run_summary(path)
    proc = [e for e in summary.events if e.kind == "procedure"]
    if not proc:
        raise InputError(f"{path}: cannot be replayed: it was recorded by an older bench "
                         f"({summary.attrs.get(layout.ATTR_SOFTWARE_VERSION, '?')}) without {REPLAY_NEEDS}; record it again")
    try:
        info = json.loads(proc[0].data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: cannot be replayed: unreadable 'procedure' event ({exc})") from None
    answers = []
    for e in summary.events:
        if e.kind == "operator":
            try:
                a = json.loads(e.message)
                answers.append((str(a["id"]), str(a["answer"]), str(a.get("source", "file"))))
            except (json.JSONDecodeError, KeyError, TypeError):
                continue
    end = max((e.t_s for e in summary.events), default=0.0)
    return Recording(
        path=path, summary=summary, sha256=file_sha256(path), mode=str(summary.attrs.get(layout.ATTR_MODE, "")), status=summary.status,
        parameters=dict(info.get("parameters") or {}), sources=dict(info.get("sources") or {}), answers=answers,
        prelude_recorded=any(e.kind == "lab_open" for e in summary.events), end_t_s=end,
        clock=str(info.get("clock") or ("wall" if summary.attrs.get(layout.ATTR_MODE) == layout.MODE_HARDWARE else "virtual")),
    )


def _check_version(path: Path) -> None:
    if not path.is_file():
        raise InputError(f"{path}: no such run file")
    try:
        with h5py.File(path, "r", locking=False) as f:
            version = f.attrs.get(layout.ATTR_FORMAT_VERSION)
    except OSError:
        try:  # a crashed SWMR file
            with h5py.File(path, "r", swmr=True, locking=False) as f:
                version = f.attrs.get(layout.ATTR_FORMAT_VERSION)
        except Exception:  # noqa: BLE001 - the reader gives the precise reason below
            return
    except Exception:  # noqa: BLE001
        return
    if version is None:
        return  # read_run_summary says "not written by bench"
    v = int(np.asarray(version).item())
    if v < layout.FORMAT_VERSION:
        raise InputError(f"{path}: run file {layout.ATTR_FORMAT_VERSION} {v} is older than bench replay reads ({layout.FORMAT_VERSION}); "
                         f"replay it with the bench version that recorded it, or record it again")


def file_sha256(path: Path) -> str:
    """Hex SHA-256 of a file's bytes (read in 1 MiB blocks)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def materialise_config(rec: Recording, workdir: Path) -> Path:
    """The recorded config text as a file the config loader reads: the original file when it still
    holds the same text, else a copy in ``workdir`` with the relative files it names (sensor
    models) linked from the original config's directory."""
    text = rec.summary.config_text
    orig = Path(str(rec.summary.attrs.get(layout.ATTR_CONFIG_PATH, "")))
    if orig.is_file() and orig.read_text(encoding="utf-8") == text:
        return orig
    out = workdir / (orig.name or "config.yaml")
    out.write_text(text, encoding="utf-8")
    try:
        doc = yaml.safe_load(text) or {}
    except yaml.YAMLError:
        return out  # the loader reports it, located
    for inst in (doc.get("instruments") or {}).values() if isinstance(doc, dict) else []:
        rel = ((inst or {}).get("sim") or {}).get("sensor_model") if isinstance(inst, dict) else None
        if isinstance(rel, str) and not Path(rel).is_absolute():
            src = (orig.parent / rel)
            dst = workdir / rel
            if src.exists() and not dst.exists():
                dst.parent.mkdir(parents=True, exist_ok=True)
                dst.symlink_to(src.resolve())
    return out


def new_workdir() -> tempfile.TemporaryDirectory:
    return tempfile.TemporaryDirectory(prefix="bench-replay-")


def param_overrides(rec: Recording, default_params: dict) -> dict[str, str]:
    """``-p`` overrides that reproduce the recorded parameters: those whose recorded value differs
    from the stored procedure's default (so a ``--procedure`` copy keeps its own defaults)."""
    out = {}
    for k, v in rec.parameters.items():
        if k in default_params and _same(default_params[k], v):
            continue
        out[k] = json.dumps(v)
    return out


def _same(a, b) -> bool:
    return json.dumps(a, default=str, sort_keys=True) == json.dumps(b, default=str, sort_keys=True)


def event_rows(summary: RunSummary, kinds: tuple[str, ...]) -> list[EventRow]:
    return [e for e in summary.events if e.kind in kinds]
