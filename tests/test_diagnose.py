"""``bench diagnose``: hidden effects in simulated sessions must be named exactly, clean sessions
must give nothing, and the extended model must close the loop.

Sessions come from ``bench/sessions.py`` (thermal cycle with continuous rate steps, pump-down
and vent, tilt changes, power-on at the start; the ESTCube-2 stepper bench). Hidden effects get
random parameters from seeds derived here (``_seed``), never passed to ``diagnose``: it only sees
the measured columns and the CSV-style metadata (sample rate, latitude).

Default run: one-hour sessions at 1 Hz (3,600 rows) and 10 Hz (36,000 rows). ``BENCH_SLOW=1`` adds
8-hour 1 Hz and 2-hour 10 Hz sessions for every vocabulary term and more seeds.
"""

from __future__ import annotations

import math
import zlib

import numpy as np
import pytest
import yaml

from bench.analysis.dataset import Dataset, load_dataset
from bench.analysis.diagnose import diagnose, write_report
from bench.errors import InputError
from bench.model import effects as fx
from bench.sessions import BaselineSensor, make_session, write_csv
from tests.diagnose_shapes import shape_leftover

VOCABULARY = [
    "thermal_lag", "warmup_transient", "pressure_bias", "gear_eccentricity", "g_sensitivity",
    "scale_factor_asymmetry", "scale_factor_tempco", "hysteresis", "time_skew", "rate_random_walk", "earth_rate",
    "bias_step", "periodic", "scale_factor_nonlinearity", "bias_instability", "gauss_markov",
]
RATE_DEPENDENT = {"gear_eccentricity", "scale_factor_asymmetry", "scale_factor_tempco", "scale_factor_nonlinearity"}
NOISE_TERMS = {"rate_random_walk", "bias_instability", "gauss_markov"}
PAIRS = [
    ("thermal_lag", "pressure_bias"),
    ("warmup_transient", "hysteresis"),
    ("gear_eccentricity", "g_sensitivity"),
    ("scale_factor_asymmetry", "time_skew"),
    ("rate_random_walk", "earth_rate"),
    ("scale_factor_tempco", "warmup_transient"),
    ("thermal_lag", "hysteresis"),
    ("pressure_bias", "g_sensitivity"),
]


def _seed(*parts: object) -> int:
    """A test-local seed from a description (stable across runs, unknown to the code under test)."""
    return zlib.crc32("/".join(map(str, parts)).encode())


def _sign(rng: np.random.Generator) -> float:
    return 1.0 if rng.random() < 0.5 else -1.0


def random_effect(name: str, rng: np.random.Generator, base: BaselineSensor, mount: str) -> dict:
    """A hidden effect with random, physically plausible and detectable parameters.

    Ranges: warm-up 0.01-0.03 deg/s, τ 60-400 s (NPSAT1 IV.A: 0.017-0.024 deg/s, 5-12 min
    settling); vacuum shift 0.01-0.05 deg/s (NPSAT1 V: ~0.01-0.05), p0 1e-3-1 Torr; hysteresis
    ±0.004-0.015 deg/s; worm gear 0.05-0.3 % of the rate at N = 1-200; g-sensitivity 0.01-0.04
    deg/s/g; scale-factor asymmetry 0.05-0.3 %, tempco 30-150 ppm/°C; delays 20-200 ms; random
    walk 1e-4-4e-4 deg/s/√s; thermal lag τ 2-15 min on the sensor's own bias cubic; bias steps
    0.01-0.04 deg/s (placed by :func:`hidden_session` where no covariate moves); periodic
    interference 0.006-0.02 deg/s at 0.003-0.3 Hz; scale-factor curvature 2e-5-1e-4 per deg/s
    (0.8-4 % at 20 deg/s... i.e. 0.008-0.04 deg/s); flicker B = 4-11 deg/h; Gauss-Markov noise
    0.008-0.02 deg/s with τ_c 20-300 s."""
    axis = mount.lstrip("+-") if name in RATE_DEPENDENT else str(rng.choice(["x", "y", "z"]))
    k = "xyz".index(axis)
    if name == "thermal_lag":
        base.poly_dps[k, 0] = _sign(rng) * rng.uniform(0.006, 0.015)
        params = {"tau_s": float(math.exp(rng.uniform(math.log(120), math.log(900)))),
                  "tempco_dps": base.poly_dps[k].tolist()}
    elif name == "warmup_transient":
        params = {"amplitude_dps": _sign(rng) * rng.uniform(0.01, 0.03), "tau_s": rng.uniform(60, 400)}
    elif name == "pressure_bias":
        params = {"shift_dps": _sign(rng) * rng.uniform(0.01, 0.05), "p0_torr": float(10 ** rng.uniform(-3, 0))}
    elif name == "gear_eccentricity":
        params = {"fraction": rng.uniform(5e-4, 3e-3), "harmonic": int(rng.integers(1, 201)),
                  "phase_rad": rng.uniform(0, 2 * math.pi)}
    elif name == "g_sensitivity":
        v = rng.normal(size=3)
        params = {"dps_per_g": (v / np.linalg.norm(v) * rng.uniform(0.01, 0.04)).tolist()}
    elif name == "scale_factor_asymmetry":
        params = {"asymmetry": _sign(rng) * rng.uniform(5e-4, 3e-3)}
    elif name == "scale_factor_tempco":
        params = {"tempco_per_c": _sign(rng) * rng.uniform(3e-5, 1.5e-4)}
    elif name == "hysteresis":
        params = {"amplitude_dps": _sign(rng) * rng.uniform(0.004, 0.015), "deadband_c": rng.uniform(0.2, 1.0)}
    elif name == "time_skew":
        axis, params = "all", {"delay_s": _sign(rng) * rng.uniform(0.02, 0.2)}
    elif name == "rate_random_walk":
        params = {"k_dps_per_sqrt_s": rng.uniform(1e-4, 4e-4)}
    elif name == "earth_rate":
        axis, params = "all", {}
    elif name == "bias_step":
        params = {"step_dps": _sign(rng) * rng.uniform(0.01, 0.04), "t_step_s": rng.uniform(0.15, 0.85)}
    elif name == "periodic":
        params = {"amplitude_dps": rng.uniform(0.006, 0.02), "frequency_hz": float(math.exp(rng.uniform(math.log(3e-3), math.log(0.3)))),
                  "phase_rad": rng.uniform(0, 2 * math.pi)}
    elif name == "scale_factor_nonlinearity":
        params = {"quadratic_per_dps": _sign(rng) * rng.uniform(2e-5, 1e-4)}
    elif name == "bias_instability":
        params = {"b_dps": rng.uniform(4.0, 11.0) / 3600.0}
    elif name == "gauss_markov":  # a correlated-noise hump the record resolves (τ_c ≤ a tenth of it)
        params = {"sigma_dps": rng.uniform(0.008, 0.02), "tau_s": float(math.exp(rng.uniform(math.log(20), math.log(300))))}
    else:  # pragma: no cover - the list above is the vocabulary
        raise AssertionError(name)
    return {"effect": name, "axis": axis, "params": params}


