"""Thermal-vacuum chamber: a Watlow F4 temperature controller (Modbus) plus a Pfeiffer TPG 261
vacuum gauge (serial), seen as one instrument ``tvac``. See ``docs/tvac.md``.

Wiring assumed (our choice, ``docs/tvac.md``): F4 event output 1 switches the roughing + turbo
pumps, event output 2 the vent valve; PV input 1 is the chamber air, input 2 the mounting plate.
"""

from __future__ import annotations

from typing import Callable

from drivers.base import Driver
from drivers.tpg261 import Tpg261
from drivers.watlow_f4 import RTU_BAUDRATE, WatlowF4

EVENT_PUMP = 1
EVENT_VENT = 2
SAFE_SET_POINT_C = 20.0  # room temperature: neither condensation on the unit nor stress on it


class TvacChamber(Driver):
    """Composite driver; temperatures in °C, ramp rates in °C/min, pressure in Torr."""

    kind = "tvac"
    streams = False

    def __init__(self, controller: WatlowF4, gauge: Tpg261, *, safe_set_point_c: float = SAFE_SET_POINT_C):
        self.controller = controller
        self.gauge = gauge
        self.name = "tvac"
        self.timeout_s = controller.timeout_s
        self.safe_set_point_c = safe_set_point_c

    @classmethod
    def open(cls, url: str, *, baudrate: int = RTU_BAUDRATE, timeout_s: float = 0.5,
             on_traffic: Callable[[str, str, bytes], None] | None = None, gauge_url: str,
             gauge_baudrate: int = 9600, safe_set_point_c: float = SAFE_SET_POINT_C) -> "TvacChamber":
        """Open the controller at ``url`` (``modbus-tcp://HOST:PORT`` or ``modbus-rtu:///dev/ttyUSB0``,
        ``baudrate`` for RTU: 9600, protocols.md section 1) and the gauge at ``gauge_url``
        (``sim://tvac.gauge`` or ``/dev/ttyUSB1``, ``gauge_baudrate`` 9600, section 2)."""
        controller = WatlowF4.open(url, baudrate=baudrate, timeout_s=timeout_s, on_traffic=on_traffic)
        try:
            gauge = Tpg261.open(gauge_url, baudrate=gauge_baudrate, timeout_s=timeout_s, on_traffic=on_traffic)
        except BaseException:
            controller.close()
            raise
        return cls(controller, gauge, safe_set_point_c=safe_set_point_c)

    def close(self) -> None:
        try:
            self.controller.close()
        finally:
            self.gauge.close()

    def identify(self) -> dict[str, str]:
        """vendor, model, serial, firmware. The F4 has no known ID register [U]: its part is what
        it reports about itself (units 901, decimals 606); the gauge gives ``PNR`` and ``TID``."""
        cfg = self.controller.check_configuration()
        g = self.gauge.identify()
        return {
            "vendor": f"Watlow + {g['vendor']}",
            "model": f"F4 (units={cfg['temp_unit']}, decimals={cfg['decimals']}) + {g['model']} ({g['gauges']})",
            "serial": "unknown",
            "firmware": f"F4 unknown; TPG {g['firmware']}",
        }

    def read(self) -> dict:
        """air_temp_c, mount_temp_c, set_point_c (°C), pressure_torr (Torr), pump_on, vent_open,
        output_pct (% heat − cool), alarms (see :meth:`WatlowF4.read_alarms`)."""
        c = self.controller
        return {
            "air_temp_c": c.read_air_temp_c(),
            "mount_temp_c": c.read_mount_temp_c(),
            "set_point_c": c.read_set_point_c(),
            "pressure_torr": self.gauge.read_pressure_torr(),
            "pump_on": c.read_event(EVENT_PUMP),
            "vent_open": c.read_event(EVENT_VENT),
            "output_pct": c.read_output_pct(),
            "alarms": c.read_alarms(),
        }

    MONITOR_COLUMNS = ("air_temp", "mount_temp", "pressure")

    def monitor_columns(self) -> list[str]:
        """Columns of :meth:`monitor` (their units: degC, degC, Torr, declared by the ``tvac`` kind)."""
        return list(self.MONITOR_COLUMNS)

    def monitor(self) -> dict[str, float]:
        """The readings a run logs every poll interval: air and mount temperature (°C), pressure (Torr)."""
        c = self.controller
        return {"air_temp": c.read_air_temp_c(), "mount_temp": c.read_mount_temp_c(), "pressure": self.gauge.read_pressure_torr()}

    def set_point(self, temp_c: float, ramp_c_per_min: float | None = None) -> None:
        """New set point (°C); with ``ramp_c_per_min`` the ramp rate is written first (0 = step)."""
        if ramp_c_per_min is not None:
            self.controller.set_ramp_rate_c_per_min(ramp_c_per_min)
        self.controller.set_set_point_c(temp_c)

    def pump_down(self) -> None:
        """Close the vent valve, then start the pumps (never pump against an open vent)."""
        self.controller.set_event(EVENT_VENT, False)
        self.controller.set_event(EVENT_PUMP, True)

    def vent(self) -> None:
        """Stop the pumps, then open the vent valve."""
        self.controller.set_event(EVENT_PUMP, False)
        self.controller.set_event(EVENT_VENT, True)

    def safe_state(self) -> str:
        """Ramp off and set point to ``safe_set_point_c``. The vacuum is left as it is: venting a
        cold chamber would condense water on the unit; venting is a deliberate step once warm.
        Returns what the controller was told."""
        self.controller.set_ramp_rate_c_per_min(0.0)
        self.controller.set_set_point_c(self.safe_set_point_c)
        return f"ramp off, set point {self.safe_set_point_c:g} degC; vacuum left as it is (no vent)"
