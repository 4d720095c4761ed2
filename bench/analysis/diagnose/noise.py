"""The noise step of ``bench diagnose``: the sensor's noise model per axis, fitted from what the
deterministic search and the covariate probes leave, the findings it names, and its IEEE Std 952
read-outs (``docs/diagnose.md``, "Noise model").

* **What the model is fitted on.** The residual of the selected deterministic model (ordinary least
  squares on the rows as analysed), less the structure a *covariate* probe or a spectral line finds
  there (``unexplained`` entries whose best probe is not time): structure that lives against a
  measured covariate is never noise. What is left lives in time only: white noise, flicker, a random
  walk, correlated (Gauss-Markov) noise (:func:`bench.analysis.noise_model.fit_noise_model`).
* **Names.** A correlated noise term is named (a finding) only on an axis where nothing is left
  unexplained and its kind is not hidden: ``bias_instability`` (flicker B), ``rate_random_walk`` (K),
  ``gauss_markov`` (σ, τ_c). White rate noise, IEEE 952's angle random walk N, is in every axis'
  model and named in the ``noise`` section (``named``), never a finding: it is not searched for. Its ``rms_before`` is the residual's RMS, ``rms_after`` the RMS of the
  one-step prediction error under the model (the innovations).
* **Read-outs.** The residual's overlapping Allan deviation (:mod:`bench.analysis.allan`, the one
  home of it) read the IEEE Std 952 way (:func:`bench.analysis.allan.read_noise_terms`): angle
  random walk, bias instability, rate random walk, with the τ where each was read.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from bench.analysis.diagnose.data import Prepared
from bench.analysis.diagnose.engine import Term, build_state
from bench.analysis.diagnose.result import Finding
from bench.analysis.diagnose.terms import Built, Probe
from bench.analysis.noise_model import (IC_MIN, SLOW_SAMPLES, NoiseModel, fit_noise_model, stationarity,
                                       stationarity_test, with_slow_part)

KINDS = {"bias_instability": "flicker", "rate_random_walk": "rrw", "gauss_markov": "gm"}
"""Vocabulary noise term -> noise-model component kind."""
NOT_NOISE = ("time",)
"""Probes whose structure may be noise (everything else found by a probe is left out of the fit)."""


def residuals(p: Prepared, terms: list[Term], unexplained: list[dict[str, Any]]) -> dict[str, np.ndarray]:
    """Per axis, the residual the noise model is fitted on (module docstring), deg/s at the analysed
    rate, computed without prewhitening."""
    terms = noise_terms(p, terms, unexplained)
    saved = p.whiten
    p.whiten = {}
    try:
        st = build_state(p, terms)
        return {a: st.axes[a].resid() for a in p.axes}
    finally:
        p.whiten = saved


def noise_terms(p: Prepared, terms: list[Term], unexplained: list[dict[str, Any]]) -> list[Term]:
    """``terms`` and the covariate probes' structure (module docstring): the model whose residual is
    the noise, fitted without prewhitening."""
    from bench.analysis.diagnose.openworld import probe_term

    saved = p.whiten
    p.whiten = {}
    try:
        extra: list[Term] = []
        for u in unexplained:
            names = [w["probe"] for w in u["where"]]
            take = [n for n in names if n not in NOT_NOISE]
            if names and names[0] in NOT_NOISE:
                take = [n for n in take if n == "spectrum"]  # a line is never noise; slow structure in time may be
            for name in take[:2]:
                hit = probe_term(p, build_state(p, terms + extra), "probe:" + name, u["axis"])
                if hit is not None:
                    extra.append(hit[0])
        return terms + extra
    finally:
        p.whiten = saved


GOF_DRAWS = 99
"""Realisations of an axis' fitted noise model the time probe is run on (:func:`beyond_noise`): the
observed structure is beyond the model when it is larger than in every one, a Monte Carlo test at
1/(GOF_DRAWS + 1) = 1 % false alarm. Not 5 %: real noise is not exactly its Gaussian model, and the
S5 phone at rest (6 h, y: time probe ΔIC −443) is beyond all of 19 realisations of its flicker model,
not of 99."""
GOF_SEED = 952
"""Fixed seed of those realisations: the engine's answer does not change from run to run."""
STATISTICS = ("time probe", "best named slow shape", "gravity segments against time")
"""What :func:`beyond_noise` compares with the realisations ("d_ic" of its evidence: that statistic)."""
UNEVEN_P = 0.05
"""Level of the stationarity test (:func:`bench.analysis.noise_model.stationarity_test`) that
:func:`beyond_noise` also asks for."""


