"""``bench instruments check``: connect to every instrument of a config, identify it, read one value.

Each instrument is opened on its own, so one that does not answer cannot hide the others. The
reading is chosen not to change the instrument's state (no motion, no power, no set point).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from bench.config import LabConfig
from bench.errors import KNOWN_ERRORS


@dataclass
class CheckRow:
    """One line of the check table."""

    instrument: str
    transport: str
    endpoint: str
    identity: str
    reading: str
    status: str

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def _acs_board(drv) -> str:
    c = drv.get_config()
    return f"ODR {c['odr_hz']} Hz, moving average {c['moving_avg_n']}, sensors {'on' if c['sensor_power'] else 'off'}"


def _stepper_bench(drv) -> str:
    s = drv.status()
    return f"{s['state']}, angle {s['angle_deg']:.3f} deg"


def _thermocouple_reader(drv) -> str:
    return f"reference junction {drv.reference_junction_c(101):.2f} degC"


def _tvac(drv) -> str:
    r = drv.read()
    return f"air {r['air_temp_c']:.1f} degC, set point {r['set_point_c']:.1f} degC, {r['pressure_torr']:.3g} Torr"


def _rate_table(drv) -> str:
    r = drv.read()
    return f"angle {r['angle_deg']:.3f} deg, rate {r['rate_dps']:.3f} deg/s, tilt {r['tilt_deg']:.3f} deg, {r['state']}"


READINGS: dict[str, Callable[[Any], str]] = {
    "acs_board": _acs_board,
    "stepper_bench": _stepper_bench,
    "thermocouple_reader": _thermocouple_reader,
    "tvac": _tvac,
    "rate_table": _rate_table,
}
"""Driver name -> one non-invasive reading, formatted with its units."""


def transport_of(url: str) -> str:
    """Transport named by a port URL: ``modbus-tcp``, ``can``, ``serial`` (simulated or real)."""
    scheme = url.split("://", 1)[0] if "://" in url else ""
    if scheme.startswith("modbus"):
        return scheme
    if scheme == "can":
        return "can"
    return "serial"


def check_instruments(config: LabConfig, *, sim: bool) -> list[CheckRow]:
    """One :class:`CheckRow` per instrument in ``config``; never raises for an instrument fault."""
    from bench.lab import open_lab

    rows = []
    for name, inst in config.instruments.items():
        endpoint, identity, reading = inst.port, "", ""
        try:
            lab = open_lab(config, [name], sim=sim, realtime=False)
        except (*KNOWN_ERRORS, OSError, ValueError) as exc:
            rows.append(CheckRow(name, transport_of(endpoint), endpoint, "", "", f"cannot open: {exc}"))
            continue
        try:
            drv = lab.instruments[name]
            endpoint = lab.ports[name]
            ident = drv.identify()
            identity = " ".join(str(ident.get(k, "")) for k in ("vendor", "model", "serial") if ident.get(k))
            reading = READINGS[inst.driver](drv)
            status = "ok"
        except (*KNOWN_ERRORS, OSError, ValueError, KeyError) as exc:
            status = f"{type(exc).__name__}: {exc}"
        finally:
            lab.close()
        rows.append(CheckRow(name, transport_of(endpoint), endpoint, identity, reading, status))
    return rows
