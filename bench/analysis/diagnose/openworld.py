"""After selection: what the named terms may claim, and the structure that nothing in the vocabulary
names (``docs/diagnose.md``, "Open world"). Noise terms are named by the noise model (``noise.py``).

0. The search's catch-all random walk is dropped: noise terms are named by the noise model.
1. **Bias steps** are not named when a covariate changes at the same instant.
2. **Specific evidence.** A named term of a family (``"time"``: slow terms, ``"rate"``: static
   functions of the rate) must still be needed when the family's generic probe is in the model,
   whenever that probe finds structure the final model leaves: otherwise it is a partial explanation
   of something else and is dropped (prefer "unexplained" over a weak name). A term on an axis where
   a probe of another family still finds more than the term explains must be needed with that probe
   in the model: otherwise it is part of that larger structure (:func:`_part_of_larger`).
3. **Unexplained.** Every generic probe (:data:`terms.PROBES`: a smooth function of time, of the rate,
   of temperature by heating/cooling, of pressure, a spectral line) is evaluated on the final model
   by the same held-out criterion as a candidate; one that is acceptable is structure left, reported
   per axis with its size and where it lives. With a noise model (prewhitened fits) the probes are
   judged against that model: the sensor's own correlated noise is not structure.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from bench.analysis.allan import chi2_ppf, overlapping_adev
from bench.analysis.diagnose.data import Prepared
from bench.analysis.diagnose.engine import State, Term, build_state, compare, evaluate, material, term_df
from bench.analysis.diagnose.terms import CANDIDATES, FAMILY_PROBE, PROBES, Built, Candidate

EXCESS_P = 1e-3
"""Per-τ false-alarm probability for 'above the white-noise line' (chi-squared, white-FM edf)."""
EXCESS_MIN = 1.1
"""... and at least this ratio of Allan variances (a material excess, not a rounding of N)."""
MIN_CLUSTERS = 4
"""Fewest independent clusters (n/m) at a τ used for the slope."""
COINCIDE_RANGE = 0.05
"""... and more than this fraction of the covariate's whole range (a steady slow trend is not a jump)."""
PARTIAL_SHARE = 0.25
"""A named term is a partial explanation when its family's probe still explains, on the final model,
more than this share of the variance the term itself explains."""
LARGER_SHARE = 1.0
"""A probe of another family that still explains more than this multiple of a named term's variance
on the term's axis makes the term a candidate part of that larger structure (:func:`_part_of_larger`)."""
NOT_MATERIAL = "not material in the final model"
"""The reason a term found by the search is dropped when it no longer carries its weight in the final
company (judged against a residual that may still hold the sensor's slow noise: the selection
against the noise model searches it again, ``bench.analysis.diagnose._diagnose``)."""
COINCIDE_SIGMA = 5.0
"""A bias step coincides with a covariate when the covariate's change across the step (means of the
blocks either side) exceeds this many of its typical block-to-block changes..."""


@dataclass
class Excess:
    """The residual's Allan deviation against its white-noise line."""

    taus_s: np.ndarray
    adev: np.ndarray
    white: np.ndarray
    significant: np.ndarray
    slope: float = float("nan")
    """Slope of the excess deviation √(σ² − σ_white²) on log-log axes over the significant range."""
    tau_range_s: tuple[float, float] | None = None
    level_dps: float = float("nan")
    """Excess deviation at the middle of the range (deg/s)."""

    @property
    def decades(self) -> float:
        if self.tau_range_s is None:
            return 0.0
        return math.log10(self.tau_range_s[1] / self.tau_range_s[0])

    def as_json(self) -> dict[str, Any]:
        return {"slope": None if not math.isfinite(self.slope) else self.slope,
                "tau_range_s": None if self.tau_range_s is None else list(self.tau_range_s),
                "excess_dps": None if not math.isfinite(self.level_dps) else self.level_dps}


