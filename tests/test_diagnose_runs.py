"""``bench diagnose A B ...``: several runs of one unit (bench/analysis/diagnose/runs.py,
docs/diagnose.md "Several runs of one unit").

One run cannot tell a warm-up from the random walk it is taken for; a second run can: a warm-up
repeats from each power-on, a walk does not. The runs are built the way tests/test_diagnose.py builds
its sessions (``hidden_session``: the unit, its mount and its effects from one seed), the second run
of the same unit with another session seed (its own noise). What the engine is given: the measured
columns only; the injected parameters stay here.

CI: 15- and 20-min runs at 1 Hz (the warm-up's τ of about 300 s is inside). ``BENCH_SLOW=1``: the 1-h
KNOWN_MISSES construction itself, more walk pairs (the false-alarm count) and the real-noise cases.
"""

from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np
import pytest

from bench.analysis.diagnose import diagnose
from bench.analysis.diagnose.runs import diagnose_runs
from bench.sessions import BaselineSensor, make_session, write_csv
from tests.test_diagnose import _seed, random_effect

NOISE_TERMS = {"rate_random_walk", "bias_instability", "gauss_markov"}
WARMUP_SEED = _seed("unnamed", 1, "warmup_transient", 1)
"""tests/test_diagnose.py KNOWN_MISSES ("unnamed", "warmup_transient", 1): a warm-up of +0.025 deg/s,
τ 297 s, on x, which one run names a rate random walk when the warm-up is hidden."""


def unit_run(names: list[str], seed: int, run: int, duration_s: float = 3600.0):
    """(session, injected entries): run ``run`` of the unit of ``seed`` (tests/test_diagnose.py's
    ``hidden_session`` draws, in its order); run 0 is ``hidden_session(names, seed)`` itself, the others
    the same unit and effects with another session seed (another noise)."""
    rng = np.random.default_rng([seed, 7919])
    base = BaselineSensor.random(rng, 1.0)
    mount = str(rng.choice(["z", "z", "x", "y", "-z"]))
    lat = float(rng.uniform(-60, 60))
    effects = [random_effect(n, rng, base, mount) for n in names]
    sess = int(rng.integers(2**31)) if run == 0 else _seed("run", seed, run)
    return make_session(duration_s, 1.0, effects, seed=sess, kind="tvac", mount=mount, latitude_deg=lat, base=base), effects


def walk_run(seed: int, run: int, duration_s: float = 3600.0, k: float = 1.5e-4):
    """Run ``run`` of a unit with a rate random walk K ``k`` deg/s/√s on x and no warm-up."""
    rng = np.random.default_rng([seed, 32])
    base = BaselineSensor.random(rng, 1.0)
    eff = [{"effect": "rate_random_walk", "axis": "x", "params": {"k_dps_per_sqrt_s": k}}]
    return make_session(duration_s, 1.0, eff, seed=int(rng.integers(2**31)) + 1000 * run, mount="z", base=base)


def across(result, axis: str) -> dict:
    return next(e for e in result.across if e.get("axis") == axis)


def names_on(result, axis: str) -> list[str]:
    return sorted({f.effect for r in result.runs for f in r.findings if f.axis == axis})


