"""What a replay takes from a recorded run file: the instrument conversation per link, the board's
data stream, the operator's answers, and the procedure and config that were in force.

Commands and replies are grouped into :class:`Exchange` objects (one command and the replies that
followed it on the same link, until the next command of that link), indexed once per link, so a
backend answers a request by popping the next exchange: no searching during the replay.

Names and paths in the file are data: :func:`load_recording` checks them (plain instrument and
stream names, recorded paths of plain components), and :func:`procedure_file` /
:func:`config_file` write the recorded texts into the replay's private directory
(:mod:`bench.replay.workspace`), from where the loaders read them.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import re
import threading
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Callable

import numpy as np

from bench.errors import InputError
from bench.kinds import registry
from bench.inputs import CONFIG_ROOTS, YAML_LIMIT_BYTES, confined_path, read_input_bytes
from bench.record import layout, read_stream
from bench.record.reader import EventRow, RunSummary, Traffic, read_format_version, read_summary_and_traffic
from bench.replay.workspace import Workspace, checked_path, shown
from bench.yamlsrc import parse_yaml


@functools.lru_cache(maxsize=None)
def _link_patterns(driver: str) -> tuple[tuple[str, re.Pattern[str]], ...]:
    """The links of an instrument of kind ``driver`` reached over several (``Kind.links``: name and
    the regex of its recorded event names, the last one the default); empty for one link."""
    kind = registry.get(driver)
    return tuple((name, re.compile(rx)) for name, rx in kind.links) if kind is not None else ()

REPLAY_NEEDS = "the run's parameters and sub-procedures ('procedure' event)"


@dataclass(slots=True)
class Exchange:
    """One recorded command and the replies that followed it on its link."""

    t_s: float
    step: int
    name: str
    data: bytes
    replies: list[tuple[float, str, bytes]] = field(default_factory=list)


def link_keys(traffic: Traffic, drivers: dict[str, str]) -> list[tuple[str, str] | None]:
    """The (instrument, link) of every traffic event (:func:`link_of`), None for an instrument not
    in ``drivers`` (instrument -> driver name); worked out once per distinct (instrument, message)."""
    one_link = {s: (s, "") for s in set(traffic.source) if s in drivers and not _link_patterns(drivers[s])}  # link_of is "" for them
    known: dict[tuple[str, str], tuple[str, str] | None] = {}
    out = []
    for source, message in zip(traffic.source, traffic.message):
        key = one_link.get(source)
        if key is None:
            key = known.get((source, message), False)
            if key is False:
                key = known[(source, message)] = (source, link_of(drivers[source], message)) if source in drivers else None
        out.append(key)
    return out


def link_of(driver: str, message: str) -> str:
    """Which link of an instrument an event belongs to (its kind's ``links``: the chamber's Modbus
    ``controller`` events are ``read N`` / ``write N``, the rest is its ``gauge``); ``""`` for an
    instrument on one link."""
    patterns = _link_patterns(driver)
    for name, rx in patterns[:-1]:
        if rx.match(message):
            return name
    return patterns[-1][0] if patterns else ""


@dataclass
class Recording:
    """A source run file, read once."""

    path: Path
    summary: RunSummary
    """The file's summary; its ``events`` without the traffic (that is :attr:`traffic`)."""
    traffic: Traffic
    """Every command and reply, column-wise."""
    digest: Callable[[], str]
    """The file's SHA-256 (hex), hashed in a thread while the rest is read (:func:`file_sha256_soon`)."""
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
    procedure_path: str = ""
    """The procedure's path as recorded (data: it only places the stored text, :func:`procedure_file`)."""
    faults_injected: bool = False
    """Whether faults were injected into the recorded run (``--inject-faults``)."""
    config_path: str = ""
    """The config's absolute path as the ``config_sources`` event recorded it (checked); ``""``
    for a file recorded before that event."""
    config_sources: dict[str, str] | None = None
    """The texts of the files the recorded config read (sensor models, calibration files): absolute
    recorded path -> text, each path checked; None for a file recorded before bench kept them
    (then only the project's ``configs/`` provides them, :func:`config_file`)."""
    _link_keys: dict = field(default_factory=dict, repr=False)

    @property
    def sha256(self) -> str:
        """Hex SHA-256 of the file's bytes."""
        return self.digest()

    def link_keys(self, drivers: dict[str, str]) -> list[tuple[str, str] | None]:
        """:func:`link_keys` of :attr:`traffic`, worked out once per ``drivers`` (the exchanges and
        the comparison both need them)."""
        key = tuple(sorted(drivers.items()))
        if key not in self._link_keys:
            self._link_keys[key] = link_keys(self.traffic, drivers)
        return self._link_keys[key]

    def links(self, drivers: dict[str, str]) -> dict[tuple[str, str], list[Exchange]]:
        """(instrument, link) -> exchanges in order. ``drivers``: instrument -> driver name."""
        out: dict[tuple[str, str], list[Exchange]] = {}
        tr = self.traffic
        for key, kind, t, step, message, data in zip(self.link_keys(drivers), tr.kind, tr.t_s, tr.step, tr.message, tr.data):
            if key is None:
                continue
            seq = out.get(key)
            if seq is None:
                seq = out[key] = []
            if kind == "command":
                seq.append(Exchange(t, step, message, data, []))
            elif seq:
                seq[-1].replies.append((t, message, data))
        return out

    def stream(self, key: str) -> dict[str, np.ndarray] | None:
        if key not in {s.key for s in self.summary.streams}:
            return None
        return read_stream(self.path, key)


