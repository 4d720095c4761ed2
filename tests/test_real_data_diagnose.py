"""``bench diagnose`` on real gyro noise nobody here wrote (tests/realdata.py: fetched from the package
index, never committed; skipped with the reason when it cannot be fetched).

What must hold, from physics and from the issue, not from what our code printed once:

* **A still sensor is noise.** The Samsung S5 phone lying still for 6 h and the CATS tag's static
  stretches (between its handlings): no deterministic finding, nothing unexplained, the noise terms
  named with IEEE 952 read-outs. The S5 read-outs are checked against allantools' figures for the
  same log (docs/noise.md: bias instability 25.8 / 34.6 / 19.7 deg/h as minimum/0.664).
* **Effects are found inside real noise.** A generated thermal-vacuum session whose white noise is
  replaced by a stretch of real noise (axes shuffled, place drawn from the seed), with one effect of
  each kind hidden in it (shapes written from the documents, ``tests/diagnose_shapes.py``, scaled
  so they stand above that noise), named exactly: no other deterministic name on any axis (noise
  terms of the background are the background's), nothing unexplained; with nothing hidden, no
  deterministic name; an effect nobody named, unexplained.
"""

from __future__ import annotations

import os
import zlib

import numpy as np
import pytest

from bench.analysis.dataset import load_dataset
from bench.analysis.diagnose import diagnose
from bench.sessions import BaselineSensor, make_session
from tests.diagnose_shapes import (INDEPENDENT, S5_MAP, SETTLE_S, background, extra, scale_against, shape_leftover,
                                   static_datasets)

NOISE_TERMS = {"bias_instability", "rate_random_walk", "gauss_markov"}
SLOW = os.environ.get("BENCH_SLOW") == "1"


def _seed(*parts: object) -> int:
    return zlib.crc32("/".join(map(str, parts)).encode())


def deterministic(result) -> list[tuple[str, str]]:
    return sorted((f.effect, f.axis) for f in result.findings if f.effect not in NOISE_TERMS)


def check_noise_only(result, where: str, axes: str = "xyz") -> None:
    """No deterministic finding, nothing unexplained, and the noise terms named on every axis with the
    IEEE 952 read-outs of its residual: angle random walk always, and every correlated term of the
    axis' model as a finding. An axis whose model is white must be white by the Allan read-out too:
    no bias-instability floor resolved (at most an estimate at the curve's minimum). ``axes``: the
    axes checked (deterministic names are checked on every axis)."""
    assert deterministic(result) == [], (where, [(f.effect, f.axis, f.params) for f in result.findings])
    assert [u for u in result.unexplained if u["axis"] in axes] == [], (where, result.unexplained)
    for a, sec in result.noise.items():
        if a not in axes:
            continue
        ro = sec["ieee952"]
        assert sec["named"][0] == "angle_random_walk", (where, a, sec["named"])
        assert ro["arw_deg_per_sqrt_h"] is not None and ro["arw_deg_per_sqrt_h"] > 0, (where, a, ro)
        model = sec["model"]
        correlated = [k for k, v in (("bias_instability", model["bias_instability_deg_per_h"]),
                                     ("rate_random_walk", model["rrw_deg_per_h_per_sqrt_h"])) if v is not None]
        correlated += ["gauss_markov"] * len(model["gauss_markov"])
        assert sorted(sec["named"][1:]) == sorted(correlated), (where, a, sec["named"], sec["describe"])
        assert sorted(f.effect for f in result.findings if f.axis == a) == sorted(correlated), (where, a)
        if not correlated:  # white by the model: then no resolved floor in the Allan curve either
            assert ro["bias_instability_deg_per_h"] is None or ro["bias_instability_read"]["estimate_only"], (where, a, ro)


# ---- a still sensor is noise --------------------------------------------------------------------------
S5_B_ALLANTOOLS = {"x": 25.8, "y": 34.6, "z": 19.7}
"""deg/h: minimum of allantools' overlapping ADEV / 0.664 on the S5 log (docs/noise.md, issue 16)."""