def beyond_noise(p: Prepared, terms: list[Term], resid: dict[str, np.ndarray], axes: frozenset[str],
                 hidden: frozenset[str] = frozenset(), alternatives: dict[str, Any] | None = None,
                 slow_parts: dict[str, Any] | None = None, in_time: frozenset[str] = frozenset()) -> dict[str, Any]:
    """The axes of ``axes`` (where the unwhitened fits leave slow structure) whose slow structure is
    not the noise model's fitted to it: axis -> evidence. Two symptoms are asked for, tests at 5 % and
    1 % (2 % for the two statistics below together), about 0.1 % together for a random walk (they are
    independent under the model), or the third alone on data with moves of the unit:

    * **uneven in time**: the stationarity likelihood ratio (four stretches, each its own slow
      variances) at :data:`UNEVEN_P` as a χ² test (not the BIC of :func:`fit_models`, which asks for
      p ≈ 1e-5; the S5 phone's own wander is uneven at p ≈ 0.01 and passes that);
    * **larger than the model makes**: on the model ``terms`` (:func:`noise_terms`: the fits without
      prewhitening), the time probe's ΔIC, or the best ΔIC of the named slow shapes
      (:func:`shape_d_ic`: the "time"-family candidates not in ``hidden``, each over its own grid),
      below the same statistic on every one of :data:`GOF_DRAWS` series in which the axis' residual is
      replaced by a realisation of the noise model fitted to it. A model fitted to a random walk,
      flicker or the phone's wander makes structure of the observed size (it was fitted to it); a
      transient, a thermal lag or a hysteresis it took for slow noise can make more than any
      realisation. Each realisation is searched over the same grids, so the test pays for the
      search itself (no look-elsewhere charge).
    * **levels between the unit's moves**, asked whether or not the slow part is uneven: on data
      with at least two segments of the measured gravity direction (:func:`gravity_segments`),
      the ΔIC of one level per segment minus the time probe's (:func:`segment_d_ic`), below that of
      every realisation. A random walk does not care when the unit moves; an Earth rate on a
      tilting table's axis is a level between the tilts (a 1 % test alone: about 1 in 100 random
      walks on such a session come out "unexplained").

    ``docs/diagnose.md``, 6b "Larger than the model makes". The decision is made on the unwhitened
    fits and kept through the whitened rounds: a whitener with the slow part in it hides the structure
    it is asked about.

    ``alternatives`` (filled when given): axis -> the best named slow shape on an axis that is *not*
    beyond, when fewer than :data:`ALTERNATIVE_MATCHES` of the realisations make a shape as large
    (:func:`slow_alternative`): what one run cannot tell from the noise term the axis will be named.

    **An axis whose model has no slow part** (:func:`has_slow_part`: the BIC took none) cannot take
    slow structure for noise, so the probes keep what they find; when ``slow_parts`` is given and the
    axis is one of ``in_time`` (the white pass' best probe of its structure is time), it is asked once
    more, against the model with its best slow part
    (:func:`bench.analysis.noise_model.with_slow_part`), every statistic asked whatever the
    unevenness, each to be matched by :data:`ASKED_MATCHES` realisations (it pays for the second
    question). ``slow_parts[axis]`` gets the evidence (``within``: every statistic matched; the
    statistics, the draws run, how many matched each). Within: :func:`fit_models` gives the axis that
    model (its slow term is named; nothing unexplained). Not: the axis is left as before (not in the
    returned axes: the selected model is kept and the probes keep the structure)."""
    from bench.analysis.diagnose.openworld import probe_term

    def stats(q: Prepared, need: list[bool]) -> list[float]:
        """The :data:`STATISTICS` on ``q``'s axis ``a`` (time probe ΔIC, best named shape ΔIC, segment
        levels' ΔIC − time probe's; more negative: larger structure); NaN where not ``need``ed."""
        state = build_state(q, terms)
        hit = probe_term(q, state, "probe:time", a) if need[0] or need[2] else None
        t = float(hit[1].d_ic) if hit is not None else 0.0
        return [t if need[0] else math.nan, shape_d_ic(q, state, a, hidden) if need[1] else math.nan,
                segment_d_ic(q, state, a, segments) - t if need[2] else math.nan]

    out: dict[str, Any] = {}
    segments = gravity_segments(p)
    saved_w, saved_g = p.whiten, p.gyro
    p.whiten = {}
    try:
        for a in sorted(axes):
            m = _full_model(p, a, resid[a])
            asked = not has_slow_part(m)
            if asked:  # the model takes no slow structure: asked again with its best slow part, or not
                m = _slow_model(p, a, resid[a]) if slow_parts is not None and a in in_time else None
                if m is None:
                    continue  # the probes keep what they find
            lr, p_uneven = stationarity_test(resid[a], m)
            uneven = bool(p_uneven < UNEVEN_P) or asked
            beyond = [uneven, uneven, segments is not None]  # which statistics are asked
            if not any(beyond):
                continue
            need = ASKED_MATCHES if asked else 1
            observed = stats(p, beyond)
            rng = np.random.default_rng([GOF_SEED, "xyz".index(a)])
            fitted = saved_g[a] - resid[a]
            draws: list[list[float]] = []
            matched = [0] * len(STATISTICS)
            for _ in range(GOF_DRAWS):
                p.gyro = {**saved_g, a: fitted + realisation(m, resid[a].size, rng)}
                draws.append(stats(p, beyond))  # only the statistics not yet matched often enough
                matched = [k + int(b and draws[-1][i] <= observed[i]) for i, (k, b) in enumerate(zip(matched, beyond))]
                beyond = [b and matched[i] < need for i, b in enumerate(beyond)]
                if not any(beyond):
                    break  # each statistic matched: within the model
            p.gyro = saved_g
            if asked:
                slow_parts[a] = {"within": not any(beyond), "model": m.describe(), "d_ic": observed,
                                 "draws_run": len(draws), "matched": matched, "need": need,
                                 "uneven_chi2": lr, "uneven_p": p_uneven}
                if any(beyond):
                    continue  # beyond that model too: left as it was
            if any(beyond):
                i = beyond.index(True)
                out[a] = {"statistic": STATISTICS[i], "d_ic": observed[i],
                          "d_ic_draws_min": min(d[i] for d in draws), "model": m.describe(),
                          "uneven_chi2": lr, "uneven_p": p_uneven}
            elif alternatives is not None and observed[1] < 0:
                shapes = [d[1] for d in draws]
                matched = _shapes_as_large(p, a, fitted, m, shapes, lambda q: stats(q, [False, True, False])[1], observed[1])
                p.gyro = saved_g
                if matched < ALTERNATIVE_MATCHES:
                    alt = slow_alternative(p, terms, a, hidden)
                    if alt is not None:
                        alternatives[a] = {**alt, "draws_as_large": matched, "draws": GOF_DRAWS,
                                           "noise_model": m.describe(), "uneven_p": p_uneven}
    finally:
        p.whiten, p.gyro = saved_w, saved_g
    return out