def load_recording(path: Path) -> Recording:
    """Read ``path`` for a replay. :class:`InputError` (one line) when it is not a run file, is of
    another format version, lacks what a replay needs, or holds names or paths bench does not write
    (they are data to the replay: see :mod:`bench.replay.workspace`)."""
    path = Path(path)
    _check_version(path)
    digest = file_sha256_soon(path)
    summary, traffic = read_summary_and_traffic(path)
    _check_names(path, summary)
    proc = [e for e in summary.events if e.kind == "procedure"]
    if not proc:
        raise InputError(f"{path}: cannot be replayed: it was recorded by an older bench "
                         f"({summary.attrs.get(layout.ATTR_SOFTWARE_VERSION, '?')}) without {REPLAY_NEEDS}; record it again")
    info = _procedure_info(path, proc[0])
    cfg = [e for e in summary.events if e.kind == layout.EVENT_CONFIG_SOURCES]
    cfg_info = _config_sources_info(path, cfg[0]) if cfg else {"path": "", "sources": None}
    answers = []
    for e in summary.events:
        if e.kind == "operator":
            try:
                a = json.loads(e.message)
                answers.append((str(a["id"]), str(a["answer"]), str(a.get("source", "file"))))
            except (json.JSONDecodeError, KeyError, TypeError, RecursionError):
                continue
    end = max(max((e.t_s for e in summary.events), default=0.0), max(traffic.t_s, default=0.0))
    return Recording(
        path=path, summary=summary, traffic=traffic, digest=digest, mode=str(summary.attrs.get(layout.ATTR_MODE, "")), status=summary.status,
        parameters=info["parameters"], sources=info["sources"], answers=answers,
        prelude_recorded=any(e.kind == "lab_open" for e in summary.events), end_t_s=end,
        clock=str(info.get("clock") or ("wall" if summary.attrs.get(layout.ATTR_MODE) == layout.MODE_HARDWARE else "virtual")),
        procedure_path=info["path"], faults_injected=summary.event_counts.get("fault_injected", 0) > 0,
        config_path=cfg_info["path"], config_sources=cfg_info["sources"],
    )


def _check_version(path: Path) -> None:
    """Refuse a run file older than the replay reads. The version is read through the reader's
    bounded opening (a truncated or corrupted file is refused in seconds, not retried for hours; a
    missing file, a directory, a FIFO or a device with the reason)."""
    version = read_format_version(path)
    if version is None:
        return  # read_run_summary says "not written by bench"
    if version < layout.FORMAT_VERSION:
        raise InputError(f"{path}: run file {layout.ATTR_FORMAT_VERSION} {version} is older than bench replay reads ({layout.FORMAT_VERSION}); "
                         f"replay it with the bench version that recorded it, or record it again")


PLAIN_NAME_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}$")
"""Instrument and stream names a replay accepts from a run file (bench writes such names)."""
MAX_SOURCES = 1000
"""Most sub-procedure and vibration-profile texts a run file's ``procedure`` event may hold."""


def check_plain_name(name: str, path: Path, what: str) -> None:
    """:class:`InputError` naming ``path`` when ``name`` (an instrument or stream name read from the
    run file, described by ``what``) is not a plain name: letters, digits, ``_``, ``-`` and ``.``,
    not starting with ``.`` or ``-``, at most 64 characters."""
    if not PLAIN_NAME_RE.match(name):
        raise InputError(f"{path}: {what} {shown(name)} is not a plain name (letters, digits, '_', '-', '.'; at most 64 characters); "
                         "the run file was not written by bench or was altered")


def _check_names(path: Path, summary: RunSummary) -> None:
    for name in summary.instruments:
        check_plain_name(name, path, f"{layout.absolute(layout.INSTRUMENTS)}:")
    for s in summary.streams:
        for part in filter(None, layout.split_stream_key(s.key)):
            check_plain_name(part, path, f"{layout.absolute(layout.STREAMS)}: stream {shown(s.key)}:")