def hidden_session(names: list[str], seed: int, rate_hz: float = 1.0, duration_s: float = 3600.0, kind: str = "tvac",
                   shapes: bool = False):
    """A session with the named hidden effects; returns (session, injected effect entries). With
    ``shapes`` the effects that ``tests/diagnose_shapes.py`` writes from the documents are added
    through those shapes (independent of ``bench/model/effects.py``), the others by the generator."""
    rng = np.random.default_rng([seed, 7919])
    base = BaselineSensor.random(rng, rate_hz)
    mount = str(rng.choice(["z", "z", "x", "y", "-z"])) if kind == "tvac" else "z"
    lat = float(rng.uniform(-60, 60))
    effects = [random_effect(n, rng, base, mount) for n in names]
    seed = int(rng.integers(2**31))
    for e in effects:
        if e["effect"] == "bias_step":  # a fraction of the session -> a quiet instant near it
            probe = make_session(duration_s, rate_hz, [], seed=seed, kind=kind, mount=mount, latitude_deg=lat, base=base)
            e["params"]["t_step_s"] = quiet_instant(probe.inputs, e["params"]["t_step_s"])
    from tests.diagnose_shapes import INDEPENDENT, extra

    own = [e for e in effects if shapes and e["effect"] in INDEPENDENT]
    gen = [e for e in effects if e not in own]
    session = make_session(duration_s, rate_hz, gen, seed=seed, kind=kind, mount=mount,
                           latitude_deg=lat, base=base, extra=extra(own) if own else None)
    return session, effects