def check_named_across(duration_s: float) -> None:
    """The warm-up in both runs: named across runs with τ and amplitudes near the truth, fixed in each
    run; nothing else named on its axis (the runs have no walk), no other axis touched."""
    (s1, eff), (s2, _) = unit_run(["warmup_transient"], WARMUP_SEED, 0, duration_s), unit_run(["warmup_transient"], WARMUP_SEED, 1, duration_s)
    truth = eff[0]
    a = truth["axis"]
    result = diagnose_runs([s1.dataset, s2.dataset])
    e = across(result, a)
    assert e["asked"] and e["beyond"] and e.get("named") == "warmup_transient", e
    tau = truth["params"]["tau_s"]
    assert abs(e["tau_s"] - tau) < 0.25 * tau, (e["tau_s"], tau)
    assert e["tau_s_interval"][0] <= e["tau_s"] <= e["tau_s_interval"][1]
    for amp in e["amplitudes_dps"]:
        assert abs(amp - truth["params"]["amplitude_dps"]) < 0.3 * abs(truth["params"]["amplitude_dps"]), e
    assert e["draws_as_large"] == 0 and e["warmup_draws_as_large"] == 0
    for r in result.runs:
        assert r.fixed_terms == [f"warmup_transient:{a}"], r.fixed_terms
        assert [(f.effect, f.axis) for f in r.findings] == [], [(f.effect, f.axis, f.params) for f in r.findings]
        assert r.unexplained == [], r.unexplained
    for b in "xyz":
        if b != a:
            assert not across(result, b)["beyond"], across(result, b)
    model = result.extended_model()
    warm = [w for w in model["effects"] if w["effect"] == "warmup_transient"]
    assert len(warm) == 1 and warm[0]["axis"] == a and warm[0]["params"]["tau_s"] == e["tau_s"], model["effects"]
    doc = result.json
    assert set(doc) == {"runs", "across_runs"} and len(doc["runs"]) == 2
    import json

    from bench.analysis.per_file import json_text

    back = json.loads(json_text(doc))  # the --json text: plain values only
    named = [x for x in back["across_runs"] if x.get("named")]
    assert [(x["axis"], x["named"]) for x in named] == [(a, "warmup_transient")], back["across_runs"]
    assert named[0]["amplitudes_dps"] == e["amplitudes_dps"] and back["runs"][0]["source"] == s1.dataset.source
    text = "\n".join(result.summary_lines())
    assert f"{a}: repeats from power-on" in text and "warmup_transient across runs" in text and "deg/s" in text


def check_unexplained_across(duration_s: float) -> None:
    """The warm-up hidden from the vocabulary: the axis unexplained across runs ("repeats from
    power-on") in both runs, no noise name on it (one run alone names a rate random walk there)."""
    (s1, eff), (s2, _) = unit_run(["warmup_transient"], WARMUP_SEED, 0, duration_s), unit_run(["warmup_transient"], WARMUP_SEED, 1, duration_s)
    a = eff[0]["axis"]
    result = diagnose_runs([s1.dataset, s2.dataset], hidden=("warmup_transient",))
    e = across(result, a)
    assert e["asked"] and e["beyond"] and "named" not in e and "hidden" in e["why_unnamed"], e
    assert names_on(result, a) == [], [(f.effect, f.axis) for r in result.runs for f in r.findings]
    for r in result.runs:
        assert any(u["axis"] == a and u.get("across_runs") for u in r.unexplained), r.unexplained
        assert r.noise[a]["named"] == ["angle_random_walk"], r.noise[a]
    assert [f for r in result.runs for f in r.findings] == []
    assert "UNEXPLAINED across runs, repeats from power-on" in "\n".join(result.summary_lines())


def check_walks(seed: int, duration_s: float, alone: bool = True) -> dict:
    """Two runs of a random walk, no warm-up: no cross-run finding, each run's result as alone
    (compared with :func:`diagnose` of the run when ``alone``)."""
    runs = [walk_run(seed, 0, duration_s).dataset, walk_run(seed, 1, duration_s).dataset]
    result = diagnose_runs(runs)
    e = across(result, "x")
    assert e["asked"] and not e["beyond"] and "named" not in e, e
    assert all(not r.fixed_terms for r in result.runs)
    assert not any(u.get("across_runs") for r in result.runs for u in r.unexplained)
    if alone:
        for ds, r in zip(runs, result.runs):
            assert r.json == diagnose(ds).json
    return e


def test_a_warm_up_in_two_runs_is_named_across_runs():
    check_named_across(900.0)


def test_a_hidden_warm_up_in_two_runs_is_unexplained_across_runs():
    check_unexplained_across(1200.0)


def test_two_runs_of_a_random_walk_name_nothing_across_runs():
    e = check_walks(3, 900.0)
    assert e["draws_as_large"] > 0, e