def test_phone_at_rest_is_noise_with_its_read_outs(real_log):
    ds = load_dataset(real_log("samsung_galaxy_s5.nc"), mapping=S5_MAP)
    result = diagnose(ds)
    check_noise_only(result, "S5")
    assert all(sec["whitened"] for sec in result.noise.values())  # flicker on every axis (allantools' B below)
    p, _ = result._internal
    assert p.raw_rows + p.motion[0] == 214_800 and p.bin_rows > 1  # 6 h at 10 Hz as bin means
    for a, b_ref in S5_B_ALLANTOOLS.items():
        b = result.noise[a]["ieee952"]["bias_instability_deg_per_h"]
        assert b is not None and 0.75 * b_ref <= b <= 1.3 * b_ref, (a, b, b_ref)
        # the model's white part is the Allan −½ line's ARW (z's 0.12-Hz hump lies past the 5-s bins'
        # Nyquist frequency: white noise there, not a Gauss-Markov term that takes the white part)
        arw_model = result.noise[a]["model"]["arw_deg_per_sqrt_h"]
        arw_allan = result.noise[a]["ieee952"]["arw_deg_per_sqrt_h"]
        assert 0.85 * arw_allan <= arw_model <= 1.15 * arw_allan, (a, arw_model, arw_allan)
    doc = result.json
    assert set(doc["noise"]) == {"x", "y", "z"} and "model" in doc["noise"]["x"]


def _after_handling(ds, settle_s: float = SETTLE_S):
    """The stretch from ``settle_s`` after the handling that began it, time from 0."""
    from bench.analysis.dataset import Dataset

    t = ds["time_s"]
    sub = ds.select(np.flatnonzero(t >= t[0] + settle_s))
    sub.columns["time_s"] = sub.columns["time_s"] - sub.columns["time_s"][0]
    return Dataset(sub.columns, dict(ds.meta), f"{ds.source} from {settle_s:.0f} s")


def _hours(ds) -> float:
    return round(len(ds) / 3600.0, 1)


TAG_STRETCHES = {"rows 374-92427": 25.6, "rows 92894-138196": 12.6, "rows 138367-183831": 12.6, "rows 184750-268081": 23.1}
"""The CATS tag's static stretches (hours), by where they lie in the log (``static_datasets``)."""


@pytest.mark.slow
@pytest.mark.parametrize("rows", list(TAG_STRETCHES))
def test_tag_at_rest_is_noise_an_hour_after_handling(real_log, rows):
    """The CATS tag's static stretches from an hour after handling (the first hour holds its settling,
    below) are noise: no deterministic name, nothing unexplained, the noise terms named on every axis
    with their read-outs; white (angle random walk alone) where 12 h with a temperature ramp leave no
    resolved slow noise (the Allan read-out agreeing: no floor). The 23.1-h stretch's x holds a real
    bias excursion (below): unexplained there, y and z noise."""
    real_log("cats_temperature_calib.nc")
    stretches = static_datasets("cats")
    assert sorted(map(_hours, stretches)) == sorted(TAG_STRETCHES.values())
    ds = next(d for d in stretches if rows in d.source)
    assert _hours(ds) == TAG_STRETCHES[rows]
    result = diagnose(_after_handling(ds))
    if _hours(ds) == 23.1:
        assert [u["axis"] for u in result.unexplained] == ["x"], (ds.source, result.unexplained)
        check_noise_only(result, ds.source, axes="yz")
    else:
        check_noise_only(result, ds.source)