ASKED_MATCHES = 2
"""Realisations that must make each statistic as large when an axis without a slow part is asked
again with its best slow part (:func:`beyond_noise`): the model was chosen after the probes found
the structure, a second question the axis gets, so "within" needs two of the :data:`GOF_DRAWS`
(a 2 % test per statistic), not one."""
ALTERNATIVE_MATCHES = 10
"""A named slow shape is reported as what one run cannot tell from a slow noise term when fewer than
this many of the :data:`GOF_DRAWS` realisations make a shape as large (fewer than 10 %): the draws
go on, for that statistic alone, until this many have matched."""
SEPARATED_BY = ("a second run: a warm-up repeats from each power-on (bench diagnose RUN1 RUN2 asks it), a thermal "
                "lag or a hysteresis with each temperature cycle, a random walk does not")
# not "a temperature channel that follows it": one run with a temperature that moves only with time
# since power-on cannot tell a warm-up from a temperature coefficient (docs/diagnose.md, Known limits)
"""What separates a named slow shape from a slow noise term when one run cannot."""


def best_shape(p: Prepared, state: Any, a: str, hidden: frozenset[str] = frozenset()) -> Any:
    """The best (most negative ΔIC) evaluation on axis ``a`` of ``state`` of the slow named shapes:
    each "time"-family candidate of the vocabulary not in ``hidden`` (warm-up, thermal lag, pressure
    bias, hysteresis, bias step), searched over its own grid; None when none applies or none has a
    negative ΔIC."""
    from bench.analysis.diagnose.engine import evaluate
    from bench.analysis.diagnose.terms import CANDIDATES

    ctx = state.context()
    best = None
    for c in CANDIDATES.values():
        if c.family != "time" or c.noise_term or c.name in hidden or c.missing(p):
            continue
        if a not in c.candidate_axes(p) or c.not_excited(p, a):
            continue
        e = evaluate(p, state, c, a, ctx)
        if e is not None and e.d_ic < (best.d_ic if best is not None else 0.0):
            best = e
    return best


