"""The discrepancy engine: baseline fit, candidate fits, blocked-CV selection with an information
criterion, backward elimination, final held-out figures.

Selection rule (``docs/diagnose.md``): a candidate term is *acceptable* when, against the current
model, on held-out data (nested blocked CV: nonlinear parameters chosen on each fold's training
rows only),

* the cross-validated information criterion, computed with the effective number of independent
  rows, improves: ΔIC = Σ_axes (n/φ)·ln(MSE_new/MSE_old) + Δk·ln(N/φ) < −:data:`IC_MIN`. Δk =
  added linear + nonlinear parameters (for the penalised random walk, whose flexibility is set by
  held-out error, its one hyperparameter), N = rows × axes involved, φ ≥ 1 the variance
  inflation of the candidate model's held-out residual summed over blocks (1 for white noise;
  large when the candidate leaves correlated structure, so a term that only partly explains a
  structure earns little evidence);
* it is material: the held-out RMS drops by at least :data:`GAIN_MIN` (relative), per sample or
  on the band where slow effects live (the RMS of the held-out residual's block means, blocks of
  ``Blocks.length`` rows): an effect far below one sample's noise but far above the noise of long
  averages is judged on those averages.

The t statistic of the per-block improvements is reported as evidence but not required: effects
confined to a part of the session (warm-up, rate ramps) improve few blocks.

Forward: add the acceptable candidate with the most negative ΔIC (``rate_random_walk`` last:
only when no named cause is acceptable), then re-fit every found term's nonlinear parameters given
the others (:func:`polish`); repeat until none is acceptable. Backward: drop any term that is no
longer acceptable given all the others (nonlinear parameters held), re-fit, repeat until stable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
from scipy.optimize import minimize_scalar

from bench.analysis.progress import each
from bench.analysis.diagnose.cv import CVFit, SparseHat, augment, block_sums, cv_fit, fold_grams
from bench.analysis.diagnose.data import Blocks, Prepared
from bench.analysis.diagnose.terms import AXES, CANDIDATES, Built, Candidate, Context, lagged_temp

IC_MIN = 10.0
"""Required drop of the cross-validated information criterion (log-likelihood units; 10 is
"very strong" evidence on the Kass-Raftery scale)."""
GAIN_MIN = 0.01
"""Required relative drop of the held-out RMS (1 %), per sample or on the block-mean band: below it
the model already explains the data (reported gains are never below it)."""
BAND_T = 3.0
"""A gain on the block-mean band counts only when the blocks agree on it: the paired t statistic of
the per-block drop of the squared block mean is at least this (120 blocks of white noise move the
band RMS by ±6 % by chance)."""


def material(d_ic: float, gain: float, gain_band: float, band_t: float = 0.0) -> bool:
    """The acceptance rule: enough evidence (ΔIC < −IC_MIN) and a material gain: the held-out RMS
    drops by at least GAIN_MIN per sample or, consistently over the blocks (t ≥ :data:`BAND_T`), on
    the block-mean band (module docstring)."""
    return d_ic < -IC_MIN and (gain >= GAIN_MIN or (gain_band >= GAIN_MIN and band_t >= BAND_T))


def block_means(sums: np.ndarray, blocks: Blocks) -> np.ndarray:
    """Block means (deg/s) from per-block sums."""
    lengths = np.minimum(blocks.length, blocks.n - np.arange(blocks.count) * blocks.length).astype(float)
    return sums / lengths


def band_rms(sums: dict[str, np.ndarray], blocks: Blocks) -> float:
    """RMS (deg/s) of the held-out residual's block means over the axes given (sums per block)."""
    tot = sum(float(np.sum(block_means(s, blocks) ** 2)) for s in sums.values())
    return math.sqrt(tot / max(len(sums) * blocks.count, 1))


def band_gain(old: dict[str, np.ndarray], new: dict[str, np.ndarray], blocks: Blocks) -> tuple[float, float, float, float]:
    """(relative drop of the block-mean RMS, RMS before, RMS after, paired t statistic of the per-block
    drop of the squared block mean) from per-block held-out sums."""
    before, after = band_rms(old, blocks), band_rms(new, blocks)
    if before <= 0:
        return 0.0, before, after, 0.0
    d = np.concatenate([block_means(old[a], blocks) ** 2 - block_means(new[a], blocks) ** 2 for a in old])
    sd = float(np.std(d, ddof=1)) if d.size > 1 else 0.0
    t = float(np.mean(d)) / (sd / math.sqrt(d.size)) if sd > 0 else 0.0
    return 1.0 - after / before, before, after, t


MAX_TERMS = 8
"""Most terms added by the forward search."""
T_REF_SCALE_C = 30.0
"""Temperature scale (°C) of the baseline cubic's variable u = (T − 25)/30 (conditioning only)."""


