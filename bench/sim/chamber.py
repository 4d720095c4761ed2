"""Thermal-vacuum chamber physics: air/shroud temperature under control, pressure, and the unit
under test coupled to both, in run time (s).

State is integrated forward in steps of at most :data:`STEP_S` with exact exponential updates, so
a virtual clock can jump hours ahead at a cost of one small update per step. Commands apply from
the run time they are given at; the past is never rewritten. A bounded history (the last
:attr:`ChamberParams.history_s` seconds) lets sensor simulators ask for the unit temperature at
any recent sample time, vectorised, with memory flat in run length.

Model (defaults and sources in ``docs/simulation.md``, section "Chamber"):

* control: the working set point moves toward the set point at the ramp rate (0 = at once); a
  proportional loop drives the air at ``u·rate_max`` with ``u = clip((SP_w − T_air)/band, −1, 1)``.
  Heating and cooling rate limits are the fastest unit-temperature ramps of NPSAT1 Appendix
  Table 1: 0.62 °C/min warm-up (TVAC2-2a, −29 → +66 °C in 9157 s) and 0.47 °C/min cool-down
  (TVAC2-1a, +66 → −29 °C in 12166 s) at ambient pressure; 0.20 °C/min both ways in vacuum
  (FL2-1a, +77 → −21 °C in 29081 s; FL2-2b: "heating was too slow").
* unit: chamber air → mount → sensor die, two first-order stages with a pressure-dependent time
  constant: 100 s at ambient pressure (warm-up transient ~5 min = 3τ, NPSAT1 sections IV.A and
  IV.D.4) and 1800 s in vacuum (transients "up to 1.5 hours in vacuum" = 3τ, section IV.D.4).
  The powered die sits ``self_heating_c`` = 4 °C above its mount (MEMS vs thermocouple "as much
  as 4°C", section IV.B.3).
* pressure: roughing ``dP/dt = −P/τ_rough`` down to the turbo cross-over, then the turbo's
  outgassing-limited ``dP/dt = −P²/K`` (P ∝ 1/t) down to the ultimate pressure. K = 0.29 Torr·s
  reproduces NPSAT1 section IV.D.4 (4.6e-5 Torr at the start of a 5 h vacuum soak, 1.2e-5 Torr
  at its end); ultimate 1e-7 Torr ("the chamber pump down reached to 10⁻⁷ Torr", section IV.D
  footnote 8). With the pump off and valves closed the chamber leaks up at
  ``dP/dt = k_leak·(760 − P)``, k_leak = 6.3e-5 /s (pump-off noise test, 190 → 250 Torr in
  1748 s, section IV.D.1). Pump on with the vent open settles at 190 Torr (section IV.D.1),
  which fixes τ_vent = τ_rough·(760 − 190)/190.
"""

from __future__ import annotations

import math
import threading

import numpy as np

from bench.model.chamber import ATMOSPHERE_TORR, ChamberParams

__all__ = ["ATMOSPHERE_TORR", "STEP_S", "Chamber", "ChamberParams"]

STEP_S = 1.0
"""Largest integration step (s): well below the smallest time constant (100 s)."""