def quiet_instant(inputs, fraction: float, window_s: float = 150.0) -> float:
    """The time nearest ``fraction`` of the session at which, for ±``window_s``, the specific force,
    the pressure and the temperature trend stay put: a bias step there is a step of the sensor, not
    of a covariate (the test's own knowledge of the generator)."""
    t = inputs.time_s
    dt = float(t[1] - t[0])
    w = max(int(window_s / dt), 1)
    moving = np.zeros(t.size, bool)
    k_axis = int(np.argmax(np.abs(inputs.rate_dps).mean(axis=0)))  # the table axis: gravity along it moves with the tilt only
    moving[1:] |= np.abs(np.diff(inputs.specific_force_g[:, k_axis])) > 1e-6
    if inputs.pressure_torr is not None:
        lp = np.log10(np.clip(inputs.pressure_torr, 1e-12, None))
        moving[1:] |= np.abs(np.diff(lp)) > 1e-3 * dt
    k = max(int(120.0 / dt), 1)
    d = np.gradient(np.convolve(np.pad(inputs.temp_c, k, mode="edge"), np.ones(2 * k + 1) / (2 * k + 1), mode="valid"), t)
    trend = np.zeros(t.size, bool)
    trend[w:-w] = np.abs(d[2 * w:] - d[:-2 * w]) > 0.1 * np.max(np.abs(d))
    moving |= trend
    for width in (w, w // 2, w // 4, 1):  # the widest quiet window this session has
        near = np.convolve(moving.astype(float), np.ones(2 * width + 1), mode="same") > 0
        ok = np.flatnonzero(~near & (t > 0.1 * t[-1]) & (t < 0.9 * t[-1]))
        if ok.size:
            return float(t[ok[np.argmin(np.abs(t[ok] - fraction * t[-1]))]])
    raise AssertionError("no quiet instant in this session")


def named(result) -> list[tuple[str, str]]:
    return sorted((f.effect, f.axis) for f in result.findings)


def injected(effects: list[dict]) -> list[tuple[str, str]]:
    return sorted((e["effect"], e["axis"]) for e in effects)


def check_exact(names: list[str], seed: int, rate_hz: float = 1.0, duration_s: float = 3600.0, shapes: bool = False):
    session, effects = hidden_session(names, seed, rate_hz, duration_s, shapes=shapes)
    result = diagnose(session.dataset)
    assert named(result) == injected(effects), (
        f"injected {effects}\nfound {[(f.effect, f.axis, f.params, f.gain) for f in result.findings]}\n"
        f"unexplained {result.unexplained}\ndropped {result.dropped}")
    left = shape_leftover(names, result.unexplained) if shapes else []
    assert [u for u in result.unexplained if u not in left] == [], result.unexplained  # everything injected has a name
    noisy = {f.axis for f in result.findings if f.effect in NOISE_TERMS} | {u["axis"] for u in left}
    for a, v in result.axes.items():  # the extended model is at the noise floor (flicker stays in the residual)
        if a not in noisy:
            assert v["rms_extended"] <= 1.06 * result.noise_floor[a], (a, v, result.noise_floor)
    return session, effects, result


INDISTINGUISHABLE = {"earth_rate": {"g_sensitivity"}}
"""Hidden effect -> names that are the same regressor for part of it (docs/diagnose.md, what the
engine cannot tell apart): the vertical component of the Earth rate, Ω·sin L along the measured
gravity direction, is exactly a g-sensitivity."""


def check_unexplained(names: list[str], seed: int, rate_hz: float = 1.0, duration_s: float = 3600.0):
    """The injected effects hidden from the candidate list: no name on ANY axis but the documented
    indistinguishable ones, 'unexplained' on each injected axis."""
    session, effects = hidden_session(names, seed, rate_hz, duration_s)
    result = diagnose(session.dataset, hidden=tuple(names))
    allowed = set().union(*(INDISTINGUISHABLE.get(n, set()) for n in names))
    wrong = [f for f in result.findings if f.effect not in allowed]
    assert wrong == [], (
        f"injected {effects} (hidden)\nnamed {[(f.effect, f.axis, f.params, f.gain) for f in wrong]}")
    axes = {u["axis"] for u in result.unexplained}
    for e in effects:
        if e["axis"] == "all":
            assert axes, (effects, result.unexplained)
        else:
            assert e["axis"] in axes, (effects, result.unexplained, result.dropped)
    for u in result.unexplained:
        assert u["rms_dps"] > 0 and u["where"], u
    return session, effects, result


# ---- the vocabulary's forward functions ---------------------------------------------------------
def test_vocabulary_names():
    assert list(fx.VOCABULARY) == VOCABULARY


def test_earth_rate_matches_the_world_geometry():
    from bench.sim.world import World, WorldParams

    for up in ("z", "x", "-y", "-z"):
        w = World(WorldParams(latitude_deg=36.4))
        w.set_mount(up)
        w.table.tilt.command_position(0.0, 37.0, 5.0)
        w.table.rotation.command_rate(0.0, 3.0)
        t = np.array([100.0, 200.0, 333.0])
        env = w.environment(t)
        earth = env.rate_dps - np.outer(w.table.rotation.rate_dps(t), w.mount[:, 2])
        got = fx.earth_rate_sensor(env.specific_force_g, w.table.rotation.angle_deg(t), 36.4, up)
        np.testing.assert_allclose(got, earth, atol=1e-12)


def test_forward_functions():
    t = np.arange(0.0, 600.0, 0.1)
    rate = np.stack([np.zeros_like(t), np.zeros_like(t), 5 * np.sin(2 * np.pi * t / 60)], axis=1)
    # a small delay is −d·dω/dt
    skew = fx.delayed(t, rate[:, 2], 0.05) - rate[:, 2]
    np.testing.assert_allclose(skew[100:-100], -0.05 * 5 * 2 * np.pi / 60 * np.cos(2 * np.pi * t / 60)[100:-100],
                               atol=2e-4)
    # play operator: up, down, hold
    temp = np.concatenate([np.linspace(20, 30, 100), np.linspace(30, 10, 200), np.full(50, 10.0)])
    s = fx.hysteresis_state(temp, 0.5)
    assert s[0] == 0 and s[99] == 1 and s[120] == -1 and s[-1] == -1
    assert fx.pressure_transition(np.array([1e-8]), 1e-3)[0] == pytest.approx(1, abs=1e-4)
    assert fx.pressure_transition(np.array([760.0]), 1e-3)[0] == pytest.approx(0, abs=1e-5)
    # lag of a ramp settles to ramp·τ behind
    lag = fx.lagged(t, t * 0.01, 30.0)
    assert t[-1] * 0.01 - lag[-1] == pytest.approx(0.3, rel=1e-2)


def test_effect_entries_are_validated():
    inputs = make_session(300, 1.0, seed=1).inputs
    out = np.zeros((inputs.time_s.size, 3))
    with pytest.raises(InputError, match="unknown effect"):
        fx.apply_effects([{"effect": "nonsense", "axis": "x"}], inputs, out)
    with pytest.raises(InputError, match="axis"):
        fx.apply_effects([{"effect": "warmup_transient", "axis": "w"}], inputs, out)
    with pytest.raises(InputError, match="unknown parameter"):
        fx.apply_effects([{"effect": "warmup_transient", "axis": "x", "params": {"tau": 3}}], inputs, out)
    with pytest.raises(InputError, match="tau_s"):
        fx.apply_effects([{"effect": "warmup_transient", "axis": "x", "params": {"tau_s": -1}}], inputs, out)
    with pytest.raises(InputError, match="harmonic"):
        fx.apply_effects([{"effect": "gear_eccentricity", "axis": "z", "params": {"harmonic": 2.5}}], inputs, out)
    # a model file's entries may carry source/description; per-axis lists with axis: all
    y = fx.apply_effects([{"effect": "warmup_transient", "axis": "all", "source": "test",
                           "params": {"amplitude_dps": [0.01, 0.02, 0.03], "tau_s": 100.0}}], inputs, out)
    np.testing.assert_allclose(y[0], [0.01, 0.02, 0.03])


def test_session_engines_agree_and_csv_round_trip(tmp_path):
    base = BaselineSensor.random(np.random.default_rng(3), 1.0)
    base.noise_dps = 0.0
    eff = [{"effect": "thermal_lag", "axis": "z", "params": {"tau_s": 300.0, "tempco_dps": base.poly_dps[2].tolist()}},
           {"effect": "earth_rate", "axis": "all"}]
    a = make_session(1200, 1.0, eff, seed=5, base=base, engine="gyro").dataset
    b = make_session(1200, 1.0, eff, seed=5, base=base, engine="builtin").dataset
    for ax in "xyz":
        np.testing.assert_allclose(a[f"gyro_{ax}_dps"], b[f"gyro_{ax}_dps"], atol=1e-12)
    path = write_csv(a, tmp_path / "s.csv")
    ds = load_dataset(path)
    assert set(ds.columns) == set(a.columns)
    assert ds.latitude_deg() == pytest.approx(36.4)
    np.testing.assert_allclose(ds["gyro_z_dps"], a["gyro_z_dps"], rtol=1e-9, atol=1e-12)


# ---- hidden effects ---------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_clean_session_1hz_names_nothing(seed):
    check_exact([], _seed("clean", 1, seed))


def test_clean_session_10hz_names_nothing():
    check_exact([], _seed("clean", 10, 0), rate_hz=10.0)


KNOWN_MISSES = {
    ("unnamed", "warmup_transient", 1): "a hidden slow warm-up (τ 297 s) passes the stationarity check and is of the "
                                        "size its fitted random walk (K 37 deg/h/√h) makes (time probe ΔIC -1698, 17 of "
                                        "99 realisations as large; the best unhidden named slow shape, a bias step at ΔIC -107, "
                                        "23 of 99: no annotation): named a rate random walk. The early slow increments "
                                        "separate it (1.14 against draws to 1.02) but name a warm-up in the S5 phone's "
                                        "wander (S5 periodic seed 1): not used; the early quarter against the model refitted on the "
                                        "rest does not see it (0.8, 21 of 99). Two runs of the unit separate it: "
                                        "unexplained across runs (bench diagnose A B, tests/test_diagnose_runs.py)",
}
"""CI cases that still fail, each with what happens: strict xfail, so a fix shows as XPASS and fails
until the mark is removed (docs/diagnose.md, known limits)."""


CI_SHAPES = ("warmup_transient", "pressure_bias", "thermal_lag", "hysteresis", "gear_eccentricity", "bias_step",
             "time_skew")
"""Kinds whose document-written shapes (seed 1) run in CI; every kind's runs in the slow suite."""


def _cases(kind: str, seeds, names=VOCABULARY) -> list:
    out = []
    for name in names:
        for seed in seeds:
            why = KNOWN_MISSES.get((kind, name, seed))
            out.append(pytest.param(name, seed, marks=pytest.mark.xfail(strict=True, reason=why)) if why else (name, seed))
    return out


@pytest.mark.parametrize("name,seed", _cases("single", [0]) + _cases("single", [1], CI_SHAPES))
def test_single_hidden_effect_1hz(name, seed):
    """Every kind; a second seed for the kinds of CI_SHAPES, which injects the effects that
    tests/diagnose_shapes.py writes from the documents through those shapes (not
    bench/model/effects.py)."""
    check_exact([name], _seed("single", 1, name) if seed == 0 else _seed("single", 1, name, seed), shapes=seed == 1)


@pytest.mark.slow
@pytest.mark.parametrize("name,seed", _cases("single", [1], [n for n in VOCABULARY if n not in CI_SHAPES])
                         + _cases("single", range(2, 8)))
def test_single_hidden_effect_more_seeds(name, seed):
    check_exact([name], _seed("single", 1, name, seed), shapes=seed % 2 == 1)


@pytest.mark.parametrize("name,seed", _cases("unnamed", [0]))
def test_effect_without_its_name_is_unexplained(name, seed):
    """Every kind of effect the generator injects, left out of the candidate list: 'unexplained' on
    the right axis and no wrong name on any axis."""
    check_unexplained([name], _seed("unnamed", 1, name))


@pytest.mark.slow
@pytest.mark.parametrize("name,seed", _cases("unnamed", range(1, 6)))
def test_effect_without_its_name_more_seeds(name, seed):
    check_unexplained([name], _seed("unnamed", 1, name, seed))


def test_slow_structure_larger_than_its_noise_model_is_not_noise():
    """A hidden thermal lag of τ 734 s on z passes the stationarity check as a random walk + Gauss-Markov
    noise; its structure in time (time probe ΔIC about -8300) is far beyond what that model makes in
    any of its realisations, so it is not that noise: z unexplained, no noise name on z
    (docs/diagnose.md, 6b "Larger than the model makes"; before: rate_random_walk + gauss_markov)."""
    _, _, result = check_unexplained(["thermal_lag"], _seed("unnamed", 1, "thermal_lag", 3))
    assert {u["axis"] for u in result.unexplained} == {"z"}, result.unexplained
    assert result.noise["z"]["named"] == ["angle_random_walk"], result.noise["z"]


@pytest.mark.parametrize("seed", [1, 5])
def test_gravity_segments_are_the_stretches_between_tilt_moves(seed):
    """noise.gravity_segments (the slow-structure check's third statistic, docs/diagnose.md 6b): one
    segment per stretch between the table's tilt moves, cut inside each move, from the measured
    accelerometer only. The moves are the test's own knowledge of the generator: where the table's
    rate has a part across its axis (the tilt rate). Seed 5 dwells about 100 s at one tilt."""
    from bench.analysis.diagnose.data import prepare
    from bench.analysis.diagnose.noise import gravity_segments

    session, _ = hidden_session(["earth_rate"], _seed("unnamed", 1, "earth_rate", seed))
    inp = session.inputs
    k = int(np.argmax(np.abs(inp.rate_dps).mean(axis=0)))  # the table axis
    across = np.delete(inp.rate_dps, k, axis=1)
    moving = np.hypot(across[:, 0], across[:, 1]) > 1e-6
    edges = np.flatnonzero(np.diff(np.concatenate([[0], moving.astype(np.int8), [0]])))
    moves = [(inp.time_s[i], inp.time_s[j - 1]) for i, j in zip(edges[::2], edges[1::2])]
    p = prepare(session.dataset)
    labels = gravity_segments(p)
    assert labels is not None
    cuts = p.t[np.flatnonzero(np.diff(labels)) + 1]
    assert len(cuts) == len(moves) >= 3, (cuts, moves)
    for c, (t0, t1) in zip(cuts, moves):
        assert t0 - 10.0 <= c <= t1 + 10.0, (c, t0, t1)


def test_the_named_slow_shape_statistic_uses_only_the_unhidden_vocabulary():
    """noise.shape_d_ic (beyond_noise's second statistic): on a warm-up of τ 297 s on x it is the
    warm-up's ΔIC, far below what any other slow shape makes of it; with the warm-up hidden it is the
    best of the rest (a bias step), and with every slow shape hidden there is nothing to fit."""
    from bench.analysis.diagnose.data import prepare
    from bench.analysis.diagnose.engine import Term, baseline_built, build_state
    from bench.analysis.diagnose.noise import shape_d_ic
    from bench.analysis.diagnose.terms import CANDIDATES

    session, _ = hidden_session(["warmup_transient"], _seed("unnamed", 1, "warmup_transient", 1))
    p = prepare(session.dataset)
    state = build_state(p, [Term("baseline", a, {}, baseline_built(p, a)) for a in p.axes])
    every = shape_d_ic(p, state, "x")
    rest = shape_d_ic(p, state, "x", frozenset({"warmup_transient"}))
    assert every < 10 * rest < 0, (every, rest)
    assert shape_d_ic(p, state, "x", frozenset(n for n, c in CANDIDATES.items() if c.family == "time")) == 0.0
    assert shape_d_ic(p, state, "y") == 0.0  # nothing slow on y


def _walk_and_warmup(amplitude_dps: float, seed: int = 2):
    """A 1-h session at 1 Hz, a random walk K 1.5e-4 deg/s/√s on x and a warm-up of ``amplitude_dps``,
    τ 300 s, on the same axis (0: none)."""
    rng = np.random.default_rng([seed, 32])
    base = BaselineSensor.random(rng, 1.0)
    eff = [{"effect": "rate_random_walk", "axis": "x", "params": {"k_dps_per_sqrt_s": 1.5e-4}}]
    if amplitude_dps:
        eff.append({"effect": "warmup_transient", "axis": "x", "params": {"amplitude_dps": amplitude_dps, "tau_s": 300.0}})
    return make_session(3600.0, 1.0, eff, seed=int(rng.integers(2**31)), mount="z", base=base)


def test_a_walk_one_run_cannot_tell_from_a_warm_up_says_so(tmp_path, monkeypatch):
    """A warm-up of 0.02 deg/s (τ 300 s) on a random walk's axis comes out the walk (its shape is
    matched by 6 of 99 realisations of the walk fitted to both: not beyond, but under 10 %): the
    finding stays rate_random_walk and carries the warm-up as what one run cannot tell from it, with
    its parameters, the fraction of draws and what separates them, in the JSON, the text and the
    report. A walk without a warm-up whose slow part is uneven (so its shapes are counted on the
    draws: seed 10, 10 of the draws as large) carries nothing (docs/diagnose.md, 6b and Output)."""
    from bench.analysis.diagnose import noise as nm
    result = diagnose(_walk_and_warmup(0.02).dataset)
    walk = [f for f in result.findings if f.effect == "rate_random_walk" and f.axis == "x"]
    assert walk and not [f for f in result.findings if f.effect == "warmup_transient"], result.findings
    alt = walk[0].evidence.get("alternative")
    assert alt is not None and alt["effect"] == "warmup_transient", walk[0].evidence
    assert 0.01 < alt["params"]["amplitude_dps"] < 0.04 and 100 < alt["params"]["tau_s"] < 900, alt
    assert alt["draws_as_large"] < 10 and alt["draws"] == 99 and alt["fraction_as_large"] < 0.1, alt
    assert "second run" in alt["separated_by"] and "temperature channel" not in alt["separated_by"]
    doc = [f for f in result.json["findings"] if f["effect"] == "rate_random_walk"][0]
    assert doc["evidence"]["alternative"]["effect"] == "warmup_transient"
    line = result.noise_line("x")
    assert "cannot tell rate_random_walk from warmup_transient" in line and f"{alt['draws_as_large']} of 99" in line
    assert line in "\n".join(result.summary_lines())
    ds = _walk_and_warmup(0.02).dataset
    html = write_report(result, ds, tmp_path / "r.html").read_text()
    assert "cannot tell rate_random_walk from warmup_transient" in html
    counted: list[int] = []
    count = nm._shapes_as_large
    monkeypatch.setattr(nm, "_shapes_as_large", lambda *a, **k: counted.append(count(*a, **k)) or counted[-1])
    clean = diagnose(_walk_and_warmup(0.0, seed=10).dataset)
    assert counted and counted[0] >= nm.ALTERNATIVE_MATCHES, counted  # the draws were counted, and matched
    assert [(f.effect, f.axis) for f in clean.findings] == [("rate_random_walk", "x")], clean.findings
    assert not any("alternative" in f.evidence for f in clean.findings), [f.evidence for f in clean.findings]
    assert "cannot tell" not in "\n".join(clean.summary_lines())


def test_a_noise_model_realisation_has_the_model_s_statistics():
    """noise.realisation (the draws the slow-structure check compares with): white variance per
    sample, a random walk's increments K²·Δt, a Gauss-Markov process' variance σ²."""
    from bench.analysis.diagnose.noise import realisation
    from bench.analysis.noise_model import NoiseModel

    rng = np.random.default_rng(7)
    n = 200_000
    w = realisation(NoiseModel(dt_s=1.0, duration_s=n, white_var=4e-6), n, rng)
    assert abs(np.var(w) / 4e-6 - 1) < 0.02
    k = 2e-4
    walk = realisation(NoiseModel(dt_s=1.0, duration_s=n, white_var=1e-12, rrw_k=k), n, rng)
    assert abs(np.var(np.diff(walk)) / (k * k) - 1) < 0.02
    gm = realisation(NoiseModel(dt_s=1.0, duration_s=n, white_var=1e-12, gm=[(0.01, 20.0)]), n, rng)
    assert abs(np.var(gm) / 1e-4 - 1) < 0.1
    lag1 = np.corrcoef(gm[:-1], gm[1:])[0, 1]
    assert abs(lag1 - np.exp(-1 / 20.0)) < 0.01


def _axis_col(k: int, v: np.ndarray) -> np.ndarray:
    out = np.zeros((v.size, 3))
    out[:, k] = v
    return out


UNNAMED = {
    # what a real bench produces that nobody wrote a term for: (axis, extra(inputs, rng, k) -> (n,) deg/s)
    "aging_drift": lambda inp, rng, k: _sign(rng) * rng.uniform(0.015, 0.03) * inp.time_s / inp.time_s[-1],
    "bias_bump": lambda inp, rng, k: (_sign(rng) * rng.uniform(0.02, 0.04)
                                      * np.exp(-0.5 * ((inp.time_s - rng.uniform(0.3, 0.7) * inp.time_s[-1]) / 120.0) ** 2)),
    "g_squared": lambda inp, rng, k: rng.uniform(0.02, 0.04) * (inp.specific_force_g[:, (k + 1) % 3] ** 2 - 0.5),
    "motor_field": lambda inp, rng, k: (rng.uniform(0.01, 0.02)
                                        * np.cos(np.radians(inp.table_angle_deg) - rng.uniform(0, 2 * math.pi))),
}


@pytest.mark.parametrize("kind", sorted(UNNAMED))
def test_bench_effects_nobody_named_are_unexplained(kind):
    """Effects outside the vocabulary (an ageing drift, a bias bump, a g² sensitivity, a bias from
    the table motor's magnetic field, periodic in the table angle): 'unexplained' on their axis, no
    name on it. (A saturating scale factor is not among them: it is a scale-factor nonlinearity.)"""
    seed = _seed("nobody", kind)
    rng = np.random.default_rng([seed, 11])
    base = BaselineSensor.random(rng, 1.0)
    mount = "z"
    k = int(rng.integers(0, 3))
    draw = np.random.default_rng([seed, 12])
    session = make_session(3600, 1.0, [], seed=int(rng.integers(2**31)), mount=mount, base=base,
                           extra=lambda inp: _axis_col(k, UNNAMED[kind](inp, draw, k)))
    result = diagnose(session.dataset)
    axis = "xyz"[k]
    assert result.findings == [], (
        kind, [(f.effect, f.axis, f.params) for f in result.findings], result.dropped)
    assert axis in {u["axis"] for u in result.unexplained}, (kind, result.unexplained, result.dropped)


HELD_OUT = {
    # effects outside the vocabulary that used to get a wrong name (issue 32): (axis index, extra)
    "bias_following_the_table_angle": lambda inp, rng: _axis_col(
        int(rng.integers(3)), rng.uniform(0.01, 0.02) * np.sin(np.radians(inp.table_angle_deg) + rng.uniform(0, 2 * math.pi))),
    "scale_factor_changing_in_vacuum": lambda inp, rng: _axis_col(
        2, rng.uniform(1e-3, 3e-3) * inp.rate_dps[:, 2] * (inp.pressure_torr < 1e-2)),
}


@pytest.mark.parametrize("kind", sorted(HELD_OUT))
def test_held_out_effects_outside_the_vocabulary_get_no_name(kind):
    """A bias that follows the table angle (was: periodic + g_sensitivity + rate_random_walk) and a
    scale factor that changes once the chamber is pumped down (was: scale_factor_tempco): no name
    on any axis, unexplained."""
    rng = np.random.default_rng([_seed("held-out", kind), 3])
    base = BaselineSensor.random(rng, 1.0)
    session = make_session(3600, 1.0, [], seed=_seed("held-out", kind, 1), base=base, mount="z",
                           extra=lambda inp: HELD_OUT[kind](inp, rng))
    result = diagnose(session.dataset)
    assert result.findings == [], [(f.effect, f.axis, f.params) for f in result.findings]
    assert result.unexplained, "structure left must be said"


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(2))
def test_gear_eccentricity_at_10hz_on_two_hours(seed):
    check_exact(["gear_eccentricity"], _seed("held-out", "gear10", seed), rate_hz=10.0, duration_s=7200.0)


