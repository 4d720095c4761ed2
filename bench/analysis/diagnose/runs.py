"""``bench diagnose A B ...``: several runs of one unit (``docs/diagnose.md``, "Several runs of one unit").

One run cannot tell a warm-up from the slow noise it is taken for (a random walk, the S5 phone's own
wander): both are slow power in time. A second run can: a warm-up repeats from each power-on, a
walk's slow wander does not. :func:`diagnose_runs` diagnoses each run as :func:`diagnose` does, then
asks per axis a **replication test tied to power-on**:

* **What is compared.** Each run's slow residual: the residual of its own selected model (the
  unwhitened fits, as :func:`bench.analysis.diagnose.noise.beyond_noise` uses; a warm-up the run named
  on its own is left in, so that the runs are judged on it together), prewhitened by the noise model
  the run itself left (:func:`bench.analysis.noise_model.fit_noise_model` on its final residual),
  against a curve in time since power-on, piecewise linear with knots at :func:`windows` (0, 30,
  60 s, then doubling, to the end of the span all runs share), each run's deterministic fit
  projected out of its columns.
* **The statistic, shape-free.** The agreement ``(RSS₀ − RSS_shared) / (RSS₀ − RSS_own)``: the part of
  the gain of one level curve per run (over those windows, each run its own constant) that a single
  curve shared by the runs takes. Under independent runs (a walk, the phone's wander) it is about
  1/R whatever the noise's size; a curve that repeats from power-on brings it towards 1.
* **Calibrated by draws.** Each run's residual replaced by a realisation of its own fitted noise model
  (:func:`bench.analysis.diagnose.noise.realisation`, fixed seeds, :data:`~bench.analysis.diagnose.noise.GOF_DRAWS`
  = 99) with the run's deterministic fit projected out as on the data: beyond when larger than in
  every draw (a 1 % test), **and** every run predicted by the others (:func:`predicted`: the curve
  fitted on the other runs gains on it): one run's large curve can pass the draws by itself.
* **Named when a vocabulary shape explains it**: ``warmup_transient`` with one τ for all runs and an
  amplitude per run (all of one sign), whose joint ΔIC on the whitened residuals is below every
  draw's, and which leaves an agreement some draw reaches. Each run is then diagnosed again with that
  warm-up as a fixed term (τ given, amplitude refitted: as a ``--model`` term), so its noise is fitted
  on what is left. Otherwise (the warm-up hidden, or not explaining it) the axis is **unexplained
  across runs** in every run's result: no noise name on it.

Only runs whose power-on is known and within :data:`POWER_ON_WITHIN_S` of their first row take part;
with fewer than two the test is not asked and ``across`` says why.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from bench.analysis.dataset import Dataset
from bench.analysis.diagnose import noise as nm
from bench.analysis.diagnose.result import DiagnoseResult, _plain
from bench.errors import InputError

POWER_ON_WITHIN_S = 60.0
"""A run takes part in the replication test when its first analysed row is at most this long after
its power-on (s): a warm-up's first minutes are in it."""
FIRST_WINDOW_S = 30.0
"""Length of the first window of time since power-on (s); the windows then double (:func:`windows`)."""
SPAN_MIN_S = 240.0
"""The runs must share at least this much time since power-on (s) for the test to be asked."""
TAU_CHI2 = 3.84
"""χ²₁ at 95 %: the shared τ's interval is where the joint warm-up fit is within this of the best,
bounded by the first τ outside it on each side of a 57-point grid over τ/4 to 4τ (so never narrower
than that grid's 5 % step)."""
RCOND = 1e-9
"""Relative singular-value cut of the least-squares fits (columns the projection left as rounding)."""
TEST = "repeats from power-on"
NOISE_NAMES = frozenset(nm.KINDS)