@pytest.mark.slow
def test_tag_settling_after_handling_is_not_noise(real_log):
    """The 12.6-h stretch whose first hour is the tag's settling after handling (temperature 14.8 ->
    6.0 degC, the x bias moving 0.08 deg/s in its first 10 minutes, z 0.07 deg/s over 40 minutes):
    that hour is structure, not noise, and the vocabulary has no name for it: unexplained on x and z,
    no deterministic name. (The same stretch from an hour on is noise: the test above.)"""
    real_log("cats_temperature_calib.nc")
    ds = next(d for d in static_datasets("cats") if d.source.endswith("rows 92894-138196"))
    result = diagnose(ds)
    assert deterministic(result) == [], deterministic(result)
    assert sorted(u["axis"] for u in result.unexplained) == ["x", "z"], result.unexplained


@pytest.mark.slow
def test_tag_bias_excursion_is_unexplained(real_log):
    """The 23.1-h stretch: x's bias falls 0.16 deg/s over 6 h and then rises 0.23 deg/s within
    90 minutes (at 8.6-9.5 degC, 7-8.5 h in), the accelerometer flat to 1 mg (the tag did not move),
    y and z untouched, no change of the temperature rate that a lag or a gradient term would follow:
    a bias excursion of one axis the vocabulary has no name for. Unexplained on x, never a noise
    term or a deterministic name there."""
    real_log("cats_temperature_calib.nc")
    ds = next(d for d in static_datasets("cats") if _hours(d) == 23.1)
    result = diagnose(ds)
    assert deterministic(result) == [], deterministic(result)
    assert [u["axis"] for u in result.unexplained] == ["x"], result.unexplained
    assert not any(f.axis == "x" for f in result.findings), [(f.effect, f.axis) for f in result.findings]
    assert result.noise["x"]["named"] == ["angle_random_walk"]


# ---- effects inside real noise ----------------------------------------------------------------------
def hidden_effect(name: str, rng: np.random.Generator, mount: str, scale: float, session, base: BaselineSensor) -> dict:
    """Parameters of one effect of kind ``name`` at bench sizes (tests/test_diagnose.py's ranges)
    times ``scale`` (so it stands above the background). A thermal lag acts on the sensor's own bias
    cubic (``base``, scaled with it)."""
    from tests.test_diagnose import quiet_instant, random_effect

    e = random_effect(name, rng, base, mount)
    for key in ("amplitude_dps", "shift_dps", "step_dps", "fraction", "asymmetry", "tempco_per_c", "quadratic_per_dps"):
        if key in e["params"]:
            e["params"][key] *= scale
    if name == "g_sensitivity":
        e["params"]["dps_per_g"] = [v * scale for v in e["params"]["dps_per_g"]]
    if name == "thermal_lag":
        k = "xyz".index(e["axis"])
        base.poly_dps[k] = np.asarray(e["params"]["tempco_dps"]) * scale
        e["params"]["tempco_dps"] = base.poly_dps[k].tolist()
    if name == "bias_step":
        e["params"]["t_step_s"] = quiet_instant(session.inputs, e["params"]["t_step_s"])
    return e


def in_background(bg: str, names: list[str], seed: int, duration_s: float = 3600.0):
    """(session, injected entries): a tvac session at 1 Hz whose white noise is the real background."""
    rng = np.random.default_rng([seed, 32])
    mount = str(rng.choice(["z", "x", "-y"]))
    base = BaselineSensor.random(rng, 1.0)
    base.noise_dps = 0.0
    n = int(duration_s)
    sess_seed = int(rng.integers(2**31))
    probe = make_session(duration_s, 1.0, [], seed=sess_seed, mount=mount, base=base)
    scale = scale_against(bg)  # the test ranges are made for 0.011 deg/s of white noise at 1 Hz
    entries = [hidden_effect(nm, rng, mount, scale, probe, base) for nm in names]
    noise = background(bg, n, seed)
    session = make_session(duration_s, 1.0, [], seed=sess_seed, mount=mount, base=base, extra=extra(entries, noise))
    return session, entries