@pytest.mark.parametrize("name", ["thermal_lag", "gear_eccentricity", "time_skew", "hysteresis"])
def test_single_hidden_effect_10hz(name):
    check_exact([name], _seed("single", 10, name), rate_hz=10.0)


@pytest.mark.parametrize("pair", PAIRS, ids=["+".join(p) for p in PAIRS])
def test_pair_of_hidden_effects(pair):
    check_exact(list(pair), _seed("pair", *pair))


@pytest.mark.parametrize("seed", [0, 1])
def test_estcube_stepper_bench_worm_gear(seed):
    """ESTCube-2 section 4.3: a periodic error in the axis the bench turns about, with a different
    period at every speed: the worm gear's eccentricity, periodic in the table angle."""
    rng = np.random.default_rng([_seed("estcube", seed), 1])
    params = {"fraction": rng.uniform(0.003, 0.01), "harmonic": int(rng.integers(1, 201)),
              "phase_rad": rng.uniform(0, 2 * math.pi)}
    session = make_session(3600, 1.0, [{"effect": "gear_eccentricity", "axis": "z", "params": params}],
                           seed=int(rng.integers(2**31)), kind="stepper")
    result = diagnose(session.dataset)
    assert named(result) == [("gear_eccentricity", "z")]
    f = result.findings[0]
    assert f.params["harmonic"] == params["harmonic"]
    assert f.params["fraction"] == pytest.approx(params["fraction"], rel=0.1)
    assert "pressure_bias" in result.skipped  # the ESTCube-2 bench has no vacuum
    clean = diagnose(make_session(3600, 1.0, [], seed=int(rng.integers(2**31)), kind="stepper").dataset)
    assert clean.findings == []