@dataclass
class Term:
    """A model term: the baseline of an axis, a term from the model file (``fixed``) or a finding."""

    effect: str
    axis: str
    nl: dict[str, Any]
    built: Built
    fixed: bool = False
    evidence: dict[str, Any] = field(default_factory=dict)

    @property
    def key(self) -> tuple[str, str]:
        return (self.effect, self.axis)


@dataclass
class AxisState:
    X: np.ndarray
    scale: np.ndarray
    P: np.ndarray | None
    y: np.ndarray
    A: np.ndarray
    spans: list[tuple[int, int, int]]
    fit: CVFit
    S: np.ndarray | None = None
    """(B, m+1) block sums of [X | y] (the held-out residual's block sums; prewhitened designs)."""
    _blocked: tuple[np.ndarray, np.ndarray] | None = None
    _resid: np.ndarray | None = None

    def blocked(self, blocks: Blocks) -> tuple[np.ndarray, np.ndarray]:
        """X and y in block layout (B, L, m), (B, L, 1), computed once."""
        if self._blocked is None:
            self._blocked = (blocks.shaped(self.X), blocks.shaped(self.y))
        return self._blocked

    @property
    def n(self) -> int:
        return int(self.y.shape[0])

    @property
    def mse(self) -> float:
        return self.fit.sse / self.n

    def resid(self) -> np.ndarray:
        """Full-data residual (deg/s), computed once."""
        if self._resid is None:
            self._resid = self.y - self.X @ self.fit.beta
        return self._resid

    def heldout_resid(self, blocks: Blocks) -> np.ndarray:
        """Each row's residual from the fold fit that did not see it (deg/s)."""
        fold = blocks.row_fold()
        pred = np.empty(self.n)
        for k in range(blocks.folds):
            sel = fold == k
            pred[sel] = self.X[sel] @ self.fit.beta_folds[k]
        return self.y - pred

    def coef(self, term_index: int) -> np.ndarray:
        """Raw (physical) coefficients of a term's columns."""
        for i, a, b in self.spans:
            if i == term_index:
                return self.fit.beta[a:b] / self.scale[a:b]
        return np.zeros(0)


@dataclass
class State:
    terms: list[Term]
    axes: dict[str, AxisState]

    def context(self) -> Context:
        return Context(resid={a: s.resid() for a, s in self.axes.items()},
                       sigma2={a: max(s.mse, 1e-30) for a, s in self.axes.items()})

    def rms(self, axes: list[str]) -> float:
        return math.sqrt(sum(self.axes[a].fit.sse for a in axes) / sum(self.axes[a].n for a in axes))


def _col_scale(Z: np.ndarray | SparseHat) -> np.ndarray:
    s = Z.col_rms() if isinstance(Z, SparseHat) else np.sqrt(np.mean(Z * Z, axis=0))
    return np.where(s > 0, s, 1.0)


def _scaled(Z: np.ndarray | SparseHat, s: np.ndarray) -> np.ndarray | SparseHat:
    return Z.scaled(s) if isinstance(Z, SparseHat) else Z / s


def _dense(Z: np.ndarray | SparseHat) -> np.ndarray:
    return Z.dense() if isinstance(Z, SparseHat) else Z


def _blockdiag(P: np.ndarray | None, m: int, Pz: np.ndarray | None, q: int) -> np.ndarray | None:
    if P is None and Pz is None:
        return None
    out = np.zeros((m + q, m + q))
    if P is not None:
        out[:m, :m] = P
    if Pz is not None:
        out[m:, m:] = Pz
    return out


def has_temp_cubic(p: Prepared) -> bool:
    return p.temp is not None and float(np.ptp(p.temp)) > 0.5


def baseline_built(p: Prepared, axis: str, tau_s: float | None = None) -> Built:
    """Constant (always the first column), cubic in (T − 25)/30 °C (T lagged by ``tau_s`` when a
    thermal lag is in the model), and the reference rates (scale factor/misalignment)."""
    cols = [np.ones(p.n)]
    if has_temp_cubic(p):
        u = (lagged_temp(p, tau_s) - 25.0) / T_REF_SCALE_C
        cols += [u, u * u, u ** 3]
    if p.ref is not None:
        for k in range(3):
            r = p.ref[:, k]
            if np.sqrt(np.mean(r * r)) > 1e-6:
                cols.append(r)
    return Built(cols={axis: np.column_stack(cols)})


def response(p: Prepared, axis: str) -> np.ndarray:
    """gyro − reference rate (deg/s): what the error model has to explain (prewhitened by the axis'
    noise model when it has one, :meth:`Prepared.w`)."""
    return p.w(axis, p.gyro[axis] - p.ref_axis(axis))


