"""``bench.analysis.diagnose.confounded``: a temperature cubic that one run cannot tell from a drift in
time is said, one the temperature's moves against time pin down is not (docs/diagnose.md, Output,
"A temperature that moved only with time"; issue 32).

The temperatures are constructions (ours): a die self-heating 4 °C after power-on (NPSAT1 IV.B.3,
the simulator's ``self_heating_c``) read at 0.01 °C, and a chamber cycle like the tvac session's.
The runs through ``diagnose`` (the S5 hours, the tvac sessions, the CATS log, the recorded ramp)
are in tests/test_diagnose_self_heating.py (slow), tests/test_diagnose.py and
tests/test_diagnose_runfile.py. Well under a second.
"""

from __future__ import annotations

import numpy as np
import pytest

from bench.analysis.diagnose.confounded import CHI2_MATERIAL, line, temperature_in_time

T = np.arange(3600.0)
DIE = np.round((20.0 + 4.0 * (1.0 - np.exp(-T / 292.0))) / 0.01) * 0.01
SIGMA = {"y": 0.011}  # deg/s, white noise at 1 Hz (the test sessions' generator)


def chamber_cycle(t: np.ndarray) -> np.ndarray:
    """20 °C → 50 °C at 1 °C/min, held, → 10 °C, held (°C)."""
    return np.interp(t, [0, 300, 2100, 2700, 3000, 3600], [20, 25, 50, 50, 10, 10])


def test_a_self_heating_die_is_said_with_its_figures():
    # k = −0.032 deg/s/°C: 0.128 deg/s over the 4 °C the die rises (the warm-up the cubic took)
    out = temperature_in_time(T, DIE, T, {"y": [0.0, -0.032, 0.0, 0.0]}, SIGMA)
    e = out["y"]
    assert e["held_dps"] == pytest.approx(0.128, rel=0.01) and e["first_last_dps"] == pytest.approx(0.128, rel=0.01)
    assert e["monotone"] and e["since_power_on"] and e["chi2_not_in_time"] <= CHI2_MATERIAL < e["chi2"]
    text = line(e)
    assert text.startswith("y: the temperature coefficient holds 0.128 deg/s over the run") and \
        "time since power-on (20.0 → 24.0 °C" in text and "temperature cycle" in text, text
    # a curved cubic in the same die, −0.02·(T − 20) + 0.003·(T − 20)² deg/s: still a function of time
    curved = np.polynomial.Polynomial([0.0, -0.02, 0.003])(np.polynomial.Polynomial([-20.0, 1.0])).coef
    assert "y" in temperature_in_time(T, DIE, T, {"y": list(curved) + [0.0]}, SIGMA)


def test_a_chamber_cycle_or_an_immaterial_cubic_is_not_said():
    assert temperature_in_time(T, chamber_cycle(T), T, {"y": [0.0, -0.032, 0.0, 0.0]}, SIGMA) == {}
    # 0.002 deg/s over the die's rise: Σ(c − c̄)²/σ² below χ²₃ at 99.9 %
    small = temperature_in_time(T, DIE, T, {"y": [0.0, -0.0005, 0.0, 0.0]}, SIGMA, every_axis=True)["y"]
    assert not small["said"] and small["chi2"] < CHI2_MATERIAL


def test_without_power_on_a_rise_from_the_first_row_is_still_a_drift_in_time():
    e = temperature_in_time(T, DIE, None, {"y": [0.0, -0.032, 0.0, 0.0]}, SIGMA)["y"]
    assert not e["since_power_on"] and "moved only with time (" in line(e)