# ---- output ----------------------------------------------------------------------------------------
def test_json_shape_summary_and_report(tmp_path):
    session, effects, result = check_exact(["pressure_bias"], _seed("json"))
    doc = result.json
    assert set(doc) == {"axes", "findings", "unexplained", "skipped", "band_s", "noise", "temperature_in_time"}
    assert doc["unexplained"] == [] and doc["band_s"] == pytest.approx(30.0)
    # the chamber cycle moves the temperature against time: its cubic is no drift in time (confounded.py)
    assert doc["temperature_in_time"] == []
    for a, sec in doc["noise"].items():  # white noise: the model says so, in IEEE 952 units
        assert sec["whitened"] is False and sec["model"]["gauss_markov"] == [], (a, sec)
        arw = sec["model"]["arw_deg_per_sqrt_h"]  # the generator's 0.011 deg/s at 1 Hz = 0.66 deg/√h
        assert arw == pytest.approx(session.base.noise_dps * 60.0, rel=0.1)
        assert sec["ieee952"]["arw_deg_per_sqrt_h"] == pytest.approx(arw, rel=0.15)
        assert sec["named"] == ["angle_random_walk"], (a, sec["named"])  # white: IEEE 952's N alone
    assert all(f"{a} noise: white" in line and "(named: angle_random_walk)" in line
               for a, line in ((a, result.noise_line(a)) for a in "xyz")), [result.noise_line(a) for a in "xyz"]
    assert set(doc["axes"]) == {"x", "y", "z"}
    for v in doc["axes"].values():
        assert set(v) == {"rms_baseline", "rms_extended"} and all(isinstance(x, float) for x in v.values())
    (f,) = doc["findings"]
    assert set(f) == {"effect", "axis", "params", "rms_before", "rms_after", "gain", "gain_band", "evidence"}
    assert f["gain_band"] > 1.01 and f["evidence"]["d_ic"] < -10
    assert f["effect"] == "pressure_bias" and f["axis"] == effects[0]["axis"]
    assert f["gain"] == pytest.approx(f["rms_before"] / f["rms_after"])
    assert f["params"]["shift_dps"] == pytest.approx(effects[0]["params"]["shift_dps"], rel=0.15)
    assert doc["skipped"] == []
    import json
    json.dumps(doc)  # plain JSON
    ax = effects[0]["axis"]
    line = next(s for s in result.summary_lines() if s.startswith(f"{ax}:"))
    assert "baseline residual" in line and "missing effect pressure_bias" in line and "held-out" in line and "Torr" in line
    out = write_report(result, session.dataset, tmp_path / "r.html")
    html = out.read_text()
    for section in ("Findings", "Noise model", "Unexplained", "Held-out residuals", "Spectra", "Correlation with covariates",
                    "Allan deviation", "Candidates"):
        assert section in html
    assert html.count("data:image/png;base64") >= 5