def axis_state(p: Prepared, a: str, terms: list[Term]) -> AxisState:
    """Fit ``terms`` on axis ``a`` from scratch."""
    tau = None
    for t in terms:
        if a in t.built.relag:
            tau = t.built.relag[a]
    cols, pens, spans = [], [], []
    y = response(p, a)
    m = 0
    for i, t in enumerate(terms):
        built = t.built
        if t.effect == "baseline" and t.axis == a and tau:
            built = baseline_built(p, a, tau)
        if a in built.offsets:
            y = y - p.w(a, built.offsets[a])
        if a in built.cols:
            z = p.w(a, _dense(built.cols[a]))
            cols.append(z)
            pens.append((m, built.penalty.get(a)))
            spans.append((i, m, m + z.shape[1]))
            m += z.shape[1]
    X = np.column_stack(cols)
    scale = _col_scale(X)
    X = X / scale
    P = None
    if any(pz is not None for _, pz in pens):
        P = np.zeros((m, m))
        for start, pz in pens:
            if pz is not None:
                q = pz.shape[0]
                sc = scale[start:start + q]
                P[start:start + q, start:start + q] = pz / np.outer(sc, sc)
    Xy = np.column_stack([X, y])
    A = p.blocks.gram(Xy)
    S = block_sums(p.blocks, Xy) if p.whiten else None
    return AxisState(X, scale, P, y, A, spans, cv_fit(A, P, p.blocks, S=S, gls=bool(p.whiten)), S)


def _sums_with(p: Prepared, st: AxisState, Zs: Any, y_new: np.ndarray | None) -> np.ndarray | None:
    """Block sums of [X | Z | y_new] from those of [X | y] (None without prewhitening: row 0 of the
    Grams holds them)."""
    if st.S is None:
        return None
    m = st.X.shape[1]
    parts = [st.S[:, :m]]
    if Zs is not None:
        parts.append(block_sums(p.blocks, _dense(Zs)))
    parts.append(st.S[:, m:] if y_new is None else block_sums(p.blocks, y_new))
    return np.concatenate(parts, axis=1)


def build_state(p: Prepared, terms: list[Term]) -> State:
    """Fit ``terms`` from scratch on every axis."""
    return State(list(terms), {a: axis_state(p, a, terms) for a in p.axes})


def add_term(p: Prepared, state: State, term: Term) -> State:
    """``state`` with ``term`` appended (only the axes it touches are refitted)."""
    idx = len(state.terms)
    terms = state.terms + [term]
    axes = dict(state.axes)
    for a in term.built.axes:
        if a in term.built.relag:
            axes[a] = axis_state(p, a, terms)
            continue
        st = state.axes[a]
        Z = p.w(a, term.built.cols.get(a))
        o = p.w(a, term.built.offsets.get(a))
        y_new = st.y - o if o is not None else st.y
        m = st.X.shape[1]
        if Z is not None:
            s = _col_scale(Z)
            Zs = _dense(_scaled(Z, s))
            pz = term.built.penalty.get(a)
            Pz = None if pz is None else pz / np.outer(s, s)
            X = np.column_stack([st.X, Zs])
            scale = np.concatenate([st.scale, s])
            P = _blockdiag(st.P, m, Pz, Z.shape[1])
            spans = st.spans + [(idx, m, m + Z.shape[1])]
        else:
            Zs, X, scale, P, spans = None, st.X, st.scale, st.P, list(st.spans)
        Xb, yb = st.blocked(p.blocks)
        A = augment(st.A, Xb, yb, p.blocks, Zs, None if o is None else y_new)
        S = _sums_with(p, st, Zs, None if o is None else y_new)
        axes[a] = AxisState(X, scale, P, y_new, A, spans, cv_fit(A, P, p.blocks, S=S, gls=bool(p.whiten)), S)
    return State(terms, axes)


# ---- candidate evaluation -----------------------------------------------------------------------
@dataclass
class Evaluation:
    """A candidate against the current model: held-out errors, criterion, chosen parameters."""

    cand: Candidate
    axis: str
    axes: list[str]
    hold: dict[str, np.ndarray]
    nl_full: dict[str, Any]
    d_ic: float
    t: float
    gain: float
    rms_before: float
    rms_after: float
    df: float
    phi: float = 1.0
    d_ic_raw: float = 0.0
    """ΔIC with φ = 1 (all rows independent)."""
    resolved: bool = True
    """False when a parameter that must be resolved sits at the top of its grid."""
    gain_band: float = 0.0
    """Relative drop of the RMS of held-out block means (the slow band)."""
    band_before: float = 0.0
    band_after: float = 0.0
    band_t: float = 0.0
    d_ic_full: float = -math.inf
    """ΔIC of the whole-data fits (same φ and Δk): a held-out gain the whole-data fit does not show
    is a fold's poorly learnt baseline repaired, not structure explained (:func:`evaluate`)."""

    @property
    def acceptable(self) -> bool:
        return self.resolved and self.d_ic_full < -IC_MIN and material(self.d_ic, self.gain, self.gain_band, self.band_t)

    @property
    def acceptable_raw(self) -> bool:
        return self.resolved and self.d_ic_full < -IC_MIN and material(self.d_ic_raw, self.gain, self.gain_band, self.band_t)

    def row(self) -> dict[str, Any]:
        return {"effect": self.cand.name, "axis": self.axis, "d_ic": self.d_ic, "t": self.t,
                "gain": 1.0 / (1.0 - self.gain) if self.gain < 1 else float("inf"),
                "gain_band": 1.0 / (1.0 - self.gain_band) if self.gain_band < 1 else float("inf"), "band_t": self.band_t, "rms_before": self.rms_before, "rms_after": self.rms_after,
                "band_before": self.band_before, "band_after": self.band_after, "df": self.df, "phi": self.phi,
                "d_ic_raw": self.d_ic_raw, "d_ic_full": self.d_ic_full, "resolved": self.resolved,
                "acceptable": self.acceptable,
                "nl": dict(self.nl_full)}