def test_one_run_is_today_s_result_and_the_test_is_not_asked():
    """One run of the warm-up unit (15 min): the single-run result, not asked across runs. Its warm-up
    (τ 297 s, the run's third) is found at τ ≈ 260 s with an interval reaching the top of the grid
    (300 s): one run does not bound τ, so it is not named and ``dropped`` says why (docs/diagnose.md,
    Power-on); given a second run it is named across runs (:func:`check_named_across`)."""
    s, eff = unit_run(["warmup_transient"], WARMUP_SEED, 0, 900.0)
    alone = diagnose(s.dataset)
    result = diagnose_runs([s.dataset])
    assert result.across == [{"test": "repeats from power-on", "asked": False,
                               "reason": "one run: a second run of the unit is needed"}]
    assert result.runs[0].json == alone.json
    assert result.runs[0].summary_lines() == alone.summary_lines()
    a = eff[0]["axis"]
    assert [f for f in alone.findings if f.effect not in NOISE_TERMS] == [], [(f.effect, f.axis) for f in alone.findings]
    (gone,) = [d for d in alone.dropped if d["effect"] == "warmup_transient"]
    assert gone["axis"] == a and gone["reason"].startswith("τ not bounded by the data"), gone
    assert gone["tau_s_interval"][1] == pytest.approx(300.0) and gone["tau_s_interval"][0] < gone["nl"]["tau_s"], gone
    assert f"{a}: a warm-up was found but is not named: τ not bounded by the data" in "\n".join(alone.summary_lines())


def test_runs_without_a_known_power_on_are_left_out_and_said():
    s, _ = unit_run([], 5, 0, 900.0)
    cols = {k: v for k, v in s.dataset.columns.items() if k != "power_on_s"}
    from bench.analysis.dataset import Dataset

    blind = Dataset(cols, dict(s.dataset.meta), "blind.csv")
    result = diagnose_runs([s.dataset, blind])
    reasons = [e["reason"] for e in result.across if not e["asked"]]
    assert any("run 2 left out: its power-on is not known" in r for r in reasons), result.across
    assert any("at least two are needed" in r for r in reasons), result.across
    late = diagnose_runs([s.dataset, blind], power_on_at=[None, -120.0])
    assert any("run 2 left out: its first row is 120 s after power-on" in e["reason"] for e in late.across if not e["asked"]), late.across
    with pytest.raises(Exception, match="1 value"):
        diagnose_runs([s.dataset, blind], power_on_at=[0.0])


def test_power_on_values_one_per_file():
    from bench.cli_analysis import _power_on_values
    from bench.errors import InputError

    assert _power_on_values(None, 2) == [None, None]
    assert _power_on_values(["0,12.5"], 2) == [0.0, 12.5] == _power_on_values(["0", "12.5"], 2)
    assert _power_on_values(["-", "3"], 2) == [None, 3.0]
    assert _power_on_values(["7"], 1) == [7.0]
    for given, n, msg in ((["0"], 2, "1 value(s) for 2 data file(s)"), (["0,x"], 2, "expected a time in s, got 'x'"),
                          (["nan"], 1, "finite"), (["-"], 1, "expected a time in s")):
        with pytest.raises(InputError, match=re.escape(msg)):
            _power_on_values(given, n)


def test_cli_several_files(tmp_path, monkeypatch, capsys):
    """Two files: exit 0, each run and the across-runs section, -o with the shared warm-up (the command
    run in this process: the same ``main`` as ``bench``); bad combinations: exit 2, one located line."""
    from bench.cli import main
    from tests.cli_output import one_error_line

    for run in (0, 1):
        s, _ = unit_run(["warmup_transient"], WARMUP_SEED, run, 900.0)
        write_csv(s.dataset, tmp_path / f"run{run}.csv")
    monkeypatch.chdir(tmp_path)
    assert main(["diagnose", "run0.csv", "run1.csv", "-o", "model.yaml"]) == 0
    out = capsys.readouterr().out
    assert "across runs:" in out and "run 1: run0.csv" in out and "run 2: run1.csv" in out, out
    assert "warmup_transient across runs" in out, out
    assert "warmup_transient" in (tmp_path / "model.yaml").read_text()
    for bad, where in ((["--power-on-at", "0"], "--power-on-at"), (["--report", "r.html"], "--report")):
        code = main(["diagnose", "run0.csv", "run1.csv", *bad])
        got = capsys.readouterr()
        line = one_error_line(SimpleNamespace(returncode=code, stdout=got.out, stderr=got.err))
        assert where in line, (bad, line)
    assert not (tmp_path / "r.html").exists()


# ---- slow: the 1-h constructions, more walks, real noise ------------------------------------------------
@pytest.mark.slow
def test_the_known_miss_warm_up_in_two_one_hour_runs_is_named_across_runs():
    """tests/test_diagnose.py KNOWN_MISSES ("unnamed", "warmup_transient", 1) as it is built there (1 h),
    its warm-up not hidden, and a second run."""
    check_named_across(3600.0)