def test_extended_model_closes_the_loop(tmp_path):
    session, effects, result = check_exact(["hysteresis", "gear_eccentricity"], _seed("loop"))
    model = result.extended_model()
    assert model["schema"] == "bench-sensor-model/1"
    assert sorted((e["effect"], e["axis"]) for e in model["effects"]) == injected(effects)
    path = tmp_path / "extended.yaml"
    path.write_text(yaml.safe_dump(model, sort_keys=False))
    from bench.model.loader import load_sensor_model

    spec = load_sensor_model(path)
    assert len(spec.effects) == 2
    # simulate with the extended model, diagnose again with it: nothing left
    again = make_session(3600, 1.0, [], seed=_seed("loop", "again"), model=path, mount=session.meta["mount"])
    with_model = diagnose(again.dataset, str(path))
    assert with_model.findings == []
    assert sorted(with_model.fixed_terms) == sorted(f"{e['effect']}:{e['axis']}" for e in effects)
    # without the model the same effects are missing again
    assert named(diagnose(again.dataset)) == injected(effects)
    # a model file's keys are kept, findings appended to its effects
    ext2 = with_model.extended_model()
    assert ext2["model"] == "npsat1_gyro" and len(ext2["effects"]) == 2


def test_project_model_terms_join_the_baseline():
    """A model that already has a warm-up (NPSAT1 ground model) does not report it as missing."""
    eff = [{"effect": "warmup_transient", "axis": "x", "params": {"amplitude_dps": 0.024, "tau_s": 240.0}}]
    session = make_session(3600, 1.0, eff, seed=_seed("npsat1-warmup"))
    assert named(diagnose(session.dataset)) == [("warmup_transient", "x")]
    result = diagnose(session.dataset, "configs/sensors/npsat1_qrs11_ground.yaml")
    assert result.findings == []
    assert "warmup_transient:x" in result.fixed_terms and "pressure_bias:z" in result.fixed_terms
    assert result.extended_model()["warmup_tau_s"] == [240.0, 170.0, 100.0]  # the file's keys