@dataclass
class RunsResult:
    """Result of :func:`diagnose_runs`: ``runs`` (each run's :class:`DiagnoseResult`, after a shared
    warm-up was fixed in it or an axis made unexplained across runs), ``across`` (one entry per test
    asked or not asked: see ``docs/diagnose.md``, "Several runs of one unit"), ``sources``."""

    runs: list[DiagnoseResult]
    across: list[dict[str, Any]]
    sources: list[str] = field(default_factory=list)

    @property
    def json(self) -> dict[str, Any]:
        return {"runs": [{"source": r.source, **r.json} for r in self.runs], "across_runs": _plain(self.across)}

    def across_lines(self) -> list[str]:
        """One line per across-runs entry."""
        return [across_line(e) for e in self.across]

    def summary_lines(self) -> list[str]:
        lines = []
        for k, r in enumerate(self.runs, 1):
            lines.append(f"run {k}: {r.source}")
            lines += ["  " + ln for ln in r.summary_lines()]
            if r.fixed_terms:
                lines.append("  fixed from the runs together (τ given, amplitude refitted): " + ", ".join(r.fixed_terms))
        lines.append("across runs:")
        lines += ["  " + ln for ln in self.across_lines()]
        return lines

    def extended_model(self) -> dict[str, Any]:
        """The first run's extended model (its fitted baseline or ``--model``'s keys, its findings)
        with each warm-up named across runs as one effect: the runs' mean amplitude, the shared τ."""
        doc = self.runs[0].extended_model()
        effects = [e for e in doc["effects"] if not (e["effect"] == "warmup_transient"
                                                     and any(c.get("named") == "warmup_transient" and c["axis"] == e["axis"]
                                                             for c in self.across))]
        for c in self.across:
            if c.get("named") == "warmup_transient":
                amps = c["amplitudes_dps"]
                effects.append({"effect": "warmup_transient", "axis": c["axis"],
                                "params": {"amplitude_dps": float(np.mean(amps)), "tau_s": c["tau_s"]},
                                "source": f"bench diagnose across {len(amps)} runs: amplitudes "
                                          + ", ".join(f"{v:+.3g}" for v in amps) + f" deg/s, tau {c['tau_s']:.0f} s "
                                          f"[{c['tau_s_interval'][0]:.0f}, {c['tau_s_interval'][1]:.0f}]"})
        doc["effects"] = effects
        return _plain(doc)


def across_line(e: dict[str, Any]) -> str:
    """The text of one across-runs entry."""
    if not e["asked"]:
        return f"{e.get('axis', 'all')}: {TEST}: not asked ({e['reason']})"
    head = (f"{e['axis']}: {TEST}: agreement {e['agreement']:.2f} of {e['runs']} runs over {e['span_s']:.0f} s "
            f"since power-on ({e['draws_as_large']} of {e['draws']} realisations as large, largest "
            f"{e['agreement_draws_max']:.2f})")
    if not e["beyond"]:
        if e.get("not_every_run"):
            return head + f": not a curve every run shares ({e['not_every_run']}); each run as alone"
        return head + ": within the noise models; each run as alone"
    if e.get("named"):
        amps = ", ".join(f"{v:+.3g}" for v in e["amplitudes_dps"])
        lo, hi = e["tau_s_interval"]
        return (head + f": warmup_transient across runs: amplitudes {amps} deg/s, tau {e['tau_s']:.0f} s "
                f"[{lo:.0f}, {hi:.0f}] (joint ΔIC {e['warmup_d_ic']:+.0f}, {e['warmup_draws_as_large']} of "
                f"{e['draws']} draws as large); fixed in each run and the runs diagnosed again")
    return head + f": UNEXPLAINED across runs, repeats from power-on ({e['why_unnamed']}); no noise name on {e['axis']}"


