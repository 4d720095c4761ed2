"""The transcript format of ``docs/golden/grbl-transcripts/*.txt``: what the real GRBL 1.1h
firmware (built with grbl-sim, docs/stepper-bench.md) and a host said to each other.

A transcript is text: ``#`` header lines (title, firmware commits, build flags, date, EEPROM,
notes), then one event a line::

    12.345 > "$J=G91G21X10.000F60.000\\n"
    12.361 < "ok\\r\\n"

time (wall s since the port was opened), direction (``>`` host to firmware, ``<`` firmware to
host) and the bytes as the inside of a Python bytes literal. Firmware bytes are cut into lines
(each keeps its line end); host bytes are kept as the host wrote them. Nothing here knows
GRBL: the tests read the bytes and compare them with what the driver writes and the simulator
answers.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass, field
from datetime import date
from pathlib import Path

TRANSCRIPTS = Path(__file__).resolve().parents[2] / "docs" / "golden" / "grbl-transcripts"

PROVENANCE = (
    "firmware: gnea/grbl bdc2da9b5972c5972cdd4a4f045a575f09ff74cc (v1.1h.20190830, default config.h: Uno, 115200 baud)",
    "simulator: grbl/grbl-sim 9bdd1654c7eb6cacf03e35340b38c962bcebe013, one change: platform_LINUX.c reads stdin with read(2), not getchar()",
    "build: gcc 12.2.0 (Debian 12.2.0-14+deb12u1), make new FLAGS='-g -O3 -fcommon', -fcommon also at link",
    "run: grbl_sim.exe -n -b /dev/null -s /dev/null on a raw pseudo-terminal (tests/grbl_firmware.py)",
)


@dataclass
class Event:
    t_s: float
    direction: str  # ">" host -> firmware, "<" firmware -> host
    data: bytes


@dataclass
class Transcript:
    name: str
    header: list[str] = field(default_factory=list)
    events: list[Event] = field(default_factory=list)

    def header_value(self, key: str) -> str:
        """The value of a ``# key: value`` header line ("" when absent)."""
        for line in self.header:
            k, sep, v = line.partition(":")
            if sep and k.strip() == key:
                return v.strip()
        return ""

    @property
    def eeprom(self) -> str:
        return self.header_value("eeprom")

    def host_bytes(self) -> bytes:
        return b"".join(e.data for e in self.events if e.direction == ">")

    def firmware_bytes(self) -> bytes:
        return b"".join(e.data for e in self.events if e.direction == "<")


def encode(data: bytes) -> str:
    """The inside of a bytes literal for ``data`` (double-quoted)."""
    text = repr(bytes(data))
    if text.startswith("b'"):
        inner = text[2:-1].replace("\\'", "'").replace('"', '\\"')
    else:
        inner = text[2:-1]
    return f'"{inner}"'


def decode(field_text: str) -> bytes:
    value = ast.literal_eval("b" + field_text)
    if not isinstance(value, bytes):
        raise ValueError(f"not a bytes literal: {field_text!r}")
    return value


def split_firmware(events: list[tuple[float, str, bytes]]) -> list[Event]:
    """Relay chunks -> events: firmware bytes cut after each line end (a partial line is emitted
    before the next host bytes, so the order of the two directions is kept)."""
    out: list[Event] = []
    pending = bytearray()
    t_pending = 0.0
    for t, direction, data in events:
        if direction == ">":
            if pending:
                out.append(Event(t_pending, "<", bytes(pending)))
                pending.clear()
            out.append(Event(t, ">", bytes(data)))
            continue
        for b in data:
            if not pending:
                t_pending = t
            pending.append(b)
            if b == 0x0A:
                out.append(Event(t, "<", bytes(pending)))
                pending.clear()
    if pending:
        out.append(Event(t_pending, "<", bytes(pending)))
    return out


def write_transcript(path: Path, events: list[tuple[float, str, bytes]], *, title: str, eeprom: str,
                     notes: list[str] | tuple[str, ...] = (), recorded: str | None = None) -> None:
    lines = [f"# title: {title}", *(f"# {p}" for p in PROVENANCE), f"# recorded: {recorded or date.today().isoformat()}",
             f"# eeprom: {eeprom}", *(f"# note: {n}" for n in notes)]
    for e in split_firmware(events):
        lines.append(f"{e.t_s:.3f} {e.direction} {encode(e.data)}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="ascii")


def read_transcript(path: Path) -> Transcript:
    tr = Transcript(path.stem)
    for n, line in enumerate(path.read_text(encoding="ascii").splitlines(), 1):
        if not line.strip():
            continue
        if line.startswith("#"):
            tr.header.append(line[1:].strip())
            continue
        t, direction, rest = line.split(" ", 2)
        if direction not in "<>":
            raise ValueError(f"{path}:{n}: direction must be < or >, got {direction!r}")
        tr.events.append(Event(float(t), direction, decode(rest)))
    return tr


def all_transcripts() -> list[Transcript]:
    return [read_transcript(p) for p in sorted(TRANSCRIPTS.glob("*.txt"))]