def _candidate_columns(p: Prepared, built, a: str):
    """The candidate's columns ``Z`` and offset ``o`` on axis ``a`` (prewhitened when the axis has a
    noise model), with ``Z`` column-scaled (``Zs``) and its penalty scaled to match (``Pz``); None
    where absent."""
    Z = p.w(a, built.cols.get(a))
    o = p.w(a, built.offsets.get(a))
    Zs, Pz = None, None
    if Z is not None:
        s = _col_scale(Z)
        Zs = _scaled(Z, s)
        pz = built.penalty.get(a)
        Pz = None if pz is None else pz / np.outer(s, s)
    return Z, o, Zs, Pz

def _fit_candidate(p: Prepared, state: State, built: Built, cache: dict | None = None) -> dict[str, CVFit]:
    """Blocked CV of ``state`` + ``built`` on the axes ``built`` touches. ``cache`` reuses the
    augmented Grams when a grid only changes the penalty (same column array)."""
    fits = {}
    for a in built.axes:
        if a in built.relag:
            fits[a] = axis_state(p, a, state.terms + [Term("thermal_lag", a, {}, built)]).fit
            continue
        st = state.axes[a]
        raw_z, raw_o = built.cols.get(a), built.offsets.get(a)
        key = (a, id(raw_z), id(raw_o))
        folded = None
        if cache is not None and key in cache and cache[key][0] is raw_z and cache[key][1] is raw_o:
            _, _, A, S, Z, Pz, folded = cache[key]
            pz = built.penalty.get(a)
            if pz is not None:  # same columns, another penalty (a grid of smoothness)
                sc = _col_scale(Z)
                Pz = pz / np.outer(sc, sc)
        else:
            Z, o, Zs, Pz = _candidate_columns(p, built, a)
            Xb, yb = st.blocked(p.blocks)
            A = augment(st.A, Xb, yb, p.blocks, Zs, None if o is None else st.y - o)
            S = _sums_with(p, st, Zs, None if o is None else st.y - o)
            if cache is not None and raw_z is not None and built.penalty:
                folded = fold_grams(A, p.blocks)
                cache[key] = (raw_z, raw_o, A, S, Z, Pz, folded)
        P = _blockdiag(st.P, st.X.shape[1], Pz, 0 if Z is None else Z.shape[1])
        fits[a] = cv_fit(A, P, p.blocks, need_df=False, S=S, gls=bool(p.whiten), folded=folded)
    return fits


@dataclass
class _Shape:
    """What the criterion needs of a candidate's regressors (not the arrays)."""

    axes: list[str]
    q: int
    relag: bool

    def __init__(self, built: Built):
        self.axes = built.axes
        self.q = sum(c.shape[1] for c in built.cols.values())
        self.relag = bool(built.relag)