def check_named(bg: str, names: list[str], seed: int) -> None:
    session, entries = in_background(bg, names, seed)
    result = diagnose(session.dataset)
    want = sorted((e["effect"], e["axis"]) for e in entries)
    assert deterministic(result) == want, (bg, entries, [(f.effect, f.axis, f.params) for f in result.findings],
                                           result.unexplained, result.dropped)
    left = shape_leftover(names, result.unexplained)
    assert [u for u in result.unexplained if u not in left] == [], (bg, entries, result.unexplained)


CI_CASES = [("cats", "pressure_bias"), ("cats", "gear_eccentricity"), ("cats", "thermal_lag")]
"""A representative set for CI (the S5 background costs 30-60 s a case on the shared machine: slow suite)."""


@pytest.mark.parametrize("bg,name", CI_CASES, ids=[f"{b}-{n}" for b, n in CI_CASES])
def test_an_effect_in_real_noise_is_named(real_log, bg, name):
    real_log("samsung_galaxy_s5.nc" if bg == "s5" else "cats_temperature_calib.nc")
    check_named(bg, [name], _seed("real", bg, name))


@pytest.mark.parametrize("bg", ["cats", pytest.param("s5", marks=pytest.mark.slow)])
def test_real_noise_alone_names_nothing_deterministic(real_log, bg):
    real_log("samsung_galaxy_s5.nc" if bg == "s5" else "cats_temperature_calib.nc")
    check_named(bg, [], _seed("real", bg, "clean"))


@pytest.mark.slow  # 11 s; the suite was 893 s of its 900-s limit on the shared VM (2026-11-28); the unit test of
# noise_model.with_slow_part stays in CI
def test_the_phone_wander_on_an_axis_without_a_slow_part_is_noise(real_log):
    """The S5 sweep's scale_factor_tempco seed 0 (injected on y, named): y's selected noise model
    is white + the phone's 2.3-s Gauss-Markov hump, the BIC refusing a random walk beside it
    (ΔBIC −1.4), while the time probe finds the phone's wander on y (ΔIC −41). Asked again with its
    best slow part, the wander is within what that model makes (5 and 6 of 99 realisations as
    large): a slow noise term on y that says why it was taken, nothing unexplained (before: y
    "unexplained against time"; docs/diagnose.md, 6b "An axis whose model has no slow part")."""
    real_log("samsung_galaxy_s5.nc")
    session, entries = in_background("s5", ["scale_factor_tempco"], _seed("real", "s5", "scale_factor_tempco", 0))
    assert [(e["effect"], e["axis"]) for e in entries] == [("scale_factor_tempco", "y")]
    result = diagnose(session.dataset)
    assert deterministic(result) == [("scale_factor_tempco", "y")], result.findings
    assert result.unexplained == [], result.unexplained
    slow = [f for f in result.findings if f.axis == "y" and f.effect in ("rate_random_walk", "bias_instability")
            or f.axis == "y" and f.effect == "gauss_markov" and f.params["tau_s"] >= 20.0]
    assert len(slow) == 1 and "within what this model makes" in slow[0].evidence["asked"], slow


def test_a_wandering_real_noise_hour_names_nothing(real_log):
    """The S5 background hour drawn for the warm-up's seed 0 (the phone 2.5-3.5 h into its log), with
    nothing injected: the phone's common-mode bias wander in it took a warm-up's shape on one axis
    and a bias step's on another (ΔBIC −20.0 and −21.5 against the best noise-only model) until the
    threshold paid for the many slow shapes the search tries (docs/diagnose.md, against the
    sensor's slow noise). Noise: no deterministic name, nothing unexplained."""
    real_log("samsung_galaxy_s5.nc")
    check_named("s5", [], _seed("real", "s5", "warmup_transient", 0))