def diagnose_runs(datasets: Sequence[Dataset], model_path: str | None = None, hidden: tuple[str, ...] | frozenset[str] = (),
                  progress: Any = None, power_on_at: Sequence[float | None] | None = None) -> RunsResult:
    """Diagnose several runs of ONE unit (module docstring). ``power_on_at``: one power-on time (s on
    each run's ``time_s`` axis, or None) per dataset, as :func:`diagnose`'s; None: each run's own
    column or metadata. Raises :class:`InputError` on a ``power_on_at`` of the wrong length."""
    from bench.analysis.diagnose import _diagnose, hidden_names
    from bench.analysis.diagnose.blas import single_thread

    datasets = list(datasets)
    if not datasets:
        raise InputError("diagnose: no data to diagnose")
    pons = list(power_on_at) if power_on_at is not None else [None] * len(datasets)
    if len(pons) != len(datasets):
        raise InputError(f"--power-on-at: {len(pons)} value(s) for {len(datasets)} data files; give one per file, in order",
                         None, "--power-on-at")
    hid = hidden_names(hidden)
    with single_thread():
        runs = []
        for k, (ds, pon) in enumerate(zip(datasets, pons), 1):
            if progress is not None and len(datasets) > 1:
                progress(f"run {k} of {len(datasets)}: {ds.source}")
            runs.append(_diagnose(ds, model_path, hid, progress, pon))
        if len(runs) < 2:
            return RunsResult(runs, [{"test": TEST, "asked": False, "reason": "one run: a second run of the unit is needed"}],
                              [r.source for r in runs])
        taking, across = _taking(runs)
        if len(taking) < 2:
            across.append({"test": TEST, "asked": False,
                           "reason": f"{len(taking)} run(s) with a known power-on within {POWER_ON_WITHIN_S:g} s of "
                                     "their first row; at least two are needed"})
            return RunsResult(runs, across, [r.source for r in runs])
        axes = [a for a in runs[taking[0]].axes if all(a in runs[i].axes for i in taking)]
        fixed: list[tuple[str, str, dict[str, Any]]] = []
        unexplained: list[dict[str, Any]] = []
        for a in axes:
            if progress is not None:
                progress(f"{a}: asking whether the runs' slow residuals repeat from power-on")
            e = replication(runs, taking, a, hid)
            across.append(e)
            if e["asked"] and e["beyond"]:
                if e.get("named"):
                    fixed.append(("warmup_transient", a, {"tau_s": e["tau_s"]}))
                else:
                    unexplained.append(e)
        if fixed:
            for i in taking:
                if progress is not None:
                    progress(f"run {i + 1}: diagnosing again with the shared warm-up fixed")
                runs[i] = _diagnose(datasets[i], model_path, hid, progress, pons[i], known=tuple(fixed))
        for e in unexplained:
            for pos, i in enumerate(taking):
                _mark_unexplained(runs[i], e, e["curve_rms_dps"][pos])
    return RunsResult(runs, across, [r.source for r in runs])


def _taking(runs: list[DiagnoseResult]) -> tuple[list[int], list[dict[str, Any]]]:
    """Indices of the runs that take part (power-on known, first row within :data:`POWER_ON_WITHIN_S`
    of it, no second power-on inside) and an entry per run left out, saying why."""
    taking, out = [], []
    for i, r in enumerate(runs):
        p = r._internal[0]
        why = None
        if p.power_on is None:
            why = "its power-on is not known (power_on_s, --power-on-at or # power_on_at_s)"
        elif float(p.power_on[0]) > POWER_ON_WITHIN_S:
            why = f"its first row is {float(p.power_on[0]):.0f} s after power-on (more than {POWER_ON_WITHIN_S:g} s)"
        elif np.any(np.diff(p.power_on) < 0):
            why = "it holds a second power-on"
        if why is None:
            taking.append(i)
        else:
            out.append({"test": TEST, "run": i + 1, "source": r.source, "asked": False, "reason": f"run {i + 1} left out: {why}"})
    return taking, out


@dataclass
class _Run:
    """One run's axis as the replication test sees it: time since power-on (s), the residual (deg/s),
    the projector of its deterministic fit (orthonormal columns U: the residual is x − U Uᵀx), its noise
    model and that model's whitener."""

    t_on: np.ndarray
    t: np.ndarray
    resid: np.ndarray
    U: np.ndarray
    model: Any
    whitener: Any
    bin_rows: int = 1

    def refitted(self, noise: np.ndarray) -> "_Run":
        """This run with its noise model fitted anew on ``noise`` (deg/s; e.g. the residual less a warm-up)."""
        from bench.analysis.noise_model import fit_noise_model

        m = fit_noise_model(noise, float(np.median(np.diff(self.t))), self.bin_rows)
        return _Run(self.t_on, self.t, self.resid, self.U, m, None if m.is_white else m.whitener(), self.bin_rows)

    def white(self, x: np.ndarray) -> np.ndarray:
        """``x`` prewhitened by the run's noise model (as it is: a white model has no whitener)."""
        return x if self.whitener is None else self.whitener.apply(x, self.t)

    def project(self, x: np.ndarray) -> np.ndarray:
        return x - self.U @ (self.U.T @ x)


