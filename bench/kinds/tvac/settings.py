"""The chamber's config keys: its pressure gauge's link and the set point of its safe state; in
``sim:``, the simulated Modbus TCP server's port (docs/tvac.md)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from bench.errors import InputError
from bench.yamlsrc import Fields

if TYPE_CHECKING:  # pragma: no cover
    from bench.config import ConfigContext, SimConfig


@dataclass
class TvacSettings:
    gauge_port: str = ""
    """Serial URL of the vacuum gauge controller (TPG 261)."""
    gauge_baudrate: int = 9600
    """TPG 261 default (BG 5195 BEN/A p65), bit/s."""
    safe_set_point_c: float = 20.0
    """Chamber set point of the safe state (°C)."""

    def open_kwargs(self) -> dict[str, Any]:
        return {"gauge_url": self.gauge_port, "gauge_baudrate": self.gauge_baudrate, "safe_set_point_c": self.safe_set_point_c}

    def ports(self) -> list[tuple[str, str]]:
        return [("gauge_port", self.gauge_port)] if self.gauge_port else []


@dataclass
class TvacSimSettings:
    modbus_port: int = 0
    """TCP port of the simulated Modbus server on 127.0.0.1 under ``bench sim serve`` (0: any free port)."""


def settings(f: Fields, ctx: "ConfigContext") -> TvacSettings:
    s = TvacSettings()
    s.gauge_port = f.get("gauge_port", str, default="")
    if not s.gauge_port:
        ctx.errors.append(InputError("a tvac instrument needs 'gauge_port' (serial port of its vacuum gauge controller, e.g. /dev/ttyUSB1)",
                                     f.node.location, "gauge_port"))
    s.gauge_baudrate = f.get("gauge_baudrate", int, default=9600)
    if (n := f.node_at("safe_set_point")) is not None:
        s.safe_set_point_c = ctx.quantity(n, "degC", "safe_set_point", s.safe_set_point_c)
        _check_safe_set_point(s.safe_set_point_c, ctx.limits, n, ctx.errors)
    return s


def _check_safe_set_point(safe_c: float, limits: dict[str, tuple], node, errors: list[InputError]) -> None:
    """The chamber's safe set point (degC), written on every abort, must lie within its set-point
    limits (the tvac defaults narrowed by this config's ``limits:``): an abort must not heat or
    cool the unit beyond what a procedure may ask."""
    from bench.procedure.limits import effective_limits, outside_limits

    lo, hi, src = effective_limits("tvac", {"set_point": limits["set_point"]} if "set_point" in limits else {})["set_point"]
    if outside_limits(safe_c, lo, hi):
        errors.append(InputError(f"{safe_c:g} degC is outside the chamber's set-point limits {lo:g}..{hi:g} degC ({src}): "
                                 "the safe set point is written on every abort", node.location, "safe_set_point"))


def sim_settings(f: Fields, ctx: "ConfigContext") -> TvacSimSettings:
    return TvacSimSettings(ctx.tcp_port(f, "modbus_port", 0))


def tcp_ports(sim: "SimConfig") -> list[tuple[int, str]]:
    """The Modbus TCP port ``bench sim serve`` binds (none when the controller is on RTU)."""
    return [(sim.settings.modbus_port, "Modbus TCP")] if sim.transport != "rtu" and sim.settings.modbus_port else []