@pytest.mark.slow
def test_the_s5_hour_of_the_bump_seed_1_names_nothing(real_log):
    """The background hour of the bump test's S5 seed 1 (``test_an_effect_nobody_named_in_real_noise_is_unexplained``
    at S5), with nothing injected: no deterministic name, nothing unexplained. Found by a bump study (the
    bump was on z; the warm-up on y came with or without it). The phone's wander on y takes a warm-up's
    shape (-0.042 deg/s, τ 1159 s) whose τ interval [531, 1200] s reaches the top of its grid: one run
    does not bound it, so it is not named (docs/diagnose.md, Power-on); y's drift is left to its noise
    model (before: named ``warmup_transient:y``)."""
    real_log("samsung_galaxy_s5.nc")
    seed = _seed("real", "s5", "bump", 1)
    base = BaselineSensor.random(np.random.default_rng(seed), 1.0)
    base.noise_dps = 0.0
    noise = background("s5", 3600, seed)
    result = diagnose(make_session(3600, 1.0, [], seed=seed, base=base, extra=lambda inp: noise.copy()).dataset)
    assert deterministic(result) == [], [(f.effect, f.axis, f.params) for f in result.findings]
    assert result.unexplained == [], result.unexplained


REAL_NOISE_MISSES = {
    ("s5", "warmup_transient", 2): "a warm-up of 0.16 deg/s, τ 292 s, is taken into a rate_random_walk on its axis "
                                   "(uneven p 0.009; time probe ΔIC -327 matched by 1 of 99 realisations of the fitted "
                                   "walk; best warm-up ΔIC -125 matched by 6 of 99): the finding carries the warm-up "
                                   "as what one run cannot tell from the walk (6 of 99). The early slow increments "
                                   "(1 of 99) and the shape against the walk (-7.8, 0 of 99) separate it, but also "
                                   "give a wrong warmup_transient in the S5 periodic seed 1 case: not used. The early quarter "
                                   "against the model refitted on the rest (17.7, 0 of 99) is as large on S5 hours with "
                                   "nothing injected (21.3 on the clean hour's y, 0 of 99): not used. Given a second "
                                   "run from power-on, it is named across runs (tests/test_diagnose_runs.py)",
}
"""Sweep cases that still fail (misses, never a wrong name), each with what happens: strict xfail
(docs/diagnose.md, known limits)."""


@pytest.mark.slow
@pytest.mark.parametrize("bg,name,seed", [
    pytest.param(bg, name, seed, marks=pytest.mark.xfail(strict=True, reason=REAL_NOISE_MISSES[(bg, name, seed)]))
    if (bg, name, seed) in REAL_NOISE_MISSES else (bg, name, seed)
    for bg in ("s5", "cats") for name in INDEPENDENT for seed in range(3)])
def test_every_kind_in_real_noise(real_log, bg, name, seed):
    real_log("samsung_galaxy_s5.nc" if bg == "s5" else "cats_temperature_calib.nc")
    check_named(bg, [name], _seed("real", bg, name, seed))


def test_an_effect_nobody_named_in_real_noise_is_unexplained(real_log):
    """A bias bump (outside the vocabulary: 0.04 deg/s for a few minutes mid-run) in the CATS
    background: unexplained on its axis, no name on it, no deterministic name anywhere. (A straight
    drift over one run would be taken as a random walk: docs/diagnose.md, 6b.)"""
    real_log("cats_temperature_calib.nc")
    seed = _seed("real", "cats", "bump")
    rng = np.random.default_rng(seed)
    base = BaselineSensor.random(rng, 1.0)
    base.noise_dps = 0.0
    k = int(rng.integers(3))
    noise = background("cats", 3600, seed)
    size = 0.04 * scale_against("cats")

    def drift(inp):
        out = noise.copy()
        out[:, k] += size * np.exp(-0.5 * ((inp.time_s - 1900.0) / 150.0) ** 2)
        return out

    result = diagnose(make_session(3600, 1.0, [], seed=seed, base=base, extra=drift).dataset)
    assert deterministic(result) == [], [(f.effect, f.axis) for f in result.findings]
    assert "xyz"[k] in {u["axis"] for u in result.unexplained}, result.unexplained
    assert not any(f.axis == "xyz"[k] for f in result.findings), [(f.effect, f.axis) for f in result.findings]