def evaluate(p: Prepared, state: State, cand: Candidate, axis: str, ctx: Context,
             grid: list[dict[str, Any]] | None = None) -> Evaluation | None:
    """Score ``cand`` on ``axis`` (nested blocked CV over its grid, or the given ``grid``)."""
    searched = grid is None
    grid = cand.grid(p, axis, ctx) if grid is None else grid
    if not grid:
        return None
    runs = []
    cache: dict = {}
    for nl in grid:
        built = cand.build(p, axis, nl, ctx)
        if not built.axes:
            continue
        runs.append((nl, _Shape(built), _fit_candidate(p, state, built, cache)))
        del built  # offsets of a large grid are not kept
    if not runs:
        return None
    axes = runs[0][1].axes
    w = {a: 1.0 / max(state.axes[a].mse, 1e-30) for a in axes}
    first = cand.refine[0][0] if cand.refine else ""
    if cand.refine and (len(grid) > 1 or cand.refine_interval(p, first, float(grid[0].get(first, 0.0))) is not None):
        # continuous parameters: refine the whole-data optimum between its grid neighbours and
        # offer it to every fold next to the grid values
        full = [sum(w[a] * f[a].sse_full for a in axes) for _, _, f in runs]
        nl_best = runs[int(np.argmin(full))][0]
        nl_ref = refine(p, state, cand, axis, nl_best, ctx, grid)
        if nl_ref != nl_best:
            built = cand.build(p, axis, nl_ref, ctx)
            runs.append((nl_ref, _Shape(built), _fit_candidate(p, state, built)))
    B = p.blocks.count
    fold = p.blocks.fold_of
    train = np.array([[sum(w[a] * f[a].sse_train[k] for a in axes) for k in range(p.blocks.folds)] for _, _, f in runs])
    held = np.array([[f[a].sse_block for a in axes] for _, _, f in runs])  # (G, axes, B)
    gls = bool(p.whiten)
    n = p.n
    if gls:
        # whole-data generalised least squares (cv_fit): the grid value of the best criterion, its
        # flexibility (effective parameters of a penalised term) charged
        dfs = np.array([sum(f[a].df - state.axes[a].fit.df for a in axes) for _, _, f in runs])
        crit = np.array([sum(n * math.log(max(f[a].sse_full, 1e-300) / max(state.axes[a].fit.sse, 1e-300)) for a in axes)
                         for _, _, f in runs]) + np.maximum(dfs, 1.0) * math.log(n * len(axes))
        g_full = int(np.argmin(crit))
        pick = np.full(B, g_full)
    elif cand.select_by_cv:
        g = int(np.argmin(np.einsum("gab,a->g", held, np.array([w[a] for a in axes]))))
        pick = np.full(B, g)
        g_full = g
    else:
        best_k = np.argmin(train, axis=0)  # per fold
        pick = best_k[fold]
        full = np.array([sum(w[a] * f[a].sse_full for a in axes) for _, _, f in runs])
        g_full = int(np.argmin(full))
    hold = {a: held[pick, j, np.arange(B)] for j, a in enumerate(axes)}
    sums = np.array([[f[a].sum_block for a in axes] for _, _, f in runs])
    hsum = {a: sums[pick, j, np.arange(B)] for j, a in enumerate(axes)}
    phi = inflation(hold, hsum, w)
    loglik = 0.0
    for a in axes:
        old, new = state.axes[a].fit.sse, float(hold[a].sum())
        loglik += n * math.log(max(new, 1e-300) / max(old, 1e-300))
    nl_count = len(cand.nonlinear) if len(grid) > 1 else 0
    if gls and cand.select_by_cv:
        df = float(dfs[g_full]) + len(cand.nonlinear)
    elif cand.select_by_cv:
        # a penalised smoother whose smoothness is chosen by held-out error: cross-validation already
        # charges its flexibility, the criterion counts the chosen hyperparameter
        df = float(len(cand.nonlinear))
    else:
        shape0 = runs[0][1]
        df = shape0.q + nl_count + (1 if not shape0.q and not shape0.relag else 0)
    df = max(df, 1.0)
    d_ic = loglik / phi + df * math.log(n * len(axes) / phi)
    d = sum((state.axes[a].fit.sse_block - hold[a]) * w[a] for a in axes)
    sd = float(np.std(d, ddof=1))
    t = float(np.mean(d) / (sd / math.sqrt(B))) if sd > 0 else 0.0
    before = state.rms(axes)
    after = math.sqrt(sum(float(hold[a].sum()) for a in axes) / (n * len(axes)))
    d_ic_raw = loglik + df * math.log(n * len(axes))
    # the whole-data fits must show the gain too: where a fold's training rows lack an excitation
    # the held-out block has (a rare tilt move's cross-axis rate), the baseline extrapolates there,
    # and any column that moves in that block repairs the fold's coefficients on held-out data
    # while it explains nothing on the whole data
    d_ic_full = (sum(n * math.log(max(runs[g_full][2][a].sse_full, 1e-300) / max(state.axes[a].fit.sse_full, 1e-300))
                     for a in axes) / phi + df * math.log(n * len(axes) / phi)) if not gls else d_ic
    gain_band, band_before, band_after, band_t = band_gain({a: state.axes[a].fit.sum_block for a in axes}, hsum, p.blocks)
    nl_full = dict(runs[g_full][0])
    resolved = True
    for name in cand.resolved if searched else ():
        top = max((g[name] for g in grid if name in g), default=None)
        if top is not None and nl_full.get(name, 0.0) >= 0.99 * top:
            resolved = False
    return Evaluation(cand, axis, axes, hold, nl_full, d_ic, t, 1.0 - after / before, before, after, df, phi,
                      d_ic_raw, resolved, gain_band, band_before, band_after, band_t, d_ic_full)