@pytest.mark.slow
def test_the_known_miss_hidden_in_two_one_hour_runs_is_unexplained_across_runs():
    """KNOWN_MISSES ("unnamed", "warmup_transient", 1) itself (warm-up hidden, 1 h; one run: named
    rate_random_walk) given a second run: unexplained across runs, no noise name on x."""
    check_unexplained_across(3600.0)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(8))
def test_two_one_hour_walks_name_nothing_across_runs(seed):
    """Eight pairs of 1-h walks (K 1.5e-4 deg/s/√s, tests/test_diagnose.py's ``_walk_and_warmup`` unit):
    no cross-run finding (a 1 % test: about 1 pair in 100 may come out unexplained, never named)."""
    check_walks(seed, 3600.0, alone=False)


def background_run(bg: str, names: list[str], seed: int, run: int, noise_seed: int | None = None):
    """(session, injected): run ``run`` of tests/test_real_data_diagnose.py's ``in_background(bg, names,
    seed)`` unit: run 0 is that session; others the same unit and effect parameters in another
    background hour (``background(bg, n, noise_seed)``, by default one drawn from ``seed`` and ``run``)
    with another session seed."""
    from tests.diagnose_shapes import background, extra, scale_against
    from tests.test_real_data_diagnose import hidden_effect

    rng = np.random.default_rng([seed, 32])
    mount = str(rng.choice(["z", "x", "-y"]))
    base = BaselineSensor.random(rng, 1.0)
    base.noise_dps = 0.0
    sess = int(rng.integers(2**31))
    probe = make_session(3600.0, 1.0, [], seed=sess, mount=mount, base=base)
    entries = [hidden_effect(n, rng, mount, scale_against(bg), probe, base) for n in names]
    if noise_seed is None:
        noise_seed = seed if run == 0 else _seed("background", seed, run)
    noise = background(bg, 3600, noise_seed)
    return make_session(3600.0, 1.0, [], seed=sess if run == 0 else _seed("session", seed, run), mount=mount, base=base,
                        extra=extra(entries, noise)), entries


def _real(real_log, bg: str) -> None:
    real_log("samsung_galaxy_s5.nc" if bg == "s5" else "cats_temperature_calib.nc")


@pytest.mark.slow
def test_the_s5_warm_up_in_two_runs_is_named_across_runs(real_log):
    """tests/test_real_data_diagnose.py REAL_NOISE_MISSES ("s5", "warmup_transient", 2) (0.16 deg/s,
    τ 292 s on y in an S5 background hour; one run: rate_random_walk) and a second run of the same unit
    and effect in another S5 hour: warmup_transient across runs, τ and amplitudes near the truth; in
    each run no deterministic name and nothing unexplained, and no noise term on the warm-up's axis that
    the run's background hour alone (the same session, nothing injected) does not have: the warm-up is
    not taken into a walk: a walk named there is no larger than the hour's own (the S5 phone's wander in
    run 1's hour is a walk on y by itself, Method 6b "An axis whose model has no slow part")."""
    from tests.test_real_data_diagnose import _seed as real_seed

    _real(real_log, "s5")
    seed = real_seed("real", "s5", "warmup_transient", 2)
    (s1, eff), (s2, _) = background_run("s5", ["warmup_transient"], seed, 0), background_run("s5", ["warmup_transient"], seed, 1)
    truth, a = eff[0]["params"], eff[0]["axis"]
    result = diagnose_runs([s1.dataset, s2.dataset])
    e = across(result, a)
    assert e.get("named") == "warmup_transient", e
    assert abs(e["tau_s"] - truth["tau_s"]) < 0.25 * truth["tau_s"], (e["tau_s"], truth)
    assert all(abs(v - truth["amplitude_dps"]) < 0.3 * abs(truth["amplitude_dps"]) for v in e["amplitudes_dps"]), e
    assert [x for x in result.across if x.get("beyond") and x["axis"] != a] == []
    for r in result.runs:
        assert [(f.effect, f.axis) for f in r.findings if f.effect not in NOISE_TERMS] == [], r.findings
        assert r.unexplained == [], r.unexplained
    for run, r in enumerate(result.runs):
        alone = diagnose(background_run("s5", [], seed, run)[0].dataset)
        own = {f.effect for f in alone.findings if f.axis == a}
        assert {f.effect for f in r.findings if f.axis == a} <= own, (run, r.findings, alone.findings)
        walk = [f.params["k_dps_per_sqrt_s"] for f in r.findings if f.axis == a and f.effect == "rate_random_walk"]
        own_k = [f.params["k_dps_per_sqrt_s"] for f in alone.findings if f.axis == a and f.effect == "rate_random_walk"]
        assert all(k <= own_k[0] for k in walk), (run, walk, own_k)  # one run alone: 7.3e-4 against 5.2e-4


