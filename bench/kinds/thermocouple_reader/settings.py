"""The thermocouple reader's config keys: the channels scanned during a run and the thermocouple
type; in ``sim:``, channels whose thermocouple is open and the SCPI socket's port under
``bench sim serve`` (docs/thermocouples.md)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from bench.errors import InputError
from bench.yamlsrc import Fields

if TYPE_CHECKING:  # pragma: no cover
    from bench.config import ConfigContext, SimConfig


@dataclass
class ReaderSettings:
    channels: list[int] = field(default_factory=lambda: [101, 102, 103, 104])
    """Channels scanned during a run (slot 1-3, channel 01-99)."""
    tc_type: str = "K"

    def open_kwargs(self) -> dict[str, Any]:
        return {"monitor_channels": self.channels, "tc_type": self.tc_type}


@dataclass
class ReaderSimSettings:
    open_channels: list[int] = field(default_factory=list)
    scpi_port: int = 5025
    """TCP port of the SCPI raw socket on 127.0.0.1 under ``bench sim serve`` (5025, the 34972A's LAN
    port; 0: any free port)."""


def settings(f: Fields, ctx: "ConfigContext") -> ReaderSettings:
    channels = f.get("channels", list, default=[101, 102, 103, 104])
    if not channels or not all(isinstance(c, int) and not isinstance(c, bool) and 101 <= c <= 399 for c in channels):
        ctx.errors.append(InputError("expected a list of channel numbers such as [101, 102] (slot 1-3, channel 01-99)",
                                     (f.map.get("channels") or f.node).location, "channels"))
    tc_type = f.get("tc_type", str, default="K")
    if tc_type not in ("K", "T"):
        ctx.errors.append(InputError(f"expected thermocouple type K or T, got {tc_type!r}", f.map["tc_type"].location, "tc_type"))
    return ReaderSettings(channels, tc_type)


def sim_settings(f: Fields, ctx: "ConfigContext") -> ReaderSimSettings:
    s = ReaderSimSettings()
    opened = f.get("open_channels", list, default=[])
    if not all(isinstance(c, int) and not isinstance(c, bool) for c in opened):
        ctx.errors.append(InputError("expected a list of channel numbers such as [104]", f.map["open_channels"].location, "open_channels"))
    else:
        s.open_channels = opened
    s.scpi_port = ctx.tcp_port(f, "scpi_port", 5025)
    return s


def tcp_ports(sim: "SimConfig") -> list[tuple[int, str]]:
    """The SCPI socket's port ``bench sim serve`` binds."""
    return [(sim.settings.scpi_port, "SCPI")] if sim.settings.scpi_port else []