def compare(p: Prepared, old: State, new: State, axes: list[str], df: float) -> tuple[float, float, float, float, float]:
    """(ΔIC, relative held-out RMS gain, φ, relative block-mean RMS gain, its t statistic) of model
    ``new`` against ``old`` on ``axes``, by the rule of :func:`evaluate` (``df`` added parameters)."""
    w = {a: 1.0 / max(old.axes[a].mse, 1e-30) for a in axes}
    hold = {a: new.axes[a].fit.sse_block for a in axes}
    sums = {a: new.axes[a].fit.sum_block for a in axes}
    phi = inflation(hold, sums, w)
    n = p.n
    loglik = sum(n * math.log(max(new.axes[a].fit.sse, 1e-300) / max(old.axes[a].fit.sse, 1e-300)) for a in axes)
    d_ic = loglik / phi + max(df, 1.0) * math.log(n * len(axes) / phi)
    g_band, _, _, band_t = band_gain({a: old.axes[a].fit.sum_block for a in axes}, sums, p.blocks)
    return d_ic, 1.0 - new.rms(axes) / old.rms(axes), phi, g_band, band_t


INFLATION_SCALES = (1, 2, 4, 8)
MIN_GROUPS = 30


def inflation(hold: dict[str, np.ndarray], sums: dict[str, np.ndarray], w: dict[str, float]) -> float:
    """Variance inflation φ ≥ 1 of a held-out residual: (Σ over groups of (Σ residual)²) /
    (Σ squared residual), for groups of 1, 2, 4, 8 consecutive blocks (at least 30 groups), the
    largest. 1 for white noise; ≈ 1 + 2·Σρ_k for correlated residual."""
    best = 1.0
    for scale in INFLATION_SCALES:
        num = den = 0.0
        groups = 0
        for a, s in sums.items():
            g = s.shape[0] // scale
            if g < MIN_GROUPS:
                continue
            grouped = s[: g * scale].reshape(g, scale).sum(axis=1)
            num += w[a] * float(np.sum(grouped ** 2))
            den += w[a] * float(np.sum(hold[a][: g * scale]))
            groups = g
        if groups and den > 0:
            best = max(best, num / den)
    return best


def _full_sse(p: Prepared, state: State, built: Built, w: dict[str, float]) -> float:
    """Whole-data weighted SSE of ``state`` + ``built`` (for refining nonlinear parameters)."""
    one = Blocks(p.n, p.n, 1)
    total = 0.0
    for a in built.axes:
        if a in built.relag:
            total += w[a] * axis_state(p, a, state.terms + [Term("thermal_lag", a, {}, built)]).fit.sse_full
            continue
        st = state.axes[a]
        Z, o, Zs, Pz = _candidate_columns(p, built, a)
        A1 = st.A.sum(axis=0, keepdims=True)
        A = augment(A1, st.X[None], st.y[None, :, None], one, Zs, None if o is None else st.y - o)[0]
        m = A.shape[0] - 1
        G = A[:m, :m].copy()
        P = _blockdiag(st.P, st.X.shape[1], Pz, 0 if Z is None else Z.shape[1])
        if P is not None:
            G += P
        G[np.arange(m), np.arange(m)] += 1e-10 * max(float(np.max(np.diag(G))), 1e-30)
        beta = np.linalg.solve(G, A[:m, m]) if m else np.zeros(0)
        v = np.concatenate([beta, [-1.0]])
        total += w[a] * float(v @ A @ v)
    return total


def refine(p: Prepared, state: State, cand: Candidate, axis: str, nl: dict[str, Any], ctx: Context,
           grid: list[dict[str, Any]] | None = None) -> dict[str, Any]:
    """Continuous nonlinear parameters refined on all rows around the grid optimum (bounded scalar
    minimisation of the profiled SSE, one parameter at a time, within one grid step)."""
    if not cand.refine:
        return nl
    grid = cand.grid(p, axis, ctx) if grid is None else grid
    nl = dict(nl)
    for name, log in cand.refine:
        if name not in nl:
            continue
        bounds = cand.refine_interval(p, name, float(nl[name]))
        if bounds is None:
            vals = sorted({g[name] for g in grid if name in g})
            if len(vals) < 2:
                continue
            i = vals.index(nl[name]) if nl[name] in vals else int(np.argmin([abs(v - nl[name]) for v in vals]))
            lo, hi = vals[max(i - 1, 0)], vals[min(i + 1, len(vals) - 1)]
        else:
            lo, hi = bounds
        built0 = cand.build(p, axis, nl, ctx)
        w = {a: 1.0 / max(state.axes[a].mse, 1e-30) for a in built0.axes}

        def f(x: float) -> float:
            trial = dict(nl)
            trial[name] = float(math.exp(x) if log else x)
            return _full_sse(p, state, cand.build(p, axis, trial, ctx), w)

        a, b = (math.log(lo), math.log(hi)) if log else (lo, hi)
        f0 = f(math.log(nl[name]) if log else nl[name])
        res = minimize_scalar(f, bounds=(a, b), method="bounded", options={"xatol": 1e-3 * (b - a)})
        if res.fun < f0:
            nl[name] = float(math.exp(res.x) if log else res.x)
    return nl