def _run_axis(r: DiagnoseResult, a: str) -> _Run:
    """The slow residual of run ``r`` on axis ``a`` (module docstring) and what the draws need."""
    from bench.analysis.diagnose import UNBOUNDED, _fixed_terms
    from bench.analysis.diagnose.engine import axis_state
    from bench.analysis.noise_model import fit_noise_model

    p, s = r._internal
    saved = p.whiten
    p.whiten = {}
    try:
        every = nm.noise_terms(p, list(s.final.terms), r.unexplained)
        st = axis_state(p, a, [t for t in every if t.effect != "warmup_transient"])
        own = any(t.effect == "warmup_transient" and t.axis == a for t in every)
        # a warm-up the run found but left unnamed (its τ not bounded by one run): its noise as if named
        gone = [] if own else [t for d in r.dropped
                               if d["effect"] == "warmup_transient" and d["axis"] == a and d["reason"].startswith(UNBOUNDED)
                               for t in _fixed_terms(p, "warmup_transient", a, d["nl"], s.final.context())]
        noise = axis_state(p, a, every + gone[-1:]).resid() if own or gone else None  # the noise as the run left it
    finally:
        p.whiten = saved
    U, sv, _ = np.linalg.svd(st.X, full_matrices=False)
    U = U[:, sv > sv[0] * 1e-10]
    resid = st.y - U @ (U.T @ st.y)
    m = fit_noise_model(resid if noise is None else noise, 1.0 / p.fs, p.bin_rows)
    return _Run(np.asarray(p.power_on, float), p.t, resid, U, m, None if m.is_white else m.whitener(), p.bin_rows)


def windows(starts: list[float], ends: list[float]) -> np.ndarray:
    """Edges (s since power-on) of the windows the runs share: from the latest first row to the
    earliest last row, cut at :data:`FIRST_WINDOW_S` and its doublings."""
    lo, hi = max(starts), min(ends)
    cuts = [FIRST_WINDOW_S * 2 ** k for k in range(40) if lo < FIRST_WINDOW_S * 2 ** k < hi]
    return np.array([lo] + cuts + [hi])


