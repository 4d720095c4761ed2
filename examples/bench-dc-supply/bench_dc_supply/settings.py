"""The supply's config keys: the outputs this lab uses, each with the voltage, current limit,
protection levels and settle time it powers its unit with; in ``sim:``, the LAN socket's port under
``bench sim serve``. Read with the same located errors as bench's own kinds (bench.config)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from bench.errors import InputError
from bench.yamlsrc import Fields
from bench_dc_supply.driver import OutputSetting
from bench_dc_supply.dp832 import LAN_PORT, RANGES

if TYPE_CHECKING:  # pragma: no cover
    from bench.config import ConfigContext, SimConfig

@dataclass
class SupplySettings:
    outputs: dict[str, OutputSetting] = field(default_factory=dict)
    """Output number (``"1"``..``"3"``) -> how it powers what it feeds (what ``powered_by`` names)."""

    def open_kwargs(self) -> dict[str, Any]:
        return {"outputs": self.outputs}


@dataclass
class SupplySimSettings:
    scpi_port: int = LAN_PORT


def settings(f: Fields, ctx: "ConfigContext") -> SupplySettings:
    out = SupplySettings()
    node = f.node_at("outputs")
    if node is None:
        return out
    if not isinstance(node.value, dict) or not node.value:
        ctx.errors.append(InputError("expected a mapping of output numbers to settings, e.g. {1: {voltage: 5 V, current: 0.1 A}}",
                                     node.location, "outputs"))
        return out
    for key, onode in node.value.items():
        name = str(key)
        if not name.isdigit() or int(name) not in RANGES:
            ctx.errors.append(InputError(f"output {key!r}: the DP832 has outputs {', '.join(map(str, RANGES))}",
                                         node.key_locations.get(key, node.location), "outputs"))
            continue
        setting = _output(int(name), Fields(onode, f"output {name}", ctx.errors), ctx)
        if setting is not None:
            out.outputs[name] = setting
    return out


def _output(n: int, f: Fields, ctx: "ConfigContext") -> OutputSetting | None:
    vmax, imax = RANGES[n]
    before = len(ctx.errors)
    values: dict[str, float | None] = {}
    for key, units, hi, required in (("voltage", "V", vmax, True), ("current", "A", imax, True),
                                     ("ovp", "V", vmax * 1.1, False), ("ocp", "A", imax * 1.1, False)):
        node = f.node_at(key)
        if node is None:
            if required:
                ctx.errors.append(InputError(f"missing required field in {f.what}", f.node.location, key))
            values[key] = None
            continue
        v = ctx.quantity(node, units, key, 0.0)
        if not 0 <= v <= hi:
            ctx.errors.append(InputError(f"{v:g} {units} is outside output {n}'s range 0..{hi:g} {units} (DP832)", node.location, key))
        values[key] = v
    settle = 0.5
    if (node := f.node_at("settle")) is not None:
        settle = ctx.quantity(node, "s", "settle", settle)
        if not 0 <= settle <= 60:
            ctx.errors.append(InputError("expected a settle time between 0 and 60 s", node.location, "settle"))
    f.check_unknown()
    if len(ctx.errors) > before:
        return None
    if values["ovp"] is not None and values["voltage"] > values["ovp"]:
        ctx.errors.append(InputError(f"voltage {values['voltage']:g} V is above the OVP level {values['ovp']:g} V: "
                                     "the output would trip when switched on", f.map["ovp"].location, "ovp"))
        return None
    return OutputSetting(values["voltage"], values["current"], values["ovp"], values["ocp"], settle)


def sim_settings(f: Fields, ctx: "ConfigContext") -> SupplySimSettings:
    return SupplySimSettings(ctx.tcp_port(f, "scpi_port", LAN_PORT))


def tcp_ports(sim: "SimConfig") -> list[tuple[int, str]]:
    """The LAN socket's port ``bench sim serve`` binds."""
    return [(sim.settings.scpi_port, "SCPI")] if sim.settings.scpi_port else []