SEGMENT_G = 0.05
"""A move of the measured gravity direction (g, any component used) that starts a new segment for
:func:`gravity_segments`: 2.9° of tilt; the accelerometer's noise over :data:`SEGMENT_SMOOTH_S` is
below 1 mg on the sessions and logs here."""
SEGMENT_SMOOTH_S = 10.0
"""The specific force is averaged over this many seconds before moves are looked for, and a move is
a change of more than :data:`SEGMENT_G` across twice this span."""
SEGMENT_BLOCKS = 1
"""A still stretch shorter than this many cross-validation blocks (30 s at 1 Hz) is not a segment of
its own (its level would be held out whole in some fold); its rows go to the neighbouring segments.
Not 2: a tilt that dwells 100 s between two moves (``earth_rate`` seed 5 of tests/test_diagnose.py)
is a level of its own."""


def gravity_segments(p: Prepared) -> np.ndarray | None:
    """Labels 0..K−1 of the rows: the stretches in which the measured gravity direction stays put,
    split at the middle of each move between them (a tilt, a turn of the unit by hand), or None when
    the data have no accelerometer or fewer than two such stretches. On a turning table only the
    component along its axis is used (the others turn with the table angle all the time)."""
    if p.accel is None:
        return None
    cols = ["xyz".index(p.table_axis.lstrip("+-"))] if p.table_axis else [0, 1, 2]
    w = max(int(round(SEGMENT_SMOOTH_S * p.fs)), 1)
    k = np.ones(w) / w
    g = np.column_stack([np.convolve(np.pad(p.accel[:, c], (w // 2, w - 1 - w // 2), mode="edge"), k, mode="valid")
                         for c in cols])
    ends = np.pad(g, ((w, w), (0, 0)), mode="edge")
    still = np.max(np.abs(ends[2 * w:] - ends[:-2 * w]), axis=1) <= SEGMENT_G
    edges = np.flatnonzero(np.diff(np.concatenate([[0], still.astype(np.int8), [0]])))
    runs = [(int(i), int(j)) for i, j in zip(edges[::2], edges[1::2]) if j - i >= SEGMENT_BLOCKS * p.blocks.length]
    if len(runs) < 2:
        return None
    labels = np.zeros(p.n, dtype=np.int64)
    for k_seg in range(1, len(runs)):
        labels[(runs[k_seg - 1][1] + runs[k_seg][0]) // 2:] = k_seg
    return labels


def segment_d_ic(p: Prepared, state: Any, a: str, labels: np.ndarray) -> float:
    """ΔIC on axis ``a`` of ``state`` of one free level per segment of ``labels``
    (:func:`gravity_segments`), by the engine's held-out criterion like any candidate; 0 when it
    cannot be evaluated."""
    from bench.analysis.diagnose.engine import evaluate

    e = evaluate(p, state, SegmentLevels(labels), a, state.context())
    return float(e.d_ic) if e is not None else 0.0


class SegmentLevels(Probe):
    """One level per segment of :func:`gravity_segments` (the first is the baseline's constant): what
    moves with the unit's orientation and stays put between its moves. A generic probe for
    :func:`segment_d_ic`: it names nothing."""

    name = "probe:gravity_segments"
    where = "gravity direction segments (a level between moves)"

    def __init__(self, labels: np.ndarray):
        self.labels = labels

    def build(self, p, axis, nl, ctx):
        z = (self.labels[:, None] == np.arange(1, int(self.labels.max()) + 1)[None, :]).astype(float)
        return Built(cols={axis: z})


def shape_d_ic(p: Prepared, state: Any, a: str, hidden: frozenset[str] = frozenset()) -> float:
    """The ΔIC of :func:`best_shape`; 0 when none applies."""
    e = best_shape(p, state, a, hidden)
    return float(e.d_ic) if e is not None else 0.0


def _shapes_as_large(p: Prepared, a: str, fitted: np.ndarray, m: NoiseModel, shapes: list[float],
                     shape: Any, observed: float) -> int:
    """How many of the :data:`GOF_DRAWS` realisations (the same fixed-seed series as
    :func:`beyond_noise`'s, replayed) have a best named shape as large as ``observed``, counted up to
    :data:`ALTERNATIVE_MATCHES`: ``shapes`` are those already computed (NaN: not), ``shape(p)`` computes
    one on ``p`` with axis ``a`` replaced. Leaves ``p.gyro`` changed (the caller restores it)."""
    saved_g = p.gyro
    rng = np.random.default_rng([GOF_SEED, "xyz".index(a)])
    matched = 0
    for k in range(GOF_DRAWS):
        x = realisation(m, fitted.size, rng)
        v = shapes[k] if k < len(shapes) else math.nan
        if math.isnan(v):
            p.gyro = {**saved_g, a: fitted + x}
            v = shape(p)
        matched += int(v <= observed)
        if matched >= ALTERNATIVE_MATCHES:
            break
    return matched


def slow_alternative(p: Prepared, terms: list[Term], a: str, hidden: frozenset[str] = frozenset()) -> dict[str, Any] | None:
    """The best named slow shape on axis ``a`` (:func:`best_shape` on the unwhitened fits of ``terms``)
    with its physical parameters: {effect, params, describe, d_ic}; None when there is none."""
    from bench.analysis.diagnose.terms import CANDIDATES

    state = build_state(p, terms)
    e = best_shape(p, state, a, hidden)
    if e is None:
        return None
    c = CANDIDATES[e.cand.name]
    from bench.analysis.diagnose import term_params

    term = Term(c.name, a, dict(e.nl_full), c.build(p, a, e.nl_full, state.context()))
    params = term_params(p, term, build_state(p, terms + [term]), len(terms))
    return {"effect": c.name, "params": params, "describe": c.describe(params), "d_ic": float(e.d_ic)}


def _full_model(p: Prepared, a: str, r: np.ndarray) -> NoiseModel:
    """Axis ``a``'s noise model with every component allowed, fitted once per residual array (asked
    for by :func:`beyond_noise` and then by :func:`fit_models` on the same residual)."""
    from bench.analysis.diagnose.terms import per_residual

    return per_residual(p, "noise_model", a, r, lambda x: fit_noise_model(x, 1.0 / p.fs, p.bin_rows))


def _slow_model(p: Prepared, a: str, r: np.ndarray) -> NoiseModel | None:
    """Axis ``a``'s selected model with its best slow part added
    (:func:`bench.analysis.noise_model.with_slow_part`), fitted once per residual array; None when it
    has a slow part already or no slow part raises the likelihood."""
    from bench.analysis.diagnose.terms import per_residual

    m = _full_model(p, a, r)
    return None if has_slow_part(m) else per_residual(p, "noise_model_slow", a, r, lambda x: with_slow_part(x, m))


def has_slow_part(m: NoiseModel) -> bool:
    """Whether ``m`` has a slow component (flicker, a random walk, or a Gauss-Markov process whose
    correlation time is at least :data:`bench.analysis.noise_model.SLOW_SAMPLES` samples): one that
    can take slow structure in time for noise."""
    return m.flicker_b > 0 or m.rrw_k > 0 or any(tau >= SLOW_SAMPLES * m.dt_s for _, tau in m.gm)


def realisation(m: NoiseModel, n: int, rng: np.random.Generator) -> np.ndarray:
    """One series of ``n`` samples of noise model ``m`` (deg/s): white plus each correlated state,
    a Gauss-Markov process from its stationary start (the generator's own,
    :func:`bench.model.effects.gauss_markov_noise`), the random walk from 0."""
    from bench.model.effects import gauss_markov_noise

    x = rng.normal(0.0, math.sqrt(m.white_var), n)
    t = np.arange(n) * m.dt_s
    for f, q in zip(*m.states()):
        if f < 1.0:
            x += gauss_markov_noise(t, math.sqrt(q / (1.0 - f * f)), -m.dt_s / math.log(f), rng)
        else:
            x += np.cumsum(rng.normal(0.0, math.sqrt(q), n))
    return x


def fit_models(p: Prepared, resid: dict[str, np.ndarray], hidden: frozenset[str] = frozenset(),
               left: frozenset[str] | None = None, structure: dict[str, Any] | None = None,
               slow_parts: dict[str, Any] | None = None) -> dict[str, NoiseModel]:
    """The noise model of each axis. It stays white (the fits ordinary least squares, slow structure
    left to the probes) when

    * its slow part is not stationary (:func:`bench.analysis.noise_model.stationarity`: a transient,
      a step, a drift or structure that follows the run's covariates has its power in some stretches
      only): that is structure, not the sensor's noise; but only on an axis where the probes found
      structure (``left``, the axes with unexplained structure; None: every axis). Where no probe
      takes it, the slow part is the sensor's noise after all, however unevenly one run spreads it
      (a white model there would say "white" of a residual whose Allan curve is far above the white
      line, and name nothing);
    * its slow structure in time is larger than the model makes (``structure``: :func:`beyond_noise`'s
      axes and evidence): that is not this model's noise;
    * a noise term is hidden (``hidden``): with part of its noise vocabulary missing the model would
      give the noise another term's name.

    On an axis of ``slow_parts`` (:func:`beyond_noise`: its slow structure in time is within what its
    model with the best slow part makes) whose selected model has no slow part, the model is that one
    (:func:`bench.analysis.noise_model.with_slow_part`, on the residual given)."""
    out = {}
    for a, r in resid.items():
        if any(name in hidden for name in KINDS):
            m = fit_noise_model(r, 1.0 / p.fs, p.bin_rows, allow=())
            m.steps.append({"component": "correlated noise", "d_bic": 0.0, "accepted": False,
                            "reason": "a noise term is hidden: white only"})
            out[a] = m
            continue
        if structure and a in structure:
            ev = structure[a]
            m = fit_noise_model(r, 1.0 / p.fs, p.bin_rows, allow=())
            m.steps.append({"component": "slow part", "d_bic": ev["d_ic"], "accepted": False,
                            "reason": f"structure in time ({ev['statistic']} ΔIC {ev['d_ic']:+.0f}) beyond what "
                                      f"{ev['model']} makes ({GOF_DRAWS} realisations, none below "
                                      f"{ev['d_ic_draws_min']:+.0f}) and {'un' if ev['uneven_p'] < UNEVEN_P else ''}even "
                                      f"in time (χ² {ev['uneven_chi2']:.1f}, p {ev['uneven_p']:.2g}): left to the probes"})
            out[a] = m
            continue
        m = _full_model(p, a, r)
        if slow_parts and slow_parts.get(a, {}).get("within") and not has_slow_part(m):
            slow = _slow_model(p, a, r)
            if slow is not None:
                ev = slow_parts[a]
                m = replace(slow, steps=[*slow.steps[:-1], dict(slow.steps[-1])])
                seen = ", ".join(f"{name} ΔIC {d:+.0f}" for name, d in zip(STATISTICS, ev["d_ic"]) if not math.isnan(d))
                m.steps[-1]["reason"] = (f"not selected by the BIC; asked because the probes found structure in time "
                                         f"({seen}): within what this model makes (each statistic matched by "
                                         f"{ev['need']} of the first {ev['draws_run']} realisations)")
        st = stationarity(r, m)
        if st < IC_MIN and (left is None or a in left):
            white = fit_noise_model(r, 1.0 / p.fs, p.bin_rows, allow=())
            white.steps.append({"component": "slow part", "d_bic": st, "accepted": False,
                                "reason": f"not stationary (ΔBIC {st:+.0f} for separate stretches): left to the probes"})
            m = white
        elif st < IC_MIN:
            m.steps.append({"component": "stationarity check", "d_bic": st, "accepted": False,
                            "reason": f"not stationary (ΔBIC {st:+.0f} for separate stretches), but no probe finds "
                                      "structure on the axis: the sensor's noise"})
        out[a] = m
    return out


PREDICTABLE = 1.5
"""The correlated part is strong when the residual's variance is at least this many times the
model's one-step prediction error (the innovations): selection is then made anew against it."""


def predictable(m: NoiseModel, r: np.ndarray) -> bool:
    """Whether the noise model predicts a material part of the residual ``r`` (:data:`PREDICTABLE`)."""
    if m.is_white:
        return False
    return float(np.var(r)) >= PREDICTABLE * m.whitener().innovation_var


def same_structure(old: dict[str, NoiseModel], new: dict[str, NoiseModel]) -> bool:
    """Whether two sets of models have the same components per axis and whitening that differs little
    (each variance within a factor 2)."""
    for a, m in new.items():
        o = old.get(a)
        if o is None or m.is_white != o.is_white:
            return False
        if (m.flicker_b > 0) != (o.flicker_b > 0) or (m.rrw_k > 0) != (o.rrw_k > 0) or len(m.gm) != len(o.gm):
            return False
        pairs = [(m.flicker_b, o.flicker_b), (m.rrw_k, o.rrw_k)] + [(x[0], y[0]) for x, y in zip(m.gm, o.gm)]
        if any(a_ > 0 and b_ > 0 and abs(math.log(a_ / b_)) > math.log(math.sqrt(2.0)) for a_, b_ in pairs):
            return False
    return True


def findings(p: Prepared, models: dict[str, NoiseModel], resid: dict[str, np.ndarray],
             unexplained: list[dict[str, Any]], hidden: frozenset[str] = frozenset(),
             alternatives: dict[str, Any] | None = None) -> list[Finding]:
    """The noise terms named on each axis with nothing unexplained (module docstring). A slow one
    (flicker, a random walk, a Gauss-Markov term of ≥ :data:`SLOW_SAMPLES` samples) on an axis of
    ``alternatives`` (:func:`beyond_noise`) carries ``evidence["alternative"]``: the named slow shape
    one run cannot tell from it (:func:`alternative_evidence`). An annotation, never a name. A slow
    one the BIC refused and :func:`fit_models` took when asked (``slow_parts``) carries
    ``evidence["asked"]``: why (the structure in time, the draws that matched it)."""
    left = {u["axis"] for u in unexplained}
    out: list[Finding] = []
    for a, m in models.items():
        if a in left or m.is_white:
            continue
        before = float(np.sqrt(np.mean((resid[a] - resid[a].mean()) ** 2)))
        after = math.sqrt(m.whitener().innovation_var)
        ev = {"noise_model": m.describe(), "d_bic": [s["d_bic"] for s in m.steps if s["accepted"]]}
        slow = dict(ev)
        asked = [s["reason"] for s in m.steps if s.get("asked") and "reason" in s]
        if asked:  # the slow part the BIC refused, taken because the probes' structure is within it
            slow["asked"] = asked[-1]
        if alternatives and a in alternatives:
            slow["alternative"] = alternative_evidence(alternatives[a])
        if m.flicker_b > 0 and "bias_instability" not in hidden:
            lo, hi = _flicker_taus(m)
            out.append(Finding("bias_instability", a, {"b_dps": m.flicker_b, "tau_min_s": lo, "tau_max_s": hi},
                               before, after, dict(slow)))
        if m.rrw_k > 0 and "rate_random_walk" not in hidden:
            out.append(Finding("rate_random_walk", a, {"k_dps_per_sqrt_s": m.rrw_k}, before, after, dict(slow)))
        if "gauss_markov" not in hidden:
            for sigma, tau in m.gm:
                out.append(Finding("gauss_markov", a, {"sigma_dps": sigma, "tau_s": tau}, before, after,
                                   dict(slow if tau >= SLOW_SAMPLES * m.dt_s else ev)))
    return out


def alternative_evidence(alt: dict[str, Any]) -> dict[str, Any]:
    """The ``alternative`` entry of a slow noise finding's evidence (``docs/diagnose.md``, Output):
    the named shape (``effect``, ``params`` in the effect's units: deg/s, s), its ΔIC on the data,
    the fraction of the noise model's realisations whose best named shape is as large, and what
    separates the two."""
    return {"effect": alt["effect"], "params": alt["params"], "describe": alt["describe"], "d_ic": alt["d_ic"],
            "draws_as_large": alt["draws_as_large"], "draws": alt["draws"],
            "fraction_as_large": alt["draws_as_large"] / alt["draws"],
            "separated_by": SEPARATED_BY}


def _flicker_taus(m: NoiseModel) -> tuple[float, float]:
    from bench.analysis.noise_model import flicker_range

    taus, _ = flicker_range(m.dt_s, m.duration_s)
    return float(taus[0]), float(taus[-1])


def readout(r: np.ndarray, fs: float) -> dict[str, Any]:
    """IEEE Std 952 read-outs of residual ``r`` (deg/s at ``fs`` Hz): ARW (deg/√h), bias instability
    (deg/h), rate random walk (deg/h/√h), each with the τ it was read at (s) or the reason it is not."""
    from bench.analysis.allan import analysis_m, overlapping_adev, read_noise_terms

    if r.shape[0] < 64:
        return {}
    al = overlapping_adev(r, fs, m=analysis_m(r.shape[0], fs))
    rd = read_noise_terms(al).readings
    out: dict[str, Any] = {}
    for key, term in (("arw_deg_per_sqrt_h", "arw"), ("bias_instability_deg_per_h", "bias_instability"),
                      ("rrw_deg_per_h_per_sqrt_h", "rrw")):
        t = rd[term]
        out[key] = t.customary(t.value)
        out[key.rsplit("_deg", 1)[0] + "_read"] = (
            {"tau_s": t.tau_s, "how": t.how or None, "estimate_only": t.estimate_only} if t.value is not None
            else {"reason": t.reason})
    return out


ANGLE_RANDOM_WALK = "angle_random_walk"
"""IEEE Std 952's name of white rate noise (N, deg/√h): the term every axis' model holds."""


def section(p: Prepared, models: dict[str, NoiseModel], resid: dict[str, np.ndarray],
            named: list[Finding] = ()) -> dict[str, dict[str, Any]]:
    """The ``noise`` section of the result: per axis the fitted model (IEEE 952 units), whether the fits
    were generalised least squares against it, the Allan read-outs of the residual, and ``named``: the
    IEEE 952 noise terms named on the axis, :data:`ANGLE_RANDOM_WALK` first (white rate noise is in
    every model: an axis whose model is white names it alone), then the correlated terms named as
    findings (``named``)."""
    out = {}
    for a, m in models.items():
        out[a] = {"model": m.terms(), "describe": m.describe(), "whitened": a in p.whiten,
                  "ieee952": readout(resid[a], p.fs),
                  "named": [ANGLE_RANDOM_WALK] + [f.effect for f in named if f.axis == a]}
    return out
