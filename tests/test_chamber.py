"""Chamber physics: the qualitative and quantitative behaviour of NPSAT1's thermal-vacuum tests."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.sim.chamber import Chamber, ChamberParams


def settling_time_s(chamber: Chamber, t_on: float, horizon_s: float, fraction: float = 0.95) -> float:
    """Time after power-on at ``t_on`` until the die has made ``fraction`` of its self-heating rise."""
    t = t_on + np.arange(0.0, horizon_s, 10.0)
    # ask in time order, an hour at a time, as a sensor simulator does (the history is bounded)
    die = np.concatenate([chamber.unit_temperature_c(chunk) for chunk in np.array_split(t, max(1, int(horizon_s // 3600)))])
    rise = die - die[0]
    final = chamber.p.self_heating_c
    reached = np.nonzero(rise >= fraction * final)[0]
    return float(t[reached[0]] - t_on) if reached.size else math.inf


def test_warm_up_transient_is_minutes_in_ambient_and_over_an_hour_in_vacuum():
    ambient = Chamber()
    ambient.set_unit_power(0.0, True)
    t_amb = settling_time_s(ambient, 0.0, 3600.0)

    vacuum = Chamber()
    vacuum.set_pump(0.0, True)
    vacuum.advance(4 * 3600.0)
    assert vacuum.pressure_torr(4 * 3600.0) < 1e-4
    vacuum.set_unit_power(4 * 3600.0, True)
    t_vac = settling_time_s(vacuum, 4 * 3600.0, 6 * 3600.0)
    # NPSAT1 IV.D.4: ~5 min in ambient, 1-1.5 h in vacuum
    assert 3 * 60 <= t_amb <= 8 * 60
    assert 3600 <= t_vac <= 2 * 3600
    assert t_vac > 5 * t_amb


def test_pump_down_follows_the_npsat1_soak_pressures():
    c = Chamber()
    c.set_pump(0.0, True)
    p_1h, p_5h, p_8h = (c.pressure_torr(h * 3600.0) for h in (1, 5, 8))
    assert 1e-3 > p_1h > p_5h > p_8h >= c.p.ultimate_torr
    # NPSAT1 IV.D.4: 4.6e-5 Torr at the start of a 5-hour soak, 1.2e-5 Torr at its end (P ~ 1/t)
    t_start = c.p.turbo_k_torr_s / 4.6e-5
    assert c.pressure_torr(t_start + 5 * 3600.0) == pytest.approx(1.2e-5, rel=0.15)
    # the thermal ramps ran at ~1e-5 Torr
    assert p_8h < 2e-5


def test_vent_returns_to_atmosphere_and_pump_with_vent_open_settles_at_190_torr():
    c = Chamber()
    c.set_pump(0.0, True)
    c.advance(3600.0)
    c.set_pump(3600.0, False)
    c.set_vent(3600.0, True)
    assert c.pressure_torr(3600.0 + 900.0) == pytest.approx(760.0, rel=1e-3)
    c.set_pump(5000.0, True)
    assert c.pressure_torr(7000.0) == pytest.approx(190.0, rel=1e-3)


def test_leak_up_with_pump_off_matches_the_noise_test():
    c = Chamber()
    c.set_pump(0.0, True)
    t = 0.0
    while c.pressure_torr(t) > 190.0:
        t += 1.0
    c.set_pump(t, False)
    # NPSAT1 IV.D.1: valves closed, pump off, 190 -> 250 Torr in 1748 s
    assert c.pressure_torr(t + 1748.0) == pytest.approx(250.0, abs=3.0)


def test_air_ramps_at_the_set_rate_and_unit_lags_more_in_vacuum():
    def ramp(vacuum: bool) -> tuple[float, float]:
        c = Chamber()
        t0 = 0.0
        if vacuum:
            c.set_pump(0.0, True)
            t0 = 4 * 3600.0
            c.advance(t0)
        c.command_ramp_rate(t0, 0.1)
        c.command_set_point(t0, 0.0)
        t1 = t0 + 100 * 60.0
        slope = (c.air_temp_c(t1) - c.air_temp_c(t1 - 600.0)) / 10.0  # degC/min
        lag = c.mount_temp_c(t1) - c.air_temp_c(t1)
        return slope, lag

    slope_amb, lag_amb = ramp(False)
    slope_vac, lag_vac = ramp(True)
    assert slope_amb == pytest.approx(-0.1, rel=0.05)
    assert slope_vac == pytest.approx(-0.1, rel=0.05)
    assert 0 < lag_amb < lag_vac


def test_step_change_is_limited_by_the_heater():
    c = Chamber()
    c.command_set_point(0.0, 66.0)
    rise_10min = c.air_temp_c(600.0) - 20.0
    assert rise_10min == pytest.approx(0.62 * 10, rel=0.05)  # NPSAT1 TVAC2-2a warm-up rate
    assert c.output_pct(600.0) == pytest.approx(100.0)
    assert c.air_temp_c(4 * 3600.0) == pytest.approx(66.0, abs=0.01)


def test_set_point_outside_limits_is_refused():
    c = Chamber()
    with pytest.raises(ValueError, match="outside"):
        c.command_set_point(0.0, 150.0)
    assert c.set_point_c == 20.0


def test_history_is_bounded_and_queries_of_recent_times_interpolate():
    c = Chamber(ChamberParams(history_s=600.0))
    c.command_set_point(0.0, 30.0)
    c.advance(10 * 3600.0)
    assert c._hist_t.shape[0] <= 602  # memory flat in run length
    recent = c.unit_temperature_c(np.array([10 * 3600.0 - 300.0, 10 * 3600.0]))
    assert np.all(np.abs(recent - 30.0) < 0.01)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.floats(1.0, 5000.0), st.sampled_from(["pump", "vent", "sp"]), st.booleans()), max_size=8))
def test_pressure_and_temperatures_stay_physical(commands):
    c = Chamber()
    t = 0.0
    for dt, what, flag in commands:
        t += dt
        if what == "pump":
            c.set_pump(t, flag)
        elif what == "vent":
            c.set_vent(t, flag)
        else:
            c.command_set_point(t, 60.0 if flag else -30.0)
        p = c.pressure_torr(t)
        assert c.p.ultimate_torr <= p <= 760.0 + 1e-9
        assert -40.0 - 1e-9 <= c.air_temp_c(t) <= 100.0 + 1e-9