REAL_PAIRS = [
    ("s5", ("real", "s5", "periodic", 1), ("real", "s5", "warmup_transient", 0)),
    ("s5", ("real", "s5", "clean"), ("real", "s5", "periodic", 1)),
    ("s5", ("real", "s5", "warmup_transient", 0), ("real", "s5", "clean")),
    ("cats", ("real", "cats", "clean"), ("real", "cats", "periodic", 1)),
    ("cats", ("real", "cats", "warmup_transient", 2), ("real", "cats", "clean")),
]
"""Background hours with nothing injected, paired: the S5 hour where a single-run warm-up statistic named
a warm-up never injected (``periodic`` seed 1), the wandering hour of
``test_a_wandering_real_noise_hour_names_nothing`` (``warmup_transient`` seed 0), the clean hour of
``test_real_noise_alone_names_nothing_deterministic``; and two pairs of CATS stretches."""


@pytest.mark.slow
@pytest.mark.parametrize("bg,first,second", REAL_PAIRS, ids=["-".join(map(str, (p[0],) + p[1][2:] + p[2][2:])) for p in REAL_PAIRS])
def test_two_real_noise_hours_name_nothing_across_runs(real_log, bg, first, second):
    """Two runs of one unit (``first``'s) in two real background hours (``first``'s and ``second``'s),
    nothing injected: no axis beyond across runs, each run as alone."""
    from tests.test_real_data_diagnose import _seed as real_seed

    _real(real_log, bg)
    a, b = real_seed(*first), real_seed(*second)
    runs = [background_run(bg, [], a, 0)[0], background_run(bg, [], a, 1, noise_seed=b)[0]]
    result = diagnose_runs([s.dataset for s in runs])
    asked = [e for e in result.across if e["asked"]]
    assert len(asked) == 3 and not any(e["beyond"] for e in asked), [(e["axis"], e["agreement"], e["draws_as_large"]) for e in asked]
    assert all(not r.fixed_terms and not any(u.get("across_runs") for u in r.unexplained) for r in result.runs)


@pytest.mark.slow
def test_a_slow_curve_in_one_run_only_does_not_repeat_from_power_on(real_log):
    """Two runs of one unit in two real S5 hours, nothing injected; the first hour's phone wander on y
    takes a warm-up's shape by itself (one run finds warmup_transient:y, never injected, and leaves it
    unnamed: its τ interval reaches the top of the grid; its noise is fitted as if named): no axis may be
    called "repeats from power-on" when the second run has no such curve. Before every run had to be
    predicted by the others' curve, y was: in-sample agreement 0.87 against draws to 0.74 (the second
    run's warm-up amplitude at that τ +0.004 deg/s), its noise names dropped."""
    from tests.diagnose_shapes import background
    from tests.test_real_data_diagnose import _seed as real_seed

    _real(real_log, "s5")
    seed = real_seed("real", "s5", "bump", 1)  # the background of test_an_effect_nobody_named_in_real_noise's S5 seed 1

    def run(k: int):
        base = BaselineSensor.random(np.random.default_rng(seed), 1.0)
        base.noise_dps = 0.0
        noise = background("s5", 3600, seed if k == 0 else _seed("background", seed, k))
        return make_session(3600, 1.0, [], seed=seed if k == 0 else _seed("session", seed, k), base=base,
                            extra=lambda inp: noise.copy()).dataset

    result = diagnose_runs([run(0), run(2)])
    beyond = [(e["axis"], e["agreement"], e["agreement_draws_max"]) for e in result.across if e.get("beyond")]
    assert beyond == [], beyond