class Chamber:
    """One simulated thermal-vacuum chamber and the unit on its mount. Thread-safe.

    All ``t_s`` arguments are run times (s) of the shared clock; a command or query at ``t_s``
    first advances the state to ``t_s``. Queries before the current state time read the history.
    """

    def __init__(self, params: ChamberParams | None = None, ambient_temp_c: float | None = None):
        self.p = params or ChamberParams()
        t0 = self.p.initial_temp_c if ambient_temp_c is None else ambient_temp_c
        self._lock = threading.RLock()
        self._t = 0.0
        self.air_c = self.mount_c = self.die_c = float(t0)
        self.pressure = ATMOSPHERE_TORR
        self.set_point_c = float(t0)
        self.working_set_point_c = float(t0)
        self.ramp_rate_c_per_min = 0.0
        self.pump_on = False
        self.vent_open = False
        self.unit_powered = False
        self._u = 0.0
        n = int(self.p.history_s / STEP_S) + 2
        self._hist_t = np.full(n, -np.inf)
        self._hist_die = np.full(n, float(t0))
        self._hist_mount = np.full(n, float(t0))
        self._hist_air = np.full(n, float(t0))
        self._hist_p = np.full(n, ATMOSPHERE_TORR)
        self._hist_n = 0  # total entries ever written (ring index = n % len)
        self._record()

    @property
    def set_point_limits_c(self) -> tuple[float, float]:
        return (self.p.set_point_low_c, self.p.set_point_high_c)

    # ---- commands --------------------------------------------------------------------------
    def command_set_point(self, t_s: float, sp_c: float) -> None:
        """New loop set point (°C) from ``t_s``; ``ValueError`` outside the set-point limits."""
        lo, hi = self.set_point_limits_c
        if not (lo <= sp_c <= hi) or not math.isfinite(sp_c):
            raise ValueError(f"set point {sp_c:g} °C outside {lo:g}..{hi:g} °C")
        with self._lock:
            self.advance(t_s)
            self.set_point_c = float(sp_c)
            if self.ramp_rate_c_per_min <= 0:
                self.working_set_point_c = float(sp_c)

    def command_ramp_rate(self, t_s: float, rate_c_per_min: float) -> None:
        """Set-point ramp rate (°C/min) from ``t_s``; 0 turns ramping off (step changes)."""
        if not rate_c_per_min >= 0 or not math.isfinite(rate_c_per_min):
            raise ValueError(f"ramp rate must be >= 0 °C/min, got {rate_c_per_min!r}")
        with self._lock:
            self.advance(t_s)
            self.ramp_rate_c_per_min = float(rate_c_per_min)
            if rate_c_per_min == 0:
                self.working_set_point_c = self.set_point_c

    def set_pump(self, t_s: float, on: bool) -> None:
        """Roughing + turbo pumps on or off from ``t_s``."""
        with self._lock:
            self.advance(t_s)
            self.pump_on = bool(on)

    def set_vent(self, t_s: float, open_: bool) -> None:
        """Vent valve open or closed from ``t_s``."""
        with self._lock:
            self.advance(t_s)
            self.vent_open = bool(open_)

    def set_unit_power(self, t_s: float, on: bool) -> None:
        """The unit's electronics on or off from ``t_s`` (self-heating of the die)."""
        with self._lock:
            self.advance(t_s)
            self.unit_powered = bool(on)

    # ---- queries ---------------------------------------------------------------------------
    def air_temp_c(self, t_s: float) -> float:
        return float(self._query(t_s, "air"))

    def mount_temp_c(self, t_s: float) -> float:
        return float(self._query(t_s, "mount"))

    def pressure_torr(self, t_s: float) -> float:
        return float(self._query(t_s, "p"))

    def output_pct(self, t_s: float) -> float:
        """Loop output: + heater, − cooler power (%)."""
        with self._lock:
            self.advance(t_s)
            return 100.0 * self._u

    def unit_temperature_c(self, t_s: np.ndarray) -> np.ndarray:
        """Sensor die temperature (°C) at run times ``t_s`` (vectorised; history-interpolated)."""
        return self._query(np.asarray(t_s, dtype=float), "die")

    def mount_temperature_c(self, t_s: np.ndarray) -> np.ndarray:
        """Mount temperature (°C) at run times ``t_s`` (vectorised)."""
        return self._query(np.asarray(t_s, dtype=float), "mount")

    # ---- integration -----------------------------------------------------------------------
    def advance(self, t_s: float) -> None:
        """Integrate the state forward to ``t_s`` (no-op for times already passed)."""
        with self._lock:
            while self._t < t_s - 1e-12:
                dt = min(STEP_S, t_s - self._t)
                self._step(dt)
                self._t += dt
                self._record()

    def _fraction_ambient(self) -> float:
        """Share of the ambient-pressure gas coupling left at the current pressure (0..1)."""
        return self.p.fraction_ambient(self.pressure)

    def _step(self, dt: float) -> None:
        p = self.p
        f = self._fraction_ambient()
        # set-point ramp
        if self.ramp_rate_c_per_min > 0 and self.working_set_point_c != self.set_point_c:
            step = self.ramp_rate_c_per_min / 60.0 * dt
            diff = self.set_point_c - self.working_set_point_c
            self.working_set_point_c = self.set_point_c if abs(diff) <= step else self.working_set_point_c + math.copysign(step, diff)
        # air under proportional control, rate-limited by heater/cooler
        self._u = max(-1.0, min(1.0, (self.working_set_point_c - self.air_c) / p.control_band_c))
        rate_max = p.slew_rate_c_per_s(self._u > 0, f)
        # exact solution of dT/dt = rate_max·(SP − T)/band inside the band, linear slew outside
        target = self.working_set_point_c
        if abs(target - self.air_c) > p.control_band_c:
            self.air_c += math.copysign(rate_max * dt, target - self.air_c)
        else:
            self.air_c = target + (self.air_c - target) * math.exp(-rate_max / p.control_band_c * dt)
        # unit: air -> mount -> die, conductance interpolated between vacuum and ambient
        g = p.unit_conductance_per_s(f)
        a = math.exp(-g * dt)
        self.mount_c = self.air_c + (self.mount_c - self.air_c) * a
        die_target = self.mount_c + (p.self_heating_c if self.unit_powered else 0.0)
        self.die_c = die_target + (self.die_c - die_target) * a
        self.pressure = self._pressure_step(self.pressure, dt)

    def _pressure_step(self, pr: float, dt: float) -> float:
        p = self.p
        if self.vent_open:
            # dP/dt = (760 − P)/τ_v − s·P/τ_r : exact exponential toward the equilibrium
            k_in = 1.0 / p.tau_vent_s
            k_out = 1.0 / p.tau_rough_s if self.pump_on else 0.0
            eq = ATMOSPHERE_TORR * k_in / (k_in + k_out)
            return eq + (pr - eq) * math.exp(-(k_in + k_out) * dt)
        if not self.pump_on:
            return ATMOSPHERE_TORR - (ATMOSPHERE_TORR - pr) * math.exp(-p.leak_per_s * dt)
        if pr > p.crossover_torr:
            nxt = pr * math.exp(-dt / p.tau_rough_s)
            if nxt >= p.crossover_torr:
                return nxt
            # the rest of the step on the turbo
            dt -= p.tau_rough_s * math.log(pr / p.crossover_torr)
            pr = p.crossover_torr
        return max(p.ultimate_torr, 1.0 / (1.0 / pr + dt / p.turbo_k_torr_s))

    # ---- history ---------------------------------------------------------------------------
    def _record(self) -> None:
        i = self._hist_n % self._hist_t.shape[0]
        self._hist_t[i] = self._t
        self._hist_die[i] = self.die_c
        self._hist_mount[i] = self.mount_c
        self._hist_air[i] = self.air_c
        self._hist_p[i] = self.pressure
        self._hist_n += 1

    def _query(self, t_s, which: str):
        with self._lock:
            scalar = isinstance(t_s, float) or np.ndim(t_s) == 0
            t_max = float(t_s) if scalar else float(np.max(t_s))
            self.advance(t_max)
            if scalar and t_s == self._t:
                return self.die_c if which == "die" else self.mount_c if which == "mount" else self.air_c if which == "air" else self.pressure
            n = self._hist_t.shape[0]
            if self._hist_n <= n:
                order = np.arange(self._hist_n)
            else:
                start = self._hist_n % n
                order = np.concatenate([np.arange(start, n), np.arange(start)])
            series = {"die": self._hist_die, "mount": self._hist_mount, "air": self._hist_air, "p": self._hist_p}[which]
            return np.interp(t_s, self._hist_t[order], series[order])