def test_absent_columns_are_skipped():
    session, effects = hidden_session(["warmup_transient"], _seed("skip"))
    cols = {k: v for k, v in session.dataset.columns.items()
            if k not in ("pressure_torr", "accel_x_g", "accel_y_g", "accel_z_g", "table_angle_deg")}
    result = diagnose(Dataset(cols, {"sample_rate_hz": 1.0}, "no-aux"))
    assert set(result.skipped) == {"pressure_bias", "gear_eccentricity", "g_sensitivity", "earth_rate"}
    assert named(result) == injected(effects)
    gyro_only = Dataset({k: v for k, v in session.dataset.columns.items() if k == "time_s" or k.startswith("gyro_")},
                        {}, "gyro-only")
    r2 = diagnose(gyro_only)
    assert set(r2.skipped) == set(VOCABULARY) - {"rate_random_walk", "bias_step", "periodic", "bias_instability",
                                                  "gauss_markov"}
    assert r2.json["axes"].keys() == {"x", "y", "z"}


def test_bad_input(tmp_path):
    with pytest.raises(InputError, match="rows"):
        diagnose(Dataset({"time_s": np.arange(50.0), "gyro_z_dps": np.zeros(50)}, {}, "short"))
    with pytest.raises(InputError, match="gyro"):
        diagnose(Dataset({"time_s": np.arange(500.0), "temp_c": np.zeros(500)}, {}, "no gyro"))
    ds = make_session(600, 1.0, seed=2).dataset
    with pytest.raises(InputError, match="not found"):
        diagnose(ds, str(tmp_path / "missing.yaml"))
    bad = tmp_path / "bad.yaml"
    bad.write_text("schema: bench-sensor-model/1\nmodel: npsat1_gyro\neffects:\n  - {effect: wobble, axis: z}\n")
    with pytest.raises(InputError, match="wobble"):
        diagnose(ds, str(bad))