def best_params(p: Prepared, state: State, cand: Candidate, axis: str, ctx: Context) -> dict[str, Any] | None:
    """Whole-data best nonlinear parameters of ``cand`` added to ``state``: grid, then refinement
    (held-out choice for the penalised random walk)."""
    if cand.select_by_cv:
        e = evaluate(p, state, cand, axis, ctx)
        return None if e is None else e.nl_full
    grid = cand.grid(p, axis, ctx)
    if len(grid) <= 1:
        return grid[0] if grid else None
    built0 = cand.build(p, axis, grid[0], ctx)
    w = {a: 1.0 / max(state.axes[a].mse, 1e-30) for a in built0.axes}
    sse = [_full_sse(p, state, cand.build(p, axis, nl, ctx), w) for nl in grid]
    return refine(p, state, cand, axis, grid[int(np.argmin(sse))], ctx, grid)


def lookahead(p: Prepared, base_terms: list[Term], found: list[Term], state: State, evals: list[Evaluation],
              cands: list[tuple[Candidate, str]], to_beat: float, steps: int = 2) -> tuple[list[Term], State] | None:
    """Named-only forward steps from ``state``; the first model (after 1 or 2 steps) whose ΔIC
    against ``state`` is acceptable and below ``to_beat`` (the random walk's), or None."""
    trial_found = [_copy(t) for t in found]
    cur, cur_evals = state, evals
    axes: set[str] = set()
    df = 0.0
    best: tuple[float, list[Term], State] | None = None
    for step in range(steps):
        raw = sorted((e for e in cur_evals if not e.cand.select_by_cv and e.acceptable_raw), key=lambda e: e.d_ic_raw)
        if not raw:
            break
        e = raw[0]
        ctx = cur.context()
        trial_found.append(Term(e.cand.name, e.axis, dict(e.nl_full), e.cand.build(p, e.axis, e.nl_full, ctx),
                                evidence={"t": e.t}))
        polish(p, base_terms, trial_found)
        cur = build_state(p, base_terms + trial_found)
        axes |= set(trial_found[-1].built.axes)
        df += e.df
        d_ic, gain, phi, gain_band, band_t = compare(p, state, cur, sorted(axes, key=AXES.index), df)
        if material(d_ic, gain, gain_band, band_t) and d_ic < (to_beat if best is None else best[0]):
            trial_found[-1].evidence.update({"d_ic": d_ic, "gain": gain, "phi": phi, "gain_band": gain_band})
            best = (d_ic, [_copy(t) for t in trial_found], cur)
        if step + 1 < steps:
            taken = {t.key for t in trial_found}
            ctx = cur.context()
            cur_evals = [x for c, ax in cands if not c.select_by_cv and (c.name, ax) not in taken
                         and (x := evaluate(p, cur, c, ax, ctx)) is not None]
    return None if best is None else (best[1], best[2])


def term_df(term: Term) -> float:
    """Parameters a found term adds (for the criterion): its linear columns and nonlinear
    parameters; 1 for the random walk (its hyperparameter) and for a fixed offset."""
    cand = CANDIDATES[term.effect]
    if cand.select_by_cv:
        return float(len(cand.nonlinear))
    q = sum(c.shape[1] for c in term.built.cols.values())
    return float(max(q + len(cand.nonlinear), 1))


def _copy(t: Term) -> Term:
    return Term(t.effect, t.axis, dict(t.nl), t.built, t.fixed, dict(t.evidence))


def polish(p: Prepared, base_terms: list[Term], found: list[Term]) -> None:
    """Re-fit each found term's nonlinear parameters given all the others (one coordinate pass,
    full grid then refinement): a parameter fitted while another effect was still unmodelled is
    biased, and the bias leaves structure a spurious term would take."""
    for term in found:
        cand = CANDIDATES[term.effect]
        if not cand.nonlinear:
            continue
        others = [t for t in found if t is not term]
        reduced = build_state(p, base_terms + others)
        ctx = reduced.context()
        nl = best_params(p, reduced, cand, term.axis, ctx)
        if nl is not None:
            term.nl = nl
            term.built = cand.build(p, term.axis, nl, ctx)


# ---- the search ----------------------------------------------------------------------------------
@dataclass
class Search:
    """Outcome of :func:`search`."""

    baseline: State
    final: State
    sequence: list[tuple[Term, State, State]]
    """(finding, state before, state after) in order of addition, recomputed for the final set."""
    rounds: list[list[dict[str, Any]]]
    not_excited: dict[str, str]
    dropped: list[dict[str, Any]]