def _design(run: _Run, edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(constant column, curve columns) of one run, its deterministic fit projected out, prewhitened.
    The curve: piecewise linear in time since power-on with knots at ``edges`` (hat functions; flat
    after the last knot, so rows past the shared span follow its end)."""
    x = np.clip(run.t_on, edges[0], edges[-1])
    Z = np.empty((x.size, edges.size))
    for j in range(edges.size):
        unit = np.zeros(edges.size)
        unit[j] = 1.0
        Z[:, j] = np.interp(x, edges, unit)
    return run.white(_kept(run, np.ones((x.size, 1)))), run.white(_kept(run, Z))


def _kept(run: _Run, Z: np.ndarray) -> np.ndarray:
    """``Z``'s columns with the run's deterministic fit projected out; a column that fit takes (all but
    rounding, e.g. the constant its bias already has) is zeroed so that it fits nothing."""
    P = run.project(Z)
    keep = np.linalg.norm(P, axis=0) > 1e-6 * np.maximum(np.linalg.norm(Z, axis=0), 1e-300)
    return P * keep


def _curve_rms(run: _Run, edges: np.ndarray) -> float:
    """RMS (deg/s) over the shared windows of a run's own unwhitened window levels about their mean:
    the size of its slow residual on the test's windows."""
    k = np.searchsorted(edges, run.t_on, side="right") - 1
    inside = (k >= 0) & (k < edges.size - 1) & (run.t_on <= edges[-1])
    lev = np.array([run.resid[inside & (k == j)].mean() for j in range(edges.size - 1)])
    w = np.bincount(k[inside], minlength=edges.size - 1)[:edges.size - 1].astype(float)
    c = lev - np.average(lev, weights=w)
    return float(math.sqrt(np.average(c * c, weights=w)))


def _rss(X: np.ndarray, y: np.ndarray) -> float:
    beta = np.linalg.lstsq(X, y, rcond=RCOND)[0]
    r = y - X @ beta
    return float(r @ r)


def agreement(ys: list[np.ndarray], designs: list[tuple[np.ndarray, np.ndarray]]) -> tuple[float, float]:
    """(agreement, ΔIC of the shared curve against none) of whitened residuals ``ys`` (module
    docstring); agreement NaN when the runs' own curves gain nothing."""
    rss0 = sum(_rss(c, y) for y, (c, _) in zip(ys, designs))
    own = sum(_rss(np.column_stack([c, Z]), y) for y, (c, Z) in zip(ys, designs))
    K = designs[0][1].shape[1]
    n = sum(y.size for y in ys)
    shared = _shared_fit(ys, designs)[0]
    gain = rss0 - own
    d_ic = n * math.log(max(shared, 1e-300) / max(rss0, 1e-300)) + 2.0 * K
    return (float((rss0 - shared) / gain) if gain > 0 else math.nan), float(d_ic)


def predicted(ys: list[np.ndarray], designs: list[tuple[np.ndarray, np.ndarray]]) -> list[float]:
    """Per run, the fraction of its own curve's gain over a constant that the curve fitted on the
    *other* runs (one shared by them) gains on it, its constant refitted (whitened residuals ``ys``;
    NaN where its own curve gains nothing). About 1 where a curve repeats from power-on; 0 or below
    on a run the others' curve does not describe."""
    out = []
    for j, (yj, (cj, Zj)) in enumerate(zip(ys, designs)):
        rss0 = _rss(cj, yj)
        own = rss0 - _rss(np.column_stack([cj, Zj]), yj)
        others = [i for i in range(len(ys)) if i != j]
        beta = _shared_fit([ys[i] for i in others], [designs[i] for i in others])[1]
        out.append(float((rss0 - _rss(cj, yj - Zj @ beta)) / own) if own > 0 else math.nan)
    return out


def _shared_fit(ys: list[np.ndarray], designs: list[tuple[np.ndarray, np.ndarray]]) -> tuple[float, np.ndarray]:
    """(RSS, curve coefficients) of one curve shared by the runs ``ys``, each its own constant."""
    n = sum(y.size for y in ys)
    C = np.zeros((n, len(ys)))
    at = 0
    for i, y in enumerate(ys):
        C[at:at + y.size, i] = designs[i][0][:, 0]
        at += y.size
    X = np.column_stack([C, np.vstack([Z for _, Z in designs])])
    y = np.concatenate(ys)
    beta = np.linalg.lstsq(X, y, rcond=RCOND)[0]
    r = y - X @ beta
    return float(r @ r), beta[len(ys):]


def _warm_cols(runs: list[_Run], tau: float) -> list[np.ndarray]:
    """Each run's warm-up column of time constant ``tau`` (s), its deterministic fit projected out,
    prewhitened."""
    return [r.white(r.project(np.exp(-np.clip(r.t_on, 0.0, None) / tau))) for r in runs]


class JointWarmup:
    """One warm-up shape of shared τ with an amplitude (and constant) per run, on whitened residuals:
    the columns of each τ of a grid built once (they do not change from draw to draw)."""

    def __init__(self, runs: list[_Run], designs: list[tuple[np.ndarray, np.ndarray]], taus: np.ndarray):
        self.taus = taus
        self.ones = [c for c, _ in designs]  # (n, 1) each
        self.cols = [_warm_cols(runs, float(t)) for t in taus]

    def d_ic(self, ys: list[np.ndarray]) -> tuple[np.ndarray, list[np.ndarray]]:
        """ΔIC per τ against a constant per run, and per τ the amplitudes (deg/s)."""
        n = sum(y.size for y in ys)
        rss0 = sum(_rss(c, y) for y, c in zip(ys, self.ones))
        out, amps = [], []
        for cols in self.cols:
            rss, a = 0.0, []
            for y, c, e in zip(ys, self.ones, cols):
                X = np.column_stack([c, e])
                beta = np.linalg.lstsq(X, y, rcond=RCOND)[0]
                r = y - X @ beta
                rss += float(r @ r)
                a.append(float(beta[1]))
            out.append(n * math.log(max(rss, 1e-300) / max(rss0, 1e-300)) + 2.0 * (len(ys) + 1))
            amps.append(np.array(a))
        return np.array(out), amps


def tau_grid(span_s: float, fs: float, n: int = 16) -> np.ndarray:
    """The shared τ grid (s): the warm-up candidate's own range over the shared span."""
    lo = max(10.0, 3.0 / fs)
    hi = min(3600.0, span_s / 3.0)
    return np.geomspace(lo, max(hi, 2 * lo), n)


def replication(runs: list[DiagnoseResult], taking: list[int], a: str, hidden: frozenset[str]) -> dict[str, Any]:
    """The replication test on axis ``a`` of the runs ``taking`` (module docstring): an across-runs
    entry (``docs/diagnose.md``, "Several runs of one unit")."""
    rs = [_run_axis(runs[i], a) for i in taking]
    edges = windows([float(r.t_on[0]) for r in rs], [float(r.t_on[-1]) for r in rs])
    entry: dict[str, Any] = {"test": TEST, "axis": a, "runs": len(rs), "run_numbers": [i + 1 for i in taking]}
    span = float(edges[-1] - edges[0])
    if span < SPAN_MIN_S:
        return {**entry, "asked": False, "reason": f"the runs share {span:.0f} s since power-on (fewer than {SPAN_MIN_S:g} s)"}
    designs = [_design(r, edges) for r in rs]
    entry["curve_rms_dps"] = [_curve_rms(r, edges) for r in rs]
    ys = [r.white(r.resid) for r in rs]
    obs, obs_dic = agreement(ys, designs)
    draws = _draws(rs, designs, a)[0]
    d = np.array([v for v in draws if math.isfinite(v)])
    as_large = int(np.sum(d >= obs)) if math.isfinite(obs) else nm.GOF_DRAWS
    entry.update({"asked": True, "windows_s": [float(v) for v in edges], "span_s": span, "agreement": obs,
                  "agreement_expected_independent": 1.0 / len(rs), "agreement_draws_max": float(d.max()) if d.size else math.nan,
                  "shared_curve_d_ic": obs_dic, "draws": nm.GOF_DRAWS, "draws_as_large": as_large,
                  "noise_models": [r.model.describe() for r in rs], "beyond": bool(math.isfinite(obs) and as_large == 0)})
    if not entry["beyond"]:
        return entry
    # a curve that repeats describes every run: the other runs' curve must predict each one (a single
    # run's large curve can take the in-sample agreement beyond every draw by itself, S5 bump seed 1)
    entry["predicted_by_others"] = predicted(ys, designs)
    if not all(v > 0 for v in entry["predicted_by_others"]):
        entry["beyond"] = False
        entry["not_every_run"] = ("run(s) " + ", ".join(str(k) for k, v in zip(entry["run_numbers"], entry["predicted_by_others"])
                                                        if not v > 0) + " not predicted by the other runs' curve")
        return entry
    if "warmup_transient" in hidden:
        return {**entry, "why_unnamed": "warmup_transient is hidden"}
    entry.update(_shared_warmup(rs, designs, ys, edges, a, tau_grid(span, 1.0 / float(np.median(np.diff(rs[0].t))))))
    if entry["warmup_draws_as_large"] == 0 and entry["one_sign"] and entry["explains"]:
        entry["named"] = "warmup_transient"
        return entry
    why = (f"the joint warm-up is matched by {entry['warmup_draws_as_large']} of {nm.GOF_DRAWS} draws"
           if entry["warmup_draws_as_large"] else
           "the runs' warm-up amplitudes differ in sign" if not entry["one_sign"] else
           f"a shared warm-up leaves agreement {entry['agreement_after_warmup']:.2f}, beyond every draw")
    return {**entry, "why_unnamed": why}


def _draws(rs: list[_Run], designs: list[tuple[np.ndarray, np.ndarray]], a: str,
           jw: "JointWarmup | None" = None) -> tuple[list[float], list[float]]:
    """On :data:`~bench.analysis.diagnose.noise.GOF_DRAWS` fixed-seed draws (each run's residual replaced
    by a realisation of its noise model, its deterministic fit projected out): the agreement, and
    with ``jw`` the joint warm-up's best ΔIC."""
    rngs = [np.random.default_rng([nm.GOF_SEED, "xyz".index(a), k]) for k in range(len(rs))]
    agree, warm = [], []
    for _ in range(nm.GOF_DRAWS):
        yd = [r.white(r.project(nm.realisation(r.model, r.resid.size, g))) for r, g in zip(rs, rngs)]
        agree.append(agreement(yd, designs)[0])
        if jw is not None:
            warm.append(float(jw.d_ic(yd)[0].min()))
    return agree, warm


def _shared_warmup(rs: list[_Run], designs: list[tuple[np.ndarray, np.ndarray]], ys: list[np.ndarray],
                   edges: np.ndarray, a: str, taus: np.ndarray) -> dict[str, Any]:
    """The warm-up of one τ shared by the runs (an amplitude each) and how it is judged: fitted on the
    residuals whitened by the runs' models; then each run's noise model fitted anew on its residual
    less that warm-up (the slow power the warm-up had lent it), and against those models the joint
    ΔIC compared with the draws' (``warmup_draws_as_large``), the τ interval (χ² profile), and the
    agreement left once the warm-up is taken out (``explains``: some draw reaches it). ``designs``,
    ``ys``: the runs' designs and whitened residuals as :func:`replication` made them."""
    k = int(np.argmin(JointWarmup(rs, designs, taus).d_ic(ys)[0]))
    fine = np.geomspace(taus[max(k - 1, 0)], taus[min(k + 1, taus.size - 1)], 17)
    f_ic, f_amps = JointWarmup(rs, designs, fine).d_ic(ys)
    tau0, amps0 = float(fine[int(np.argmin(f_ic))]), f_amps[int(np.argmin(f_ic))]
    rs = [r.refitted(r.resid - A * r.project(np.exp(-np.clip(r.t_on, 0.0, None) / tau0))) for r, A in zip(rs, amps0)]
    designs = [_design(r, edges) for r in rs]
    ys = [r.white(r.resid) for r in rs]
    f_ic, f_amps = JointWarmup(rs, designs, fine).d_ic(ys)
    j = int(np.argmin(f_ic))
    tau, amps, best = float(fine[j]), [float(v) for v in f_amps[j]], float(f_ic[j])
    wide = np.geomspace(max(tau / 4.0, taus[0]), min(tau * 4.0, taus[-1]), 57)
    prof = JointWarmup(rs, designs, wide).d_ic(ys)[0]
    out = (prof - best) > TAU_CHI2  # the interval: bounded by the first grid τ excluded on each side
    below, above = wide[(wide < tau) & out], wide[(wide > tau) & out]
    ok = np.array([below.max() if below.size else wide[0], above.min() if above.size else wide[-1]])
    agree, warm = _draws(rs, designs, a, JointWarmup(rs, designs, taus))
    left = [y - A * e for y, A, e in zip(ys, amps, _warm_cols(rs, tau))]
    left_agree = agreement(left, designs)[0]
    finite = [v for v in agree if math.isfinite(v)]
    return {"warmup_d_ic": best, "warmup_draws_as_large": int(np.sum(np.array(warm) <= best)),
            "warmup_d_ic_draws_min": float(min(warm)), "tau_s": tau, "tau_s_interval": [float(ok.min()), float(ok.max())],
            "amplitudes_dps": amps, "agreement_after_warmup": left_agree,
            "noise_models_without_warmup": [r.model.describe() for r in rs],
            "one_sign": bool(all(v > 0 for v in amps) or all(v < 0 for v in amps)),
            "explains": bool(not math.isfinite(left_agree) or any(v >= left_agree for v in finite))}


def _mark_unexplained(r: DiagnoseResult, e: dict[str, Any], rms: float) -> None:
    """Axis ``e["axis"]`` of run ``r`` unexplained across runs: its slow noise names dropped (the
    noise section says so), an ``unexplained`` entry that lives against time since power-on."""
    a = e["axis"]
    drop = [f for f in r.findings if f.axis == a and f.effect in NOISE_NAMES]
    r.findings[:] = [f for f in r.findings if f not in drop]
    sec = r.noise.get(a)
    if sec is not None:
        sec["named"] = [n for n in (sec.get("named") or []) if n not in NOISE_NAMES]
        sec["across_runs"] = f"{TEST} in {e['runs']} runs: no noise name"
    where = {"against": f"time since power-on, repeated in {e['runs']} runs", "probe": "runs",
             "rms_dps": rms, "band_rms_dps": rms, "d_ic": e["shared_curve_d_ic"], "agreement": e["agreement"],
             "draws_as_large": e["draws_as_large"], "draws": e["draws"]}
    r.unexplained.append({"axis": a, "rms_dps": rms, "band_rms_dps": rms, "band_s": r.band_s,
                          "residual_rms_dps": float(math.sqrt(r._internal[1].final.axes[a].mse)),
                          "where": [where], "across_runs": True, "dropped_names": [f.effect for f in drop]})