def allan_excess(r: np.ndarray, fs: float) -> Excess:
    """Overlapping Allan deviation of residual ``r`` (deg/s at ``fs`` Hz) against the white-noise
    line N/√τ, N² the smallest σ²·τ of the first four octaves (where white noise dominates), the
    τ where it lies significantly above (chi-squared at :data:`EXCESS_P` and :data:`EXCESS_MIN`), and
    the log-log slope of the excess over the longest run of such τ that reaches the longest τ."""
    al = overlapping_adev(r, fs)
    taus, adev = al.taus_s, al.adev
    n2 = float(np.min((adev[:4] ** 2) * taus[:4])) if taus.size else 0.0
    white = np.sqrt(n2 / taus)
    limit = chi2_ppf(1.0 - EXCESS_P, al.edf) / al.edf
    ratio = (adev / np.maximum(white, 1e-300)) ** 2
    clusters = al.n_samples / al.m
    sig = (ratio > np.maximum(limit, EXCESS_MIN)) & (clusters >= MIN_CLUSTERS)
    out = Excess(taus, adev, white, sig)
    idx = np.flatnonzero(sig)
    if idx.size < 2:
        return out
    # the longest contiguous run of significant τ
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    run = max(runs, key=lambda r_: r_.size)
    if run.size < 2:
        return out
    ex = np.sqrt(np.maximum(adev[run] ** 2 - white[run] ** 2, 1e-300))
    w = np.sqrt(al.edf[run])
    slope, _ = np.polyfit(np.log(taus[run]), np.log(ex), 1, w=w)
    out.slope = float(slope)
    out.tau_range_s = (float(taus[run[0]]), float(taus[run[-1]]))
    out.level_dps = float(ex[run.size // 2])
    return out


def coincident_covariates(p: Prepared, t_step: float) -> list[str]:
    """Measured covariates that change abruptly at ``t_step`` (s): pressure, temperature trend,
    specific force, power cycles. A bias that moves with one of them is not a bias step."""
    L = p.blocks.length
    i = int(np.searchsorted(p.t, t_step))
    covs: dict[str, np.ndarray] = {}
    if p.pressure is not None:
        covs["pressure"] = np.log10(p.pressure)
    if p.temp is not None:
        covs["temperature trend"] = p.dtemp()
    if p.accel is not None:
        # on a turning table only the component along its axis moves with the tilt; the others turn
        # with the table angle all the time
        axes = [p.table_axis.lstrip("+-")] if p.table_axis else ["x", "y", "z"]
        for a in axes:
            covs[f"specific force {a}"] = p.accel[:, "xyz".index(a)]
    if p.power_on is not None:
        covs["power-on time"] = p.power_on
    out = []
    for name, c in covs.items():
        if i < L or i > p.n - L:
            continue
        change = abs(float(np.mean(c[i:i + L]) - np.mean(c[i - L:i])))
        means = p.blocks.shaped(c)[:, :, 0].mean(axis=1)[: max(p.n // L, 2)]
        typical = float(np.median(np.abs(np.diff(means)))) if means.size > 2 else 0.0
        if change > max(COINCIDE_SIGMA * typical, COINCIDE_RANGE * float(np.ptp(c)), 1e-9):
            out.append(name)
    return out


def _probe_evaluations(p: Prepared, state: State, axis: str, skip: tuple[str, ...] = ()) -> dict[str, Any]:
    """Every probe (but ``skip``) evaluated on ``state`` at ``axis``: name -> Evaluation."""
    out = {}
    for name in PROBES:
        if name in skip:
            continue
        hit = probe_term(p, state, name, axis)
        if hit is not None:
            out[name] = hit[1]
    return out


def _lives_in_time_only(evals: dict[str, Any]) -> tuple[bool, str]:
    """Whether the slow structure the probes ``evals`` (:func:`_probe_evaluations`) find is best
    explained by time itself: the time probe beats every covariate probe by IC_MIN (else it lives
    against that covariate and is not a random process of the sensor)."""
    t = evals["probe:time"].d_ic if "probe:time" in evals else 0.0
    rivals = {k: e.d_ic for k, e in evals.items() if k not in ("probe:time", "probe:spectrum") and e.d_ic < -10.0}
    if not rivals:
        return True, ""
    best = min(rivals, key=rivals.get)
    if t < rivals[best] - 10.0:
        return True, ""
    return False, f"the structure lives as well against {PROBES[best].where} (ΔIC {rivals[best]:+.0f} vs time {t:+.0f})"


@dataclass
class OpenWorld:
    found: list[Term]
    unexplained: list[dict[str, Any]]
    dropped: list[dict[str, Any]]
    excess: dict[str, Excess]


def ratio(drop: float) -> float:
    """A relative drop of an RMS (1 − after/before) as the ratio before/after, the one meaning of
    ``gain`` in the output (findings and unexplained alike)."""
    return 1.0 / (1.0 - drop) if drop < 1.0 else float("inf")


def _without(found: list[Term], term: Term) -> list[Term]:
    return [t for t in found if t is not term]


def _drop(dropped: list[dict[str, Any]], found: list[Term], term: Term, reason: str) -> list[Term]:
    """Record why ``term`` leaves the model; ``found`` without it."""
    dropped.append({"effect": term.effect, "axis": term.axis, "nl": dict(term.nl), "reason": reason})
    return _without(found, term)


def _not_needed_beside(p: Prepared, terms: list[Term], generic: Term, term: Term, key: str) -> float | None:
    """ΔIC of adding ``term`` to ``terms`` + ``generic`` (a generic shape of the structure), kept in the
    term's evidence under ``key``: None when the term is still needed (ΔIC < −10 and a gain), else
    that ΔIC."""
    reduced = build_state(p, terms + [generic])
    with_term = build_state(p, terms + [generic, term])
    d_ic, gain, _, gain_band, _ = compare(p, reduced, with_term, term.built.axes, term_df(term))
    term.evidence.update({key: d_ic})
    return None if d_ic < -10.0 and max(gain, gain_band) > 0 else d_ic


def _prune(dropped: list[dict[str, Any]], found: list[Term], eligible: Callable[[Term], bool],
           why_not: Callable[[list[Term], Term], str | None]) -> list[Term]:
    """``found`` less, one at a time until none is left to drop, each free term that is ``eligible``
    and for which ``why_not(found, term)`` gives a reason (recorded in ``dropped``)."""
    changed = True
    while changed:
        changed = False
        for term in [t for t in found if not t.fixed and eligible(t)]:
            why = why_not(found, term)
            if why:
                found = _drop(dropped, found, term, why)
                changed = True
                break
    return found


def probe_term(p: Prepared, state: State, name: str, axis: str) -> tuple[Term, Any] | None:
    """The probe evaluated on ``state`` at ``axis`` and, when acceptable, as a model term."""
    probe = PROBES[name]
    if probe.missing(p) or axis not in probe.candidate_axes(p) or probe.not_excited(p, axis):
        return None
    ctx = state.context()
    e = evaluate(p, state, probe, axis, ctx)
    if e is None:
        return None
    return Term(name, axis, dict(e.nl_full), probe.build(p, axis, e.nl_full, ctx)), e


def _partial(p: Prepared, base_terms: list[Term], found: list[Term], final: State, term: Term, a: str,
             probe_name: str, left: float) -> str | None:
    """Why ``term`` is only a partial explanation of what the probe ``probe_name`` finds on axis
    ``a`` of the final model (``left``: the variance the probe still explains there), or None: it
    must explain more than PARTIAL_SHARE⁻¹ times what it leaves, and be needed with the probe in."""
    others = _without(found, term)
    without = build_state(p, base_terms + others)
    explained = without.axes[a].mse - final.axes[a].mse
    where = PROBES[probe_name].where
    if left > PARTIAL_SHARE * explained:
        return (f"partial explanation: {where} still explains {math.sqrt(max(left, 0)):.2g} deg/s after it, against "
                f"{math.sqrt(max(explained, 0)):.2g} deg/s explained by the term")
    hit = probe_term(p, build_state(p, base_terms + others), probe_name, a)
    if hit is None:
        return None
    d_ic = _not_needed_beside(p, base_terms + others, hit[0], term, "d_ic_given_probe")
    if d_ic is None:
        return None
    return (f"partial explanation: {where} leaves structure it does not explain, and with that structure modelled "
            f"generically the term is not needed (ΔIC {d_ic:+.1f})")


def _part_of_larger(p: Prepared, base_terms: list[Term], found: list[Term], term: Term,
                    cache: dict[Any, Any]) -> str | None:
    """Why ``term`` is part of a larger structure that a probe of another family finds on its axis in
    the final model, or None. Such a probe explains more variance than the term itself
    (:data:`LARGER_SHARE`); the term must then still be needed with that probe in the model (ΔIC
    < −10), or the term only takes the share of that structure its own shape happens to match.
    (Its own family's probe is :func:`_partial`'s, with the stricter share.)"""
    a = term.axis
    key = (tuple(id(t) for t in found), a)  # the final model's probes, once per model and axis
    if key not in cache:
        final = build_state(p, base_terms + found)
        cache[key] = (final, _probe_evaluations(p, final, a))
    final, evals = cache[key]
    others = _without(found, term)
    without = build_state(p, base_terms + others)
    explained = without.axes[a].mse - final.axes[a].mse
    own = FAMILY_PROBE.get(CANDIDATES[term.effect].family or "")
    for name, e in evals.items():
        if name == own or not e.acceptable:
            continue
        left = e.rms_before ** 2 - e.rms_after ** 2
        if left <= LARGER_SHARE * explained:
            continue
        generic = probe_term(p, without, name, a)
        if generic is None:
            continue
        d_ic = _not_needed_beside(p, base_terms + others, generic[0], term, "d_ic_given_larger")
        if d_ic is not None:
            return (f"part of a larger structure: {PROBES[name].where} still explains "
                    f"{math.sqrt(max(left, 0)):.2g} deg/s after it, against {math.sqrt(max(explained, 0)):.2g} deg/s "
                    f"explained by the term, and with that structure modelled generically the term is not needed "
                    f"(ΔIC {d_ic:+.1f})")
    return None


COMMON_CHECK = ("bias_step",)
"""Terms checked against the shape the other axes' residuals share (:func:`_shared`): a jump at one
instant follows no covariate. (Not the warm-up: every axis of a sensor warms up from the same
power-on, each named on its own.)"""


class CommonModeProbe(Candidate):
    """The other axes' final-model residuals (unwhitened), as block-length moving averages, as
    regressors of one axis: a slow shape the axes share."""

    name = "probe:common_mode"
    where = "the other axes' residual (a shape the axes share)"

    def __init__(self, shapes: dict[str, np.ndarray]):
        self.shapes = shapes

    def candidate_axes(self, p):
        return list(self.shapes)

    def build(self, p, axis, nl, ctx):
        return Built(cols={axis: self.shapes[axis]})

    def params(self, p, axis, nl, coef):
        return {}


def _smooth(x: np.ndarray, width: int) -> np.ndarray:
    """Centred moving average of ``x`` over ``width`` rows (shorter at the ends)."""
    if width <= 1:
        return x.copy()
    k = np.ones(width)
    return np.convolve(x, k, mode="same") / np.convolve(np.ones_like(x), k, mode="same")


def _shared(p: Prepared, base_terms: list[Term], found: list[Term], term: Term) -> str | None:
    """Why ``term`` (one axis) is not an effect of its axis, or None: with the other axes' residual
    shapes (block-length moving averages of the final model's residuals, without prewhitening) in the
    model, ``term`` must still be needed (ΔIC < −10 and a gain)."""
    a = term.axis
    others = _without(found, term)
    # the other axes' steps at the same instant are part of the shape they share (else two axes'
    # steps for one common event would each hide the event from the other's check)
    near = 2.0 * p.blocks.length / p.fs
    mates = [t for t in others if t.effect == term.effect and abs(float(t.nl["t_step_s"]) - float(term.nl["t_step_s"])) <= near]
    saved = p.whiten
    p.whiten = {}
    try:
        raw = build_state(p, base_terms + [t for t in found if not any(t is m for m in mates)])
        shapes = np.column_stack([_smooth(raw.axes[b].resid(), p.blocks.length) for b in p.axes if b != a])
    finally:
        p.whiten = saved
    probe = CommonModeProbe({a: shapes})
    reduced0 = build_state(p, base_terms + others)
    e = evaluate(p, reduced0, probe, a, reduced0.context())
    if e is None or not e.acceptable:
        return None  # the other axes share nothing with this one
    common = Term(probe.name, a, {}, probe.build(p, a, {}, None))
    d_ic = _not_needed_beside(p, base_terms + others, common, term, "d_ic_given_common_mode")
    if d_ic is None:
        return None
    return (f"shared by the other axes: with the shape their residuals share modelled, the term is not needed "
            f"(ΔIC {d_ic:+.1f}); a common-mode disturbance, not an effect of this axis")


NOISE_ALTERNATIVES = (("flicker", "rrw", "gm"), ("flicker", "gm"), ("rrw", "gm"))
"""The noise models a slow term is weighed against (forward selection within each set of kinds)."""


def look_elsewhere(p: Prepared) -> float:
    """2·ln K, K the slow shapes the search could have picked in place of any one "time"-family term:
    per axis, each searched candidate's grid of time constants, transition pressures or deadbands,
    and for a bias step every block boundary (the cumulative-sum scan looks at every instant). The
    term won a maximisation over those K shapes, which its BIC (one parameter charged per nonlinear
    parameter) does not pay for; adding 2·ln K to the threshold keeps the false-alarm rate of the
    best of K at that of one shape (Bonferroni). On a 1-h, 1-Hz session with temperature and
    pressure K ≈ 500 and the charge ≈ 12. Hidden names count too: the charge is that of the whole
    vocabulary's search (a re-selection against the noise model hides what the first did not name,
    but the term was the best of the first search)."""
    k = 0
    for cand in CANDIDATES.values():
        if cand.family != "time" or cand.noise_term or cand.missing(p):
            continue
        for a in p.axes:
            if cand.not_excited(p, a):
                continue
            k += max(p.n // max(p.blocks.length, 1), 1) if cand.name == "bias_step" else len(cand.grid(p, a, None))
    return 2.0 * math.log(k) if k > 1 else 0.0


def _noise_alternative(p: Prepared, base_terms: list[Term], found: list[Term], term: Term,
                       charge: float = 0.0) -> str | None:
    """Why ``term`` (a slow term of the "time" family) is not told apart from the sensor's slow noise,
    or None. Two joint models of the axis: the term plus a noise model fitted to what it leaves,
    against no term and a noise model (white, flicker, random walk, Gauss-Markov) fitted to the
    residual with the term's part in it; exact Gaussian likelihoods (innovations of each model),
    BIC charging the term's parameters and the noise models' own. The term stays when its model is
    better by IC_MIN plus ``charge`` (:func:`look_elsewhere`: the term is the best of many slow
    shapes): a bias that wanders like flicker over one run is the sensor's noise, whatever step or
    transient fits it best (``docs/diagnose.md``, what one run cannot separate)."""
    from bench.analysis.noise_model import IC_MIN, fit_noise_model

    a = term.axis
    saved = p.whiten
    p.whiten = {}
    try:
        r_term = build_state(p, base_terms + found).axes[a].resid()
        r_none = build_state(p, base_terms + _without(found, term)).axes[a].resid()
    finally:
        p.whiten = saved
    def bic(r: np.ndarray, m: Any) -> float:
        return -2.0 * m.exact_loglik(r, p.t) + m.n_params * math.log(p.n)

    m_term = fit_noise_model(r_term, 1.0 / p.fs, p.bin_rows)
    # the noise explanation at its most favourable: each slow kind given its chance
    alts = [fit_noise_model(r_none, 1.0 / p.fs, p.bin_rows, allow=allow) for allow in NOISE_ALTERNATIVES]
    scores = [bic(r_none, m) for m in alts]
    m_none = alts[int(np.argmin(scores))]
    d_bic = bic(r_term, m_term) + term_df(term) * math.log(p.n) - min(scores)
    term.evidence.update({"d_bic_vs_noise": d_bic, "noise_alternative": m_none.describe(), "look_elsewhere": charge})
    if d_bic < -(IC_MIN + charge):
        return None
    return (f"not told apart from the sensor's slow noise: no term and {m_none.describe()} explains the axis as well "
            f"(ΔBIC of the term {d_bic:+.1f}; needed below {-(IC_MIN + charge):+.1f}, the best of many slow shapes)")


def finish(p: Prepared, base_terms: list[Term], found: list[Term], hidden: frozenset[str] = frozenset(),
           progress: Callable[[str], None] | None = None) -> OpenWorld:
    """Steps 1-3 of the module docstring on the terms ``found`` by the search."""
    say = progress or (lambda _msg: None)
    found = list(found)
    dropped: list[dict[str, Any]] = []
    excess: dict[str, Excess] = {}

    # 1. the catch-all random walk never keeps its name: the noise model names the noise
    for term in [t for t in found if t.effect == "rate_random_walk" and not t.fixed]:
        found = _drop(dropped, found, term, "a random walk is a noise term: the noise model names it")

    # bias steps: not when a covariate changes at the same time
    for term in [t for t in found if t.effect == "bias_step" and not t.fixed]:
        hits = coincident_covariates(p, float(term.nl["t_step_s"]))
        if hits:
            found = _drop(dropped, found, term, f"coincides with a change of {', '.join(hits)}: not a bias step of the sensor")

    # 2. specific evidence against each family's probe
    changed = True
    while changed:
        changed = False
        final = build_state(p, base_terms + found)
        for a in p.axes:
            for family, probe_name in FAMILY_PROBE.items():
                mine = [t for t in found if not t.fixed and t.axis == a and CANDIDATES[t.effect].family == family]
                if not mine:
                    continue
                hit = probe_term(p, final, probe_name, a)
                if hit is None or not hit[1].acceptable:
                    continue
                say(f"open world: {probe_name} finds structure on {a}; checking {', '.join(t.effect for t in mine)}")
                left = hit[1].rms_before ** 2 - hit[1].rms_after ** 2
                for term in mine:
                    why = _partial(p, base_terms, found, final, term, a, probe_name, left)
                    if why:
                        found = _drop(dropped, found, term, why)
                        changed = True
                        break
                if changed:
                    break
            if changed:
                break

    # 2a. a term that is a small part of a larger structure another probe finds on its axis must be
    # needed with that structure modelled generically (a timing error's rate-derivative structure
    # taken in part as a gear line)
    larger: dict[Any, Any] = {}
    found = _prune(dropped, found, lambda t: t.axis in p.axes and CANDIDATES[t.effect].family is not None,
                   lambda f, t: _part_of_larger(p, base_terms, f, t, larger))

    # 2b. a transient of one axis that the other axes' residuals share (a phone's common-mode
    # event, a bench disturbance) is not an effect of that axis
    if len(p.axes) > 1:
        found = _prune(dropped, found, lambda t: t.effect in COMMON_CHECK, lambda f, t: _shared(p, base_terms, f, t))
    # 2c. a slow term of one run must explain its axis better than the sensor's own slow noise could
    charge = look_elsewhere(p)
    found = _prune(dropped, found, lambda t: CANDIDATES[t.effect].family == "time",
                   lambda f, t: _noise_alternative(p, base_terms, f, t, charge))

    # every term still material in the final company (a term found next to a random walk that has
    # since lost its name may no longer carry its weight)
    changed = True
    while changed and found:
        changed = False
        full = build_state(p, base_terms + found)
        for term in [t for t in found if not t.fixed]:
            reduced = build_state(p, base_terms + _without(found, term))
            d_ic, gain, phi, gain_band, band_t = compare(p, reduced, full, term.built.axes, term_df(term))
            if not material(d_ic, gain, gain_band, band_t):
                found = _drop(dropped, found, term, f"{NOT_MATERIAL} (ΔIC {d_ic:+.1f}, gain {100 * gain:.2g} %)")
                changed = True
                break

    # 3. noise terms and what is left
    final = build_state(p, base_terms + found)
    unexplained: list[dict[str, Any]] = []
    for a in p.axes:
        say(f"open world: looking for structure left on {a}")
        ex = allan_excess(final.axes[a].resid(), p.fs)
        excess[a] = ex
        evals = _probe_evaluations(p, final, a)
        hits = [e for e in evals.values() if e.acceptable]
        if not hits:
            continue
        hits.sort(key=lambda e: e.d_ic)
        where = []
        for e in hits:
            size = math.sqrt(max(e.rms_before ** 2 - e.rms_after ** 2, 0.0))
            band = math.sqrt(max(e.band_before ** 2 - e.band_after ** 2, 0.0))
            item = {"against": PROBES[e.cand.name].where, "probe": e.cand.name.split(":", 1)[1],
                    "rms_dps": size, "band_rms_dps": band, "gain": ratio(e.gain), "gain_band": ratio(e.gain_band),
                    "d_ic": e.d_ic}
            if "frequency_hz" in e.nl_full:
                item["frequency_hz"] = float(e.nl_full["frequency_hz"])
            where.append(item)
        unexplained.append({
            "axis": a,
            "rms_dps": max(w["rms_dps"] for w in where),
            "band_rms_dps": max(w["band_rms_dps"] for w in where),
            "band_s": p.blocks.length / p.fs,
            "residual_rms_dps": math.sqrt(final.axes[a].mse),
            "where": where,
            "allan_excess": ex.as_json(),
        })
    return OpenWorld(found, unexplained, dropped, excess)