def _event_json(path: Path, event: EventRow, what: str) -> object:
    """The JSON of a recorded event ``what`` (e.g. ``'procedure' event``); :class:`InputError` when unreadable."""
    try:
        return json.loads(event.data.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: cannot be replayed: unreadable {what} ({exc})") from None
    except RecursionError:
        raise InputError(f"{path}: cannot be replayed: unreadable {what} (nested too deeply)") from None


def _checked_sources(sources: dict, path: Path, what: str, texts: str, path_what: str) -> dict[str, str]:
    """``sources`` of a recorded event (absolute normalised recorded path -> text of at most
    :data:`~bench.inputs.YAML_LIMIT_BYTES`, at most :data:`MAX_SOURCES` of them), each checked."""
    where = f"{path}: the {what}"
    if len(sources) > MAX_SOURCES:
        raise InputError(f"{where} holds {len(sources)} {texts}, more than {MAX_SOURCES}")
    checked: dict[str, str] = {}
    for key, text in sources.items():
        checked_path(key, path, f"{what}: {path_what}", absolute=True)
        if not isinstance(text, str) or len(text.encode("utf-8", errors="surrogateescape")) > YAML_LIMIT_BYTES:
            raise InputError(f"{where}: the text of {shown(key)} is not a text of at most {YAML_LIMIT_BYTES >> 20} MiB")
        checked[key] = text
    return checked


def _procedure_info(path: Path, event: EventRow) -> dict:
    """The ``procedure`` event's JSON, its types checked: ``path`` (str), ``parameters`` (mapping),
    ``sources`` (absolute recorded path -> text, each path checked, each text at most
    :data:`~bench.inputs.YAML_LIMIT_BYTES`), ``clock``."""
    what = "'procedure' event"
    where = f"{path}: the {what}"
    info = _event_json(path, event, what)
    if not isinstance(info, dict):
        raise InputError(f"{where} is not a JSON object; the run file was not written by bench or was altered")
    params, sources, proc_path = info.get("parameters") or {}, info.get("sources") or {}, info.get("path")
    if not isinstance(params, dict) or not isinstance(sources, dict) or not isinstance(proc_path, str):
        raise InputError(f"{where} does not hold parameters, sources and path as bench writes them; "
                         "the run file was not written by bench or was altered")
    checked = _checked_sources(sources, path, what, "sub-procedure texts", "sub-procedure path")
    checked_path(proc_path, path, "'procedure' event: procedure path", absolute=False)
    return {"parameters": params, "sources": checked, "path": proc_path, "clock": info.get("clock")}


def _config_sources_info(path: Path, event: EventRow) -> dict:
    """The ``config_sources`` event's JSON, checked as :func:`_procedure_info` checks the
    ``procedure`` event's: ``path`` (absolute, normalised) and ``sources`` (absolute normalised
    recorded path -> text of at most :data:`~bench.inputs.YAML_LIMIT_BYTES`)."""
    what = f"'{layout.EVENT_CONFIG_SOURCES}' event"
    info = _event_json(path, event, what)
    sources = info.get("sources") if isinstance(info, dict) else None
    cfg_path = info.get("path") if isinstance(info, dict) else None
    if not isinstance(sources, dict) or not isinstance(cfg_path, str):
        raise InputError(f"{path}: the {what} does not hold the config's path and sources as bench writes them; "
                         "the run file was not written by bench or was altered")
    checked_path(cfg_path, path, f"{what}: config path", absolute=True)
    return {"path": cfg_path, "sources": _checked_sources(sources, path, what, "texts", "source path")}


def file_sha256(path: Path) -> str:
    """Hex SHA-256 of a file's bytes (read in 1 MiB blocks)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def file_sha256_soon(path: Path) -> Callable[[], str]:
    """:func:`file_sha256` of ``path`` started in a thread (hashing and reading release the GIL,
    so an 8-h run file's 400 MB are hashed on another core while the replay reads the events);
    the returned function waits for it (raising what it raised)."""
    box: dict[str, object] = {}

    def work() -> None:
        try:
            box["hex"] = file_sha256(path)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller
            box["error"] = exc

    th = threading.Thread(target=work, name=f"sha256 {path.name}", daemon=True)
    th.start()

    def result() -> str:
        th.join()
        if "error" in box:
            raise box["error"]  # type: ignore[misc]
        return box["hex"]  # type: ignore[return-value]

    return result


# ---- the recorded texts as files, in the replay's private directory -------------------------------
def procedure_file(rec: Recording, ws: Workspace) -> Path:
    """Write the recorded procedure and every text of the ``procedure`` event's ``sources``
    (sub-procedures, vibration profiles) into ``ws`` at their mirrored recorded paths; the path of
    the procedure there. A relative recorded procedure path is anchored where its sub-procedures
    were found (:func:`_anchor`)."""
    keys = [PurePosixPath(k) for k in rec.sources]
    for key, text in rec.sources.items():
        ws.write(PurePosixPath(key), text, f"{ws.run_file}:'procedure' event sources[{key}]")
    rel = checked_path(rec.procedure_path, rec.path, "'procedure' event: procedure path", absolute=False)
    anchor = PurePosixPath("/") if PurePosixPath(rec.procedure_path).is_absolute() else _anchor(rel, keys)
    return ws.write(anchor / rel, rec.summary.procedure_text, f"{ws.run_file}:{layout.absolute(layout.PROCEDURE_TEXT)}")


def _anchor(rel: PurePosixPath, keys: list[PurePosixPath]) -> PurePosixPath:
    """The directory a relative recorded procedure path ``rel`` was taken from (the recording's
    working directory), guessed from the absolute paths of the texts it called: the nearest
    ancestor of one of them that ends with ``rel``'s directories; ``/`` when none does."""
    want = rel.parent.parts
    for key in sorted(keys, key=lambda k: (len(k.parts), str(k))):
        for anc in key.parents:
            if not want:
                return anc
            if len(anc.parts) > len(want) and anc.parts[-len(want):] == want:
                return PurePosixPath(*anc.parts[:-len(want)])
    return PurePosixPath("/")


def config_file(rec: Recording, ws: Workspace) -> Path:
    """Write the recorded config into ``ws`` at its mirrored recorded path with the files it read
    (sensor models, calibration files): from the ``config_sources`` event, or, for a file
    recorded before that event, those the project's ``configs/`` holds under the relative name the
    config gives; the path of the config there. Nothing is read from the recorded config's own
    directory."""
    text = rec.summary.config_text
    recorded = str(rec.summary.attrs.get(layout.ATTR_CONFIG_PATH, "")) or "config.yaml"
    rel = checked_path(recorded, rec.path, f"{layout.ATTR_CONFIG_PATH} attribute", absolute=False)  # checked either way
    if rec.config_sources is not None:
        event = f"{ws.run_file}:'{layout.EVENT_CONFIG_SOURCES}' event"
        for key, source in rec.config_sources.items():
            ws.write(PurePosixPath(key), source, f"{event} sources[{key}]")
        where = checked_path(rec.config_path, rec.path, f"'{layout.EVENT_CONFIG_SOURCES}' event: config path", absolute=True)
        return ws.write(where, text, f"{ws.run_file}:{layout.absolute(layout.CONFIG_TEXT)}")
    where = PurePosixPath("/") / rel
    out = ws.write(where, text, f"{ws.run_file}:{layout.absolute(layout.CONFIG_TEXT)}")
    for name in _relative_names(text):
        try:
            src = confined_path(name, base=CONFIG_ROOTS[0], roots=(), what="", where="", location=None, field=None)
            data = read_input_bytes(src, limit_bytes=YAML_LIMIT_BYTES, what="")
        except InputError:
            continue  # not shipped: the config loader reports the file as missing, located
        ws.write(where.parent / os.path.normpath(name), data.decode("utf-8", errors="surrogateescape"), str(src))
    return out


def _relative_names(text: str) -> list[str]:
    """Relative file names the config text gives under ``instruments:``: ``sim.sensor_model`` and
    ``calibration`` (one or a list) that stay inside the config's directory; ``[]`` for a text the
    config loader will refuse anyway."""
    if len(text.encode("utf-8", errors="surrogateescape")) > YAML_LIMIT_BYTES:
        return []
    try:
        root = parse_yaml(text, "<config>", "config")
    except InputError:
        return []
    names: list[str] = []
    insts = root.root.value.get("instruments") if isinstance(root.root.value, dict) else None
    for inst in (insts.value.values() if insts is not None and isinstance(insts.value, dict) else []):
        if not isinstance(inst.value, dict):
            continue
        sim = inst.value.get("sim")
        nodes = [sim.value.get("sensor_model")] if sim is not None and isinstance(sim.value, dict) else []
        cal = inst.value.get("calibration")
        nodes += (cal.value if isinstance(cal.value, list) else [cal]) if cal is not None else []
        for n in nodes:
            v = getattr(n, "value", None)
            if isinstance(v, str) and v and "\0" not in v and not v.startswith("/") and not os.path.normpath(v).startswith(".."):
                names.append(v)
    return names


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