# ---- long sessions (BENCH_SLOW=1) -------------------------------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("name", ["clean", *VOCABULARY])
def test_eight_hour_1hz_session(name):
    check_exact([] if name == "clean" else [name], _seed("8h", name), duration_s=28800.0)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["clean", *VOCABULARY])
def test_two_hour_10hz_session(name):
    check_exact([] if name == "clean" else [name], _seed("2h10", name), rate_hz=10.0, duration_s=7200.0)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(3, 12))
def test_more_clean_sessions(seed):
    check_exact([], _seed("clean", 1, seed))


PAIR_10HZ_MISSES: dict[tuple[str, str], str] = {}
"""Slow 10-Hz pairs that still fail, each with what happens (strict xfail)."""


@pytest.mark.slow
@pytest.mark.parametrize("pair", [pytest.param(p, marks=pytest.mark.xfail(strict=True, reason=PAIR_10HZ_MISSES[p]))
                                  if p in PAIR_10HZ_MISSES else p for p in PAIRS], ids=["+".join(p) for p in PAIRS])
def test_pairs_at_10hz(pair):
    check_exact(list(pair), _seed("pair10", *pair), rate_hz=10.0)


# ---- open world: adding a term, reporting what has no name -----------------------------------------
def test_a_registered_term_is_searched_and_simulated(tmp_path):
    """A user adds a term in one call (forward model + candidate); the simulator injects it through a
    model file's effects and diagnose names it; without it, the same data are 'unexplained'."""
    from dataclasses import dataclass

    from bench.analysis.diagnose import terms

    @dataclass
    class RateSquaredTempParams:
        k_dps_per_c2: float = 0.0

    def forward(prm, inputs, k, t, rng):
        return prm.k_dps_per_c2 * (np.asarray(inputs.temp_c, dtype=float) - 25.0) ** 2 * np.sign(np.gradient(inputs.temp_c))

    class RateSquaredTemp(terms.Candidate):
        name = "test_heating_curvature"
        family = "time"

        def missing(self, p):
            return [] if p.temp is not None else ["temp_c"]

        def build(self, p, axis, nl, ctx):
            return terms.Built(cols={axis: ((p.temp - 25.0) ** 2 * np.sign(np.gradient(p.temp)))[:, None]})

        def params(self, p, axis, nl, coef):
            return {"k_dps_per_c2": float(coef[axis][0])}

    name = RateSquaredTemp.name
    try:
        terms.register(RateSquaredTemp(), RateSquaredTempParams, forward, ("temp_c",))
        assert name in fx.VOCABULARY
        eff = [{"effect": name, "axis": "y", "params": {"k_dps_per_c2": 4e-5}}]
        session = make_session(3600, 1.0, eff, seed=_seed("registered"), mount="z")
        assert named(diagnose(session.dataset)) == [(name, "y")]
        hidden = diagnose(session.dataset, hidden=(name,))
        assert [f for f in hidden.findings if f.axis == "y"] == []
        assert "y" in {u["axis"] for u in hidden.unexplained}
    finally:
        terms.CANDIDATES.pop(name, None)
        for table in (fx.PARAMS, fx.NEEDS, fx._FORWARD):
            table.pop(name, None)
        fx.VOCABULARY = tuple(fx.PARAMS)


def test_unexplained_is_said_in_text_json_and_html(tmp_path):
    """A bias bump nobody named (0.03 deg/s for a few minutes mid-run): the summary says UNEXPLAINED
    on its axis, the JSON lists it with its size and where it lives (gain before/after), the HTML
    report has it; nothing is named. (A straight ageing drift over one run is not separable from a
    random walk: docs/diagnose.md, 6b.)"""
    rng = np.random.default_rng([_seed("said"), 1])
    session = make_session(3600, 1.0, [], seed=_seed("said", 2), mount="z",
                           extra=lambda inp: _axis_col(0, 0.03 * np.exp(-0.5 * ((inp.time_s - 1900.0) / 150.0) ** 2)))
    result = diagnose(session.dataset)
    assert result.findings == [], [(f.effect, f.axis) for f in result.findings]
    (u,) = [u for u in result.json["unexplained"] if u["axis"] == "x"]
    assert 0.002 < u["rms_dps"] < 0.02 and u["where"][0]["probe"] == "time" and u["where"][0]["gain"] > 1.0
    assert any(line.startswith("x: UNEXPLAINED") for line in result.summary_lines())
    html = write_report(result, session.dataset, tmp_path / "u.html").read_text()
    assert "Unexplained" in html and "UNEXPLAINED" in html
    del rng
