"""The chamber in a replay: its controller's recorded Modbus exchanges (TCP on a socket or an
in-process stream, or RTU frames) and its gauge's recorded serial bytes (bench/replay/lab.py)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from bench.replay.backends import ModbusReplayServer, ModbusRtuReplay, ModbusTcpReplay

if TYPE_CHECKING:  # pragma: no cover
    from bench.config import InstrumentConfig
    from bench.replay.lab import ReplayContext


def controller_on_rtu(inst: "InstrumentConfig", mode: str) -> bool:
    """Whether the chamber controller of a recording in ``mode`` (``sim`` | ``hardware``) talked
    Modbus RTU: the simulator's ``transport: rtu`` in a dry-run, a ``modbus-rtu://`` port on hardware."""
    if mode == "sim":
        return inst.sim is not None and inst.sim.transport == "rtu"
    return inst.port.startswith("modbus-rtu:")


def wire(ctx: "ReplayContext", name: str, inst: "InstrumentConfig") -> str:
    url = _controller(ctx, name, inst)
    ctx.kwargs[name]["gauge_url"] = ctx.serial(name, "gauge", "gauge")
    return url


def _controller(ctx: "ReplayContext", name: str, inst: "InstrumentConfig") -> str:
    if controller_on_rtu(inst, ctx.mode):
        scheme = "modbus-rtu+stream://" if ctx.inprocess else "modbus-rtu://"
        return scheme + ctx.serial(name, "controller", "", ModbusRtuReplay)
    if ctx.inprocess:
        return "modbus-tcp+stream://" + ctx.serial(name, "controller", "", ModbusTcpReplay)
    addr = None
    if name in ctx.prelude:
        host_port = ctx.prelude[name].url.split("://", 1)[1]
        h, p = host_port.rsplit(":", 1)
        addr = (h, int(p))
    b = ModbusReplayServer(f"{name} controller", ctx.links.get((name, "controller"), []), ctx.on_exhausted, addr)
    ctx.backends[(name, "controller")] = b
    return f"modbus-tcp://127.0.0.1:{b.port}"