def candidate_list(p: Prepared, exclude: set[tuple[str, str]],
                   hidden: frozenset[str] = frozenset()) -> tuple[list[tuple[Candidate, str]], dict[str, str]]:
    """(candidate, axis) pairs to try (regressors: not the noise terms, not the ``hidden`` names),
    and why others cannot be seen in these data."""
    out, why = [], {}
    for cand in CANDIDATES.values():
        if cand.noise_term or cand.name in hidden or cand.missing(p):
            continue
        for ax in cand.candidate_axes(p):
            if (cand.name, ax) in exclude or (cand.name, "all") in exclude:
                continue
            reason = cand.not_excited(p, ax)
            if reason:
                why[f"{cand.name}:{ax}"] = reason
                continue
            out.append((cand, ax))
    return out, why


def search(p: Prepared, base_terms: list[Term], max_terms: int = MAX_TERMS,
           hidden: frozenset[str] = frozenset(), progress: Callable[[str], None] | None = None) -> Search:
    """Forward selection then backward elimination (module docstring); ``hidden`` vocabulary
    names are not searched; ``progress`` is told each candidate evaluated."""
    base = build_state(p, base_terms)
    state = base
    rounds: list[list[dict[str, Any]]] = []
    exclude = {t.key for t in base_terms if t.effect != "baseline"}
    found: list[Term] = []
    not_excited: dict[str, str] = {}
    for _ in range(max_terms):
        cands, why = candidate_list(p, exclude | {t.key for t in found}, hidden)
        not_excited.update(why)
        ctx = state.context()
        evals = [e for c, ax in each(cands, progress, f"round {len(rounds) + 1}/{max_terms}, candidates")
                 if (e := evaluate(p, state, c, ax, ctx)) is not None]
        rounds.append([e.row() for e in sorted(evals, key=lambda e: e.d_ic)])
        ok = [e for e in evals if e.acceptable]
        if not ok:
            break
        best = min(ok, key=lambda e: e.d_ic)
        chosen: tuple[list[Term], State] | None = None
        if best.cand.select_by_cv:
            # a random walk can imitate any slow structure. Before it is added, named causes get a
            # second chance: up to two of them in turn, the others' parameters re-fitted around each
            # (a named cause looks partial while another named one is still unmodelled); the
            # alternative that explains better on held-out data, by the same criterion, goes in.
            chosen = lookahead(p, base_terms, found, state, evals, cands, best.d_ic)
        if chosen is not None:
            found, state = chosen
            continue
        nl = best.nl_full
        term = Term(best.cand.name, best.axis, nl, best.cand.build(p, best.axis, nl, ctx),
                    evidence={"d_ic": best.d_ic, "t": best.t, "gain": best.gain, "phi": best.phi,
                              "gain_band": best.gain_band})
        found.append(term)
        if len(found) > 1:
            polish(p, base_terms, found)
            state = build_state(p, base_terms + found)
        else:
            state = add_term(p, state, term)
    # backward elimination: each term against the best model without it (the others re-fitted in
    # its absence), the catch-all random walk first
    if progress is not None and found:
        progress(f"backward elimination of {len(found)} terms")
    dropped: list[dict[str, Any]] = []
    changed = True
    while changed and found:
        changed = False
        if len(found) > 1:
            polish(p, base_terms, found)
        full = build_state(p, base_terms + found)
        for term in sorted(found, key=lambda t: not CANDIDATES[t.effect].select_by_cv):
            others = [_copy(t) for t in found if t is not term]
            if others:
                polish(p, base_terms, others)
            reduced = build_state(p, base_terms + others)
            d_ic, gain, phi, gain_band, band_t = compare(p, reduced, full, term.built.axes, term_df(term))
            if not material(d_ic, gain, gain_band, band_t):
                dropped.append({"effect": term.effect, "axis": term.axis, "d_ic": d_ic, "gain": gain, "phi": phi,
                                "gain_band": gain_band, "nl": dict(term.nl), "reason": "no longer material"})
                found = others
                changed = True
                break
            term.evidence.update({"d_ic": d_ic, "gain": gain, "phi": phi, "gain_band": gain_band})
    seq, state = sequence(p, base, found)
    return Search(base, state, seq, rounds, not_excited, dropped)


def sequence(p: Prepared, base: State, found: list[Term]) -> tuple[list[tuple[Term, State, State]], State]:
    """(term, state before, state after) for each found term in order, and the final state."""
    seq = []
    state = base
    for term in found:
        if CANDIDATES[term.effect].select_by_cv:  # rebuild the penalty against the current noise
            term.built = CANDIDATES[term.effect].build(p, term.axis, term.nl, state.context())
        after = add_term(p, state, term)
        seq.append((term, state, after))
        state = after
    return seq, state
