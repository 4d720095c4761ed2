"""``bench diagnose``: show what the sensor model gets wrong, name the cause, extend the model,
measure the gain (``docs/diagnose.md``).

Public API::

    result = diagnose(ds, model_path=None, seed=0)   # ds: bench.analysis.dataset.Dataset
    result.json                # {"axes": ..., "findings": [...], "skipped": [...]}
    result.summary_lines()     # human summary
    result.extended_model()    # YAML-ready sensor model with the findings as effects
    write_report(result, ds, "out.html")
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from bench.analysis.dataset import Dataset
from bench.analysis.diagnose import noise as nm
from bench.analysis.diagnose.confounded import temperature_in_time, white_rms
from bench.analysis.diagnose.data import Prepared, prepare
from bench.analysis.diagnose.engine import (GAIN_MIN, IC_MIN, T_REF_SCALE_C, Search, Term, baseline_built,
                                            build_state, has_temp_cubic, search)
from bench.analysis.diagnose.result import UNBOUNDED, DiagnoseResult, Finding
from bench.analysis.diagnose.terms import AXES, CANDIDATES, Built, Context
from bench.errors import InputError
from bench.model import effects as fx

__all__ = ["diagnose", "DiagnoseResult", "Finding", "write_report", "IC_MIN", "GAIN_MIN"]


def diagnose(ds: Dataset, model_path: str | None = None, seed: int = 0, hidden: tuple[str, ...] | frozenset[str] = (),
             progress: Any = None, power_on_at: float | None = None) -> DiagnoseResult:
    """Fit the baseline sensor model (plus the model file's known terms) to ``ds``, search the
    vocabulary for missing effects by blocked cross-validation, and return the findings.

    ``model_path``: a sensor-model YAML (``configs/sensors/*.yaml`` or a previous ``-o`` output);
    its nonzero warm-up, pressure, g-sensitivity and rate-random-walk terms and its ``effects:``
    join the baseline (nonlinear parameters as given, amplitudes refitted) and are not searched
    again. ``seed`` is accepted for interface stability; the method is deterministic. ``hidden``:
    vocabulary names left out of the search (what the engine says about an effect it has no name
    for; the tests hide the injected effect this way). ``progress``: a callable taking one line of
    text, called as the search goes. ``power_on_at``: when the data have no ``power_on_s`` column,
    the time (s, on the ``time_s`` axis) the sensor was powered on (``--power-on-at``); None: the
    first sample's time when the log starts within the first minute of power (module ``data``,
    :data:`~bench.analysis.diagnose.data.POWER_ON_DEFAULT`).
    """
    del seed  # deterministic: blocked folds, grids, fixed-seed draws (noise.beyond_noise)
    from bench.analysis.diagnose.blas import single_thread

    with single_thread():
        return _diagnose(ds, model_path, hidden_names(hidden), progress, power_on_at)


def hidden_names(hidden: tuple[str, ...] | frozenset[str]) -> frozenset[str]:
    """``hidden`` as a set of vocabulary names; :class:`InputError` naming any that is not one."""
    unknown = set(hidden) - set(CANDIDATES)
    if unknown:
        raise InputError(f"diagnose: unknown vocabulary name(s) to hide: {', '.join(sorted(unknown))}")
    return frozenset(hidden)


def _diagnose(ds: Dataset, model_path: str | None, hidden: frozenset[str] = frozenset(),
              progress: Any = None, power_on_at: float | None = None,
              known: tuple[tuple[str, str, dict[str, Any]], ...] = ()) -> DiagnoseResult:
    """:func:`diagnose` without its checks; ``known``: more (name, axis, nonlinear parameters) terms
    fixed as the model file's are (``runs.py``: a warm-up shared by several runs)."""
    p = prepare(ds, power_on_at=power_on_at, fit_lines="periodic" not in hidden)
    raw, spec_effects, model_terms = None, [], list(known)
    if model_path is not None:
        raw, spec_effects, model_terms = _load_model(model_path)
        model_terms += list(known)
    base_terms = [Term("baseline", a, {}, baseline_built(p, a)) for a in p.axes]
    ctx = build_state(p, base_terms).context()
    fixed = []
    for name, axis, nl in model_terms + [(e.name, e.axis, e) for e in spec_effects]:
        fixed += _fixed_terms(p, name, axis, nl, ctx)
    found, ow = _select(p, base_terms + fixed, hidden, progress)
    unbounded = _unbounded(found.dropped, {})
    # the sensor's noise model from what is left; when it is not white, selection is made again
    # against it (generalised least squares): correlated noise may have passed for structure, and may
    # have hidden it. When the correlated part is weak (the noise is mostly white) only the causes
    # named already are tested again: a small model error is no reason to search anew
    white = nm.noise_terms(p, base_terms + fixed + ow.found, ow.unexplained)
    resid = nm.residuals(p, white, [])
    # slow structure in time larger than the noise model fitted to it makes is structure: decided on
    # the unwhitened fits and kept through the rounds (a whitener with the slow part in it hides it)
    white_left = frozenset(u["axis"] for u in ow.unexplained)
    alternatives: dict[str, Any] = {}  # a named slow shape one run cannot tell from the noise term
    slow_parts: dict[str, Any] = {}  # axes without a slow part asked again with one (noise.beyond_noise)
    in_time = frozenset(u["axis"] for u in ow.unexplained if u["where"] and u["where"][0]["probe"] in nm.NOT_NOISE)
    structure = {} if hidden & set(nm.KINDS) else nm.beyond_noise(p, white, resid, white_left, hidden, alternatives,
                                                                   slow_parts, in_time)
    models = nm.fit_models(p, resid, hidden, white_left, structure, slow_parts)
    # against a noise model the slow noise is the model's: no catch-all random walk in the search
    search_hidden = hidden | {"rate_random_walk"}
    if not any(nm.predictable(m, resid[a]) for a, m in models.items()):
        from bench.analysis.diagnose.openworld import NOT_MATERIAL

        # ... and those found but judged not material against a residual that still held the slow
        # noise (an Earth rate next to a random walk at 10 Hz: ΔIC −22, gain 0.7 % against white)
        named = {t.effect for t in ow.found} | {d["effect"] for d in ow.dropped if d["reason"].startswith(NOT_MATERIAL)}
        search_hidden |= frozenset(n for n in CANDIDATES if n not in named and not CANDIDATES[n].noise_term)
    for _ in range(NOISE_ROUNDS):
        whiten = {a: m.whitener() for a, m in models.items() if not m.is_white}
        if not whiten:
            # white everywhere: at once, or once the selection against the model found the structure
            # the model had taken (then a white selection again is the first one, whose residual gave
            # that model: a cycle, hidden Earth rate CI seed 0's y, Gauss-Markov <-> table angle)
            break
        if progress is not None:
            progress("selecting again against the noise model ("
                     + "; ".join(f"{a}: {m.describe()}" for a, m in models.items()) + ")")
        p.whiten = whiten
        found, ow = _select(p, base_terms + fixed, search_hidden, progress)
        unbounded = _unbounded(found.dropped, unbounded)
        resid = nm.residuals(p, base_terms + fixed + ow.found, ow.unexplained)
        again = nm.fit_models(p, resid, hidden, frozenset(u["axis"] for u in ow.unexplained), structure, slow_parts)
        stable = nm.same_structure(models, again)
        models = again
        if stable:
            break
    noise = nm.findings(p, models, resid, ow.unexplained, hidden, alternatives)
    # a warm-up left unnamed in any round is said, unless named (bounded) in the last one
    found.dropped.extend(d for a, d in unbounded.items() if d not in found.dropped
                         and not any(t.effect == "warmup_transient" and t.axis == a for t in ow.found))
    return _result(p, ds, found, model_path, raw, fixed, ow, noise, nm.section(p, models, resid, noise))


NOISE_ROUNDS = 2
"""Most selections against a re-fitted noise model after the first (white) one."""


def _select(p: Prepared, terms: list[Term], hidden: frozenset[str], progress: Any) -> tuple[Search, Any]:
    """Forward/backward selection and the open-world checks on the current fits (prewhitened by
    ``p.whiten``): (search with the final sequence, open-world outcome)."""
    from bench.analysis.diagnose.engine import sequence
    from bench.analysis.diagnose.openworld import finish

    found = search(p, terms, hidden=hidden, progress=progress)
    ow = finish(p, terms, [t for t in found.final.terms if t.effect != "baseline" and not t.fixed], hidden, progress)
    found.sequence, found.final = sequence(p, build_state(p, terms), ow.found)
    # a warm-up whose τ the data do not bound from above is a slow drift over this run, which the
    # sensor's slow noise also makes: not named, and the axis goes on as if it had not been found
    # (its drift left to the noise model; docs/diagnose.md, Power-on)
    unbounded = [d for d in (_unbounded_warmup(p, found.final, t) for t in ow.found) if d is not None]
    if unbounded:
        gone = {(d["effect"], d["axis"]) for d in unbounded}
        ow.found = [t for t in ow.found if t.key not in gone]
        ow.dropped.extend(unbounded)
        found.sequence, found.final = sequence(p, build_state(p, terms), ow.found)
    found.dropped.extend(ow.dropped)
    return found, ow


def _unbounded(dropped: list[dict[str, Any]], before: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """``before`` (axis → ``dropped`` entry) updated with the unbounded warm-ups in ``dropped``."""
    return {**before, **{d["axis"]: d for d in dropped if d["reason"].startswith(UNBOUNDED)}}


def _unbounded_warmup(p: Prepared, final: Any, term: Term) -> dict[str, Any] | None:
    """A ``dropped`` entry for ``term`` when it is a searched warm-up whose τ interval
    (:func:`_tau_interval`) reaches the top of its grid, else None."""
    if term.effect != "warmup_transient" or term.fixed:
        return None
    lo, hi, top = _tau_interval(p, final, term, with_top=True)
    if hi < top * (1.0 - 1e-9):
        term.evidence["tau_s_interval"] = [lo, hi]  # the final state's, as the result reports it
        return None
    return {"effect": term.effect, "axis": term.axis, "nl": dict(term.nl), "tau_s_interval": [lo, hi],
            "reason": f"{UNBOUNDED}: {term.nl['tau_s']:.0f} s, interval [{lo:.0f}, {hi:.0f}] s reaches "
                      f"the top of its grid ({top:.0f} s, duration/3): a slow drift over this run, not a warm-up "
                      "one run can name"}


# ---- model file -----------------------------------------------------------------------------------
def _load_model(path: str) -> tuple[dict[str, Any], list[fx.Effect], list[tuple[str, str, dict[str, Any]]]]:
    """Raw YAML mapping, parsed effects, and the base model's own terms mapped to the vocabulary."""
    import yaml

    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: sensor model file not found")
    try:
        from bench.model.loader import load_sensor_model
    except ImportError:  # pragma: no cover - the model package ships with bench
        load_sensor_model = None
    spec = load_sensor_model(p) if load_sensor_model else None
    try:
        raw = yaml.safe_load(p.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as exc:
        raise InputError(f"{p}: cannot read the sensor model: {exc}") from None
    if not isinstance(raw, dict):
        raise InputError(f"{p}: a sensor model is a mapping (schema, model, ...)")
    effects = fx.parse_effects(spec.effects if spec is not None else raw.get("effects"))
    terms: list[tuple[str, str, dict[str, Any]]] = []
    g = getattr(spec, "gyro", None)
    imu = getattr(spec, "imu", None)
    for k, a in enumerate(AXES):
        if g is not None:
            if g.warmup_amplitude_dps[k] != 0:
                terms.append(("warmup_transient", a, {"tau_s": float(g.warmup_tau_s[k])}))
            if g.pressure_shift_vacuum_dps[k] != 0:
                terms.append(("pressure_bias", a, {"p0_torr": float(g.pressure_transition_torr)}))
            if any(v != 0 for v in g.g_sensitivity_dps_per_g[k]):
                terms.append(("g_sensitivity", a, {}))
            if g.rrw_deg_h_rth[k] != 0:
                terms.append(("rate_random_walk", a, {"k_dps_per_sqrt_s": g.rrw_deg_h_rth[k] / (3600.0 * 60.0)}))
        if imu is not None and imu.warmup_amplitude_dps[k] != 0:
            terms.append(("warmup_transient", a, {"tau_s": float(imu.warmup_settling_s[k]) / 3.0}))
    return raw, effects, terms


def _fixed_terms(p: Prepared, name: str, axis: str, src: Any, ctx: Context) -> list[Term]:
    """Terms (one per axis) for a known effect: nonlinear parameters fixed, amplitudes free."""
    cand = CANDIDATES[name]
    if cand.missing(p):
        return []
    out = []
    if isinstance(src, fx.Effect):
        axes = ["all"] if cand.shared else ([a for a in p.axes] if src.axis == "all" else [src.axis])
    else:
        axes = [axis]
    for a in axes:
        if a != "all" and a not in p.axes:
            continue
        if isinstance(src, fx.Effect):
            k = AXES.index(a) if a != "all" else 0
            prm = src.axis_params(k)
            nl = {f: getattr(prm, f) for f in ("tau_s", "p0_torr", "slope", "harmonic", "deadband_c", "delay_s",
                                               "k_dps_per_sqrt_s") if hasattr(prm, f)}
        else:
            nl = dict(src)
        if name == "earth_rate":
            prm = src.axis_params(0) if isinstance(src, fx.Effect) else fx.EarthRateParams()
            e = fx.earth_rate_sensor(p.accel, p.angle, prm.latitude_deg, prm.table_axis) * prm.scale
            built = Built(offsets={b: e[:, AXES.index(b)] for b in p.axes})
        elif name == "time_skew" and isinstance(src, fx.Effect) and src.axis != "all":
            built = cand.build(p, "all", nl, ctx)
            built = Built(offsets={src.axis: built.offsets[src.axis]} if src.axis in built.offsets else {})
        else:
            if cand.candidate_axes(p) and a != "all" and a not in cand.candidate_axes(p) and name in (
                    "gear_eccentricity", "scale_factor_asymmetry", "scale_factor_tempco"):
                continue
            built = cand.build(p, a, nl, ctx)
        out.append(Term(name, "all" if cand.shared else a, nl, built, fixed=True))
    return out


# ---- result -------------------------------------------------------------------------------------
def _result(p: Prepared, ds: Dataset, s: Search, model_path: str | None, raw: dict[str, Any] | None,
            fixed: list[Term], ow: Any, noise: list[Finding], noise_section: dict[str, Any]) -> DiagnoseResult:
    skipped, reasons = [], {}
    for cand in CANDIDATES.values():
        miss = cand.missing(p)
        if miss:
            skipped.append(cand.name)
            reasons[cand.name] = miss
    axes = {a: {"rms_baseline": math.sqrt(s.baseline.axes[a].mse), "rms_extended": math.sqrt(s.final.axes[a].mse)}
            for a in p.axes}
    findings = []
    for term, before, after in s.sequence:
        touched = term.built.axes
        params = term_params(p, term, after, len(before.terms))
        ev = dict(term.evidence)
        if term.effect == "earth_rate":
            num = sum(float(np.dot(before.axes[a].resid(), term.built.offsets[a])) for a in touched)
            den = sum(float(np.dot(term.built.offsets[a], term.built.offsets[a])) for a in touched)
            ev["fitted_scale"] = num / den if den > 0 else float("nan")
        ev.setdefault("gain_band", _band_gain(p, before, after, touched))
        if term.effect == "warmup_transient" and "tau_s_interval" not in ev:  # else set by _unbounded_warmup
            ev["tau_s_interval"] = _tau_interval(p, s.final, term)
        findings.append(Finding(term.effect, term.axis, params, before.rms(touched), after.rms(touched), ev))
    for ln in p.lines:  # coherent lines above the bins' reach, fitted on the raw samples
        findings.append(Finding("periodic", ln.axis, {"amplitude_dps": ln.amplitude_dps, "frequency_hz": ln.frequency_hz,
                                                      "phase_rad": ln.phase_rad}, ln.rms_before, ln.rms_after,
                                {"gain_heldout": ln.gain_heldout, "fitted_on": "raw samples, before binning"}))
    findings.extend(noise)
    floors = {a: white_rms(s.final.axes[a].resid()) for a in p.axes}
    from bench.analysis.diagnose.structure import analyse

    structure = {stage: {a: analyse(p, a, st.axes[a].heldout_resid(p.blocks), floors[a]) for a in p.axes}
                 for stage, st in (("baseline", s.baseline), ("extended", s.final))}
    fitted = _fitted_baseline(p, s)
    in_time = temperature_in_time(p.t, p.temp, p.power_on, {a: fitted["in_run_poly"][AXES.index(a)] for a in p.axes},
                                  floors) if has_temp_cubic(p) else {}
    return DiagnoseResult(
        source=ds.source, axes=axes, findings=findings, skipped=skipped, skipped_reasons=reasons,
        not_excited=s.not_excited, noise_floor=floors, rows=p.n, sample_rate_hz=p.fs, model_path=model_path,
        base_model=raw, fitted_baseline=fitted, rounds=s.rounds, dropped=s.dropped,
        temperature_in_time=list(in_time.values()), fixed_terms=[f"{t.effect}:{t.axis}" for t in fixed], structure=structure, unexplained=ow.unexplained,
        band_s=p.blocks.length / p.fs, noise=noise_section, _internal=(p, s))


TAU_CHI2 = 3.84
"""χ²₁ at 95 %: the warm-up τ interval is where the whole-data fit is within this of the best."""


def _tau_interval(p: Prepared, final: Any, term: Term, with_top: bool = False) -> list[float]:
    """[low, high] (s): the warm-up time constants whose whole-data fit, the other terms as found,
    lies within :data:`TAU_CHI2` of the best in units of the residual's variance times its inflation
    φ (the data's correlated noise widens it). ``high`` at the top of the grid: the data do not bound
    τ from above (such a warm-up is not named: :func:`_unbounded_warmup`). ``with_top``: [low, high,
    top of the grid]."""
    from bench.analysis.diagnose.engine import _full_sse, inflation

    cand = CANDIDATES[term.effect]
    reduced = build_state(p, [t for t in final.terms if t is not term])
    ctx = reduced.context()
    a = term.axis
    grid = sorted({g["tau_s"] for g in cand.grid(p, a, ctx)})
    taus = np.geomspace(grid[0], grid[-1], 48)
    w = {a: 1.0 / max(final.axes[a].mse, 1e-30)}
    sse = np.array([_full_sse(p, reduced, cand.build(p, a, {"tau_s": float(t)}, ctx), w) for t in taus])
    st = final.axes[a]
    phi = inflation({a: st.fit.sse_block}, {a: st.fit.sum_block}, w)
    ok = (sse - sse.min()) / phi <= TAU_CHI2
    best = float(term.nl["tau_s"])
    out = [float(min(taus[ok].min(), best)), float(max(taus[ok].max(), best))]
    return out + [float(grid[-1])] if with_top else out


def _band_gain(p: Prepared, before: Any, after: Any, axes: list[str]) -> float:
    """Relative drop of the held-out block-mean RMS from state ``before`` to ``after``."""
    from bench.analysis.diagnose.engine import band_gain

    return band_gain({a: before.axes[a].fit.sum_block for a in axes},
                     {a: after.axes[a].fit.sum_block for a in axes}, p.blocks)[0]


def term_params(p: Prepared, term: Term, after: Any, index: int) -> dict[str, Any]:
    """The physical parameters (the effect's units: deg/s, s, ...) of ``term``, fitted as column block
    ``index`` of the state ``after`` that holds it; a thermal lag's from the baseline's temperature
    coefficients it acts on."""
    touched = term.built.axes
    if term.effect == "thermal_lag":
        coef = {a: _temp_coefs(after, a) for a in touched}
    else:
        coef = {a: after.axes[a].coef(index) for a in touched}
    return CANDIDATES[term.effect].params(p, term.axis, term.nl, coef)


def _temp_coefs(state: Any, a: str) -> np.ndarray:
    """Cubic temperature coefficients of axis ``a``'s baseline in powers of (T − 25 °C)."""
    idx = next(i for i, t in enumerate(state.terms) if t.effect == "baseline" and t.axis == a)
    c = state.axes[a].coef(idx)
    return np.array([c[k] / T_REF_SCALE_C ** k for k in (1, 2, 3)]) if c.size >= 4 else np.zeros(3)


def _fitted_baseline(p: Prepared, s: Search) -> dict[str, Any]:
    """``npsat1_gyro`` keys of the fitted baseline: b_cons 0, in_run_poly [B, m1, m2, m3] in °C,
    misalignment_pct (M − I in %), arw_deg_rth from the extended model's held-out RMS."""
    poly, mis, arw = [], [], []
    for a in AXES:
        if a not in p.axes:
            poly.append([0.0, 0.0, 0.0, 0.0])
            mis.append([0.0, 0.0, 0.0])
            arw.append(0.0)
            continue
        st = s.final.axes[a]
        idx = next(i for i, t in enumerate(s.final.terms) if t.effect == "baseline" and t.axis == a)
        c = st.coef(idx)
        cu = [c[0]]
        j = 1
        if has_temp_cubic(p):
            cu += list(c[1:4])
            j = 4
        u = np.polynomial.Polynomial([-25.0 / T_REF_SCALE_C, 1.0 / T_REF_SCALE_C])
        pt = np.polynomial.Polynomial(cu)(u).coef
        coeffs = [float(v) for v in np.concatenate([pt, np.zeros(4)])[:4]]
        poly.append(coeffs)
        row = [0.0, 0.0, 0.0]
        if p.ref is not None:
            for k in range(3):
                r = p.ref[:, k]
                if np.sqrt(np.mean(r * r)) > 1e-6:
                    row[k] = float(c[j]) * 100.0
                    j += 1
        mis.append(row)
        arw.append(float(math.sqrt(st.mse) * 60.0 / math.sqrt(p.fs)))
    return {"b_cons_dps": [0.0, 0.0, 0.0], "in_run_poly_variable": "temp_c", "in_run_poly": poly,
            "misalignment_pct": mis, "arw_deg_rth": arw}


def write_report(result: DiagnoseResult, ds: Dataset, path: str | Path) -> Path:
    """Write the HTML report (residuals before/after, spectra, evidence per finding) to ``path``."""
    from bench.analysis.diagnose.blas import single_thread
    from bench.analysis.diagnose.report import write_report as _write

    with single_thread():
        return _write(result, ds, path)
