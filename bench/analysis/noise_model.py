"""The sensor's own noise model, fitted from its data: white rate noise, flicker (bias instability),
rate random walk and Gauss-Markov (correlated) noise; and the whitening filter that lets an
analysis judge structure against that model instead of against white noise (``docs/diagnose.md``,
"Noise model").

Model of a residual series r_t sampled every Δ = 1/f_s seconds (bin means or raw samples), as a sum
of independent processes (IEEE Std 952-1997 Annex C names; the flicker as the Gauss-Markov sum of
:func:`bench.model.gyro.flicker_processes`, as the simulator makes it):

* white rate noise, variance w per sample: angle random walk N = √(w·Δ) (deg/√s);
* flicker (bias instability) B (deg/s): Gauss-Markov processes two per decade of correlation time
  between Δ and the record length T, each of variance B²·ln r/π (one-sided PSD B²/(2πf), Allan
  plateau 0.664·B, IEEE 952 Eq. C.14);
* rate random walk K (deg/s/√s): a random walk with increments of variance K²·Δ;
* Gauss-Markov processes (σ, τ_c): first-order, variance σ², correlation e^(−|t|/τ_c) (the hump of a
  MEMS Allan curve; NPSAT1 IV.G.3 and the Allan literature's "Markov" term).

Each correlated process is an AR(1) state (φ = e^(−Δ/τ), the random walk φ = 1), so the spectral
density of the sum at ω (rad/sample) is

    S(ω) = w + Σ_j v_j (1 − φ_j²) / |1 − φ_j e^(−iω)|² + K²Δ / |1 − e^(−iω)|².

**Fitting** (:func:`fit_noise_model`): Whittle likelihood of the periodogram of r, averaged over
log-spaced frequency bands (each band mean of L ordinates is Gamma(L, S/L)), maximised over the
variances (log-parameters, L-BFGS-B) for a given set of components; components are added forward
(flicker, random walk, a Gauss-Markov process at the best correlation time of a grid, up to
:data:`MAX_COMPONENTS`) while the Bayesian information criterion drops by more than
:data:`IC_MIN` and the component is material (its spectral density reaches :data:`MATERIAL_SHARE` of
the total at some observed frequency). Where a Gauss-Markov term of τ_c ≈ one sample makes the
white part unidentifiable (its profile likelihood does not reject "no white part", :data:`WHITE_LR`),
the white part is the likelihood-weighted mean along that ridge, with its 95 % interval.
:func:`with_slow_part` gives a model without a slow part its best slow component whatever the BIC
says: the model diagnose judges slow structure in time against when the selected one has none.

**Whitening** (:class:`Whitener`): the steady-state Kalman filter of that state-space model turns r
into its innovations, which are white with variance S_ε when the model is right; as a transfer
function it has its zeros at φ_j and its poles at the eigenvalues of F(I − KH), applied as second-
order sections to every column of a design (generalised least squares by prewhitening). A segment's
first innovations carry the start-up uncertainty of the slow states; they are scaled by
√(S_ε/S_t) (the time-varying innovation variance of the filter started from the stationary state),
so no single early row dominates a fit. Gaps in time start a new segment.

The engine cannot tell a slow deterministic drift from bias instability or a random walk in one
run: both are power at low frequency. The model takes whatever the deterministic search and the
covariate probes leave; a second run (the drift repeats, noise does not) separates them. A
temperature channel takes a drift that follows it into the baseline, but over a temperature that
only rises after power-on it takes a drift that follows time as well: in one run it does not
separate them (docs/diagnose.md, Known limits).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

IC_MIN = 10.0
"""Required drop of the Whittle BIC for a component to join the noise model (as diagnose's IC_MIN)."""
MATERIAL_SHARE = 0.1
"""A component joins only if its spectral density is at least this share of the model's at some
observed frequency (it shapes the spectrum; as the Allan excess test's 10 % in variance)."""
MAX_COMPONENTS = 4
"""Most correlated components (flicker, random walk, Gauss-Markov processes) in one model."""
BANDS_PER_DECADE = 24
"""Frequency bands per decade for the band-averaged Whittle likelihood (first ordinates kept single)."""
GM_PER_DECADE = 3
"""Gauss-Markov correlation times tried per decade (then refined)."""
GM_RESOLVED = 1.0 / 3.0
"""A Gauss-Markov correlation time is at most this share of the record: the spectrum must show its
roll-off (a longer one is a random walk within the record, which the ``rrw`` component is)."""
GM_GRID_FROM = 0.5
"""The correlation-time grid's anchor (samples): its points are those of a grid from half a sample,
so the points in the resolved range, and the fits at them, do not move with :data:`GM_MIN_SAMPLES`."""
GM_MIN_SAMPLES = 2.0 / math.pi
"""... and at least this many samples: its corner f_c = 1/(2π τ_c) lies at or below half the Nyquist
frequency 1/(2Δ), so the band shows the plateau and an octave of the 1/f² fall. A shorter process is,
at the sampled rate, a tilt of a nearly flat spectrum (its sampled AR(1) density falls by less than
(1+φ)²/(1−φ)² = 2.3 from 0 to Nyquist), which an anti-alias filter, bin averaging or an aliased hump
makes as well: it is part of the white rate noise (its low-frequency level is what the Allan −½ line
reads), not a resolved Gauss-Markov term. A fitted τ_c at either end of the grid is not resolved."""
WHITE_FLOOR = 1e-6
"""The white variance is at least this share of the series' variance (the filter needs R > 0)."""
WHITE_LR = 3.841
"""The white part is *identified* when the profile likelihood ratio of the fitted model against the
same model with the white part at its floor (the other parts, and the fastest Gauss-Markov τ_c,
refitted) is at least this: χ²₁ at 5 %. Asked when the model has a Gauss-Markov term faster than
:data:`SLOW_SAMPLES`. Below it the data cannot tell the white part from a Gauss-Markov term of τ_c
about one sample (their sum is nearly one ARMA(1,1) spectrum; the Whittle Cramér-Rao bound of ln w
at τ_c = Δ, σ_gm = 2σ_white, n = 3600 is 0.56), the likelihood is flat along that ridge and its
maximum can lie at the floor: then, unless the 95 % interval also rejects every material white
part (:attr:`WhiteProfile.identified`), the white part is the likelihood-weighted mean along the
ridge and the model keeps its 95 % interval (:func:`white_profile`, ``NoiseModel.white_interval``)."""
WHITE_GRID = 16
"""Points of the white variance's profile likelihood (linear, floor to the fitted spectrum's
minimum) that :func:`white_profile` averages over when the white part is not identified."""


@dataclass
class NoiseModel:
    """A fitted noise model of a series sampled every ``dt_s`` seconds over ``duration_s``.

    ``white_var``: white variance per sample ((deg/s)²); ``flicker_b``: B (deg/s) or 0;
    ``rrw_k``: K (deg/s/√s) or 0; ``gm``: [(σ deg/s, τ_c s), ...]; ``loglik`` the Whittle
    log-likelihood; ``steps``: the forward selection (component, ΔBIC, accepted)."""

    dt_s: float
    duration_s: float
    white_var: float
    flicker_b: float = 0.0
    rrw_k: float = 0.0
    gm: list[tuple[float, float]] = field(default_factory=list)
    loglik: float = float("nan")
    steps: list[dict[str, Any]] = field(default_factory=list)
    bin_rows: int = 1
    """Raw samples averaged into each analysed sample (for the read-outs in physical units)."""
    white_interval: tuple[float, float] | None = None
    """When the data can tell the white part neither from zero nor from a material one
    (:attr:`WhiteProfile.identified`): the white variance's 95 % profile-likelihood interval
    ((deg/s)² per sample), ``white_var`` being the likelihood-weighted mean along it; None when the
    white part is identified."""

    @property
    def is_white(self) -> bool:
        return self.flicker_b == 0 and self.rrw_k == 0 and not self.gm

    def flicker_states(self) -> tuple[np.ndarray, np.ndarray]:
        """(τ_j, variance_j) of the flicker's Gauss-Markov sum."""
        if self.flicker_b <= 0:
            return np.zeros(0), np.zeros(0)
        taus, per_b = flicker_range(self.dt_s, self.duration_s)
        return taus, np.full(taus.size, (self.flicker_b * per_b) ** 2)

    def states(self) -> tuple[np.ndarray, np.ndarray]:
        """AR(1) coefficients φ_j and driving-noise variances q_j of every correlated state."""
        taus, var = self.flicker_states()
        taus = list(taus) + [t for _, t in self.gm]
        var = list(var) + [s * s for s, _ in self.gm]
        phi = [math.exp(-self.dt_s / t) for t in taus]
        q = [v * (1.0 - f * f) for v, f in zip(var, phi)]
        if self.rrw_k > 0:
            phi.append(1.0)
            q.append(self.rrw_k ** 2 * self.dt_s)
        return np.asarray(phi, float), np.asarray(q, float)

    def psd(self, omega: np.ndarray) -> np.ndarray:
        """Spectral density at ω (rad/sample), (deg/s)² per rad/sample·2π (white = w)."""
        phi, q = self.states()
        c = np.cos(omega)
        out = np.full(np.shape(omega), self.white_var, dtype=float)
        for f, qq in zip(phi, q):
            out = out + qq / (1.0 - 2.0 * f * c + f * f)
        return out

    def terms(self) -> dict[str, Any]:
        """The model in IEEE 952 units: ARW (deg/√h), B (deg/h), K (deg/h/√h), Gauss-Markov
        (σ deg/s, τ_c s)."""
        n = math.sqrt(self.white_var * self.dt_s)  # deg/√s
        return {"arw_deg_per_sqrt_h": 60.0 * n,
                "bias_instability_deg_per_h": 3600.0 * self.flicker_b if self.flicker_b > 0 else None,
                "rrw_deg_per_h_per_sqrt_h": 3600.0 * 60.0 * self.rrw_k if self.rrw_k > 0 else None,
                "gauss_markov": [{"sigma_dps": s, "tau_s": t} for s, t in self.gm],
                "arw_interval_deg_per_sqrt_h": None if self.white_interval is None else
                [60.0 * math.sqrt(v * self.dt_s) for v in self.white_interval]}

    def describe(self) -> str:
        t = self.terms()
        parts = [f"white {t['arw_deg_per_sqrt_h']:.3g} deg/√h"]
        if self.white_interval is not None:
            lo, hi = (60.0 * math.sqrt(v * self.dt_s) for v in self.white_interval)
            parts[0] += f" ({lo:.2g}-{hi:.2g} within 95 %: not told apart from the fast Gauss-Markov term)"
        if t["bias_instability_deg_per_h"] is not None:
            parts.append(f"flicker B {t['bias_instability_deg_per_h']:.3g} deg/h")
        if t["rrw_deg_per_h_per_sqrt_h"] is not None:
            parts.append(f"rate random walk K {t['rrw_deg_per_h_per_sqrt_h']:.3g} deg/h/√h")
        for g in t["gauss_markov"]:
            parts.append(f"Gauss-Markov {g['sigma_dps']:.2g} deg/s, τc {g['tau_s']:.3g} s")
        return " + ".join(parts)

    @property
    def n_params(self) -> int:
        """Fitted parameters: the white variance, B, K, and (σ, τ_c) of each Gauss-Markov process."""
        return 1 + int(self.flicker_b > 0) + int(self.rrw_k > 0) + 2 * len(self.gm)

    def exact_loglik(self, r: np.ndarray, t: np.ndarray) -> float:
        """Exact Gaussian log-likelihood of the series ``r`` (sampled at ``t``) under this model (the
        time domain, no taper: ``loglik`` is the band Whittle approximation the fit maximised)."""
        if self.is_white:
            x = np.asarray(r, dtype=float) - float(np.mean(r))
            return -0.5 * (x.size * math.log(2.0 * math.pi * self.white_var) + float(np.dot(x, x)) / self.white_var)
        return self.whitener().exact_loglik(r, t)

    def whitener(self) -> "Whitener | None":
        """The prewhitening filter of this model (None when it is white)."""
        return None if self.is_white else Whitener(self)


def flicker_range(dt_s: float, duration_s: float) -> tuple[np.ndarray, float]:
    """The flicker's Gauss-Markov correlation times (one sample to the record length, two per decade)
    and σ per unit B (:func:`bench.model.gyro.flicker_processes`)."""
    from bench.model.gyro import flicker_processes

    return flicker_processes(dt_s, max(duration_s, 10.0 * dt_s))


# ---- fitting --------------------------------------------------------------------------------------
@dataclass
class _Bands:
    omega: np.ndarray
    mean_i: np.ndarray
    count: np.ndarray

    @property
    def ordinates(self) -> int:
        return int(self.count.sum())


def _bands(r: np.ndarray) -> _Bands:
    """Band-averaged periodogram of the mean-removed series through a split-cosine taper (10 % at
    each end, normalised to unit power: a random walk's jump between the record's end and start
    would otherwise leak into every low ordinate): ordinates j = 1 … (n−1)/2 at ω_j = 2πj/n,
    I_j = |Σ h_t r_t e^(−iω_j t)|²/Σh², grouped into log-spaced bands."""
    n = r.shape[0]
    h = _taper(n)
    spec = np.fft.rfft((r - r.mean()) * h) * math.sqrt(n / float(np.dot(h, h)))
    j = np.arange(1, (n - 1) // 2 + 1)
    i_j = (spec.real[j] ** 2 + spec.imag[j] ** 2) / n
    edges = np.unique(np.round(np.geomspace(1, j.size + 1, int(BANDS_PER_DECADE * math.log10(j.size + 1)) + 2)).astype(int))
    edges = np.unique(np.concatenate([edges, [j.size + 1]]))
    starts, ends = edges[:-1] - 1, edges[1:] - 1
    csum = np.concatenate([[0.0], np.cumsum(i_j)])
    wsum = np.concatenate([[0.0], np.cumsum(j)])
    count = (ends - starts).astype(float)
    omega = 2.0 * math.pi * ((wsum[ends] - wsum[starts]) / count) / n
    return _Bands(omega, (csum[ends] - csum[starts]) / count, count)


TAPER = 0.1
"""Share of the record tapered at each end (split-cosine bell) before the periodogram."""


def _taper(n: int) -> np.ndarray:
    m = max(int(TAPER * n), 1)
    h = np.ones(n)
    ramp = 0.5 * (1.0 - np.cos(np.pi * (np.arange(m) + 0.5) / m))
    h[:m] = ramp
    h[n - m:] = ramp[::-1]
    return h


def _basis(kind: str, omega: np.ndarray, dt: float, duration: float, tau: float | None = None) -> np.ndarray:
    """Spectral density of one component per unit parameter² (white: w, flicker: B², rrw: K²,
    gm: σ²) at ω."""
    c = np.cos(omega)
    if kind == "white":
        return np.ones_like(omega)
    if kind == "rrw":
        return dt / (2.0 - 2.0 * c)
    if kind == "gm":
        f = math.exp(-dt / tau)
        return (1.0 - f * f) / (1.0 - 2.0 * f * c + f * f)
    if kind == "flicker":
        taus, per_b = flicker_range(dt, duration)
        out = np.zeros_like(omega)
        for t in taus:
            f = math.exp(-dt / t)
            out += per_b ** 2 * (1.0 - f * f) / (1.0 - 2.0 * f * c + f * f)
        return out
    raise ValueError(kind)


def _whittle(theta: np.ndarray, G: np.ndarray, b: _Bands, offset: np.ndarray | float = 0.0) -> float:
    """Band Whittle log-likelihood of S = G·θ (+ a fixed ``offset`` spectrum)."""
    s = np.maximum(G @ theta + offset, 1e-300)
    return float(-np.sum(b.count * (np.log(s) + b.mean_i / s)))


def _fit(G: np.ndarray, b: _Bands, theta0: np.ndarray, offset: np.ndarray | float = 0.0) -> tuple[np.ndarray, float]:
    """Maximise the Whittle likelihood over θ ≥ 0 (log-parameters), S = G·θ + ``offset``."""
    from scipy.optimize import minimize

    hi = _log_cap(G, b)
    s_min = SPEC_FLOOR * float(np.mean(b.mean_i)) + 1e-300
    floor = np.maximum(theta0 * 1e-8, 1e-300)

    def f(x: np.ndarray) -> tuple[float, np.ndarray]:
        capped = x > hi
        th = np.exp(np.where(capped, hi, x))
        s = np.maximum(G @ th + offset, s_min)
        val = -np.sum(b.count * (np.log(s) + b.mean_i / s))
        grad_s = -b.count * (s - b.mean_i) / s / s
        return -val, np.where(capped, 0.0, -(G.T @ grad_s) * th)

    x0 = np.minimum(np.log(np.maximum(theta0, floor)), hi)
    res = minimize(f, x0, jac=True, method="L-BFGS-B", options={"maxiter": 300})
    th = np.exp(np.minimum(res.x, hi))
    return th, _whittle(th, G, b, offset)


CAP_ABOVE = 1e6
"""A component's parameter is capped where its density reaches this many times the band-averaged
periodogram at the band where it comes closest: no maximum of the Whittle likelihood lies there
(each band beyond the data by a factor F costs its count·ln F). The cap (and :data:`SPEC_FLOOR`)
keeps a wild line-search step finite: uncapped, one step reached e^(2.8e5) on a residual with a large
slow part, and the density, then its square, overflowed. (Bounds given to the optimiser instead
would let a projected step park the white part at its lower bound, where the gradient in log θ
vanishes.)"""
SPEC_FLOOR = 1e-12
"""The model density is at least this share of the mean band periodogram (never a maximum either)."""


def _log_cap(G: np.ndarray, b: _Bands) -> np.ndarray:
    """The log-parameter of each column of ``G`` at :data:`CAP_ABOVE`."""
    data = np.maximum(b.mean_i, SPEC_FLOOR * float(np.mean(b.mean_i)) + 1e-300)
    return np.log(CAP_ABOVE * np.min(data[:, None] / np.maximum(G, 1e-300), axis=0))


def fit_noise_model(r: np.ndarray, dt_s: float, bin_rows: int = 1, allow: tuple[str, ...] = ("flicker", "rrw", "gm"),
                    ic_min: float = IC_MIN, max_tau_s: float | None = None) -> NoiseModel:
    """Fit the noise model of residual ``r`` (deg/s, one sample every ``dt_s`` s): white, then forward
    selection of flicker, rate random walk and Gauss-Markov processes (module docstring). ``allow``
    limits the kinds tried, ``max_tau_s`` the Gauss-Markov correlation times."""
    r = np.asarray(r, dtype=float)
    n = r.shape[0]
    duration = n * dt_s
    var = float(np.var(r))
    model = NoiseModel(dt_s, duration, max(var, 1e-300), bin_rows=bin_rows)
    if n < 64 or var <= 0:
        return model
    b = _bands(r)
    comps: list[tuple[str, float | None]] = [("white", None)]
    G = _basis("white", b.omega, dt_s, duration)[:, None]
    theta, ll = _fit(G, b, np.array([var]))
    model.loglik = ll
    lo_tau, hi_tau = GM_MIN_SAMPLES * dt_s, GM_RESOLVED * duration
    if max_tau_s is not None:
        hi_tau = max(min(hi_tau, max_tau_s), 1.01 * lo_tau)
    taus = _tau_grid(dt_s, lo_tau, hi_tau)
    while len(comps) - 1 < MAX_COMPONENTS:
        tried = _trials(G, b, theta, ll, comps, allow, taus, dt_s, duration)
        best = _accept(tried, G, b, theta, dt_s, duration, lo_tau, hi_tau, ic_min)
        if best is None:
            if tried:
                d_bic, k_, tau, *_ = min(tried, key=lambda x: x[0])
                model.steps.append({"component": k_, "tau_s": tau, "d_bic": d_bic, "accepted": False})
            break
        d_bic, k_, tau, th, ll2, col, share = best
        comps.append((k_, tau))
        G = np.column_stack([G, col])
        theta, ll = th, ll2
        model.steps.append({"component": k_, "tau_s": tau, "d_bic": d_bic, "share": share, "accepted": True})
    if any(c[0] == "gm" and c[1] < SLOW_SAMPLES * dt_s for c in comps):
        # a fast Gauss-Markov term's nearly flat spectrum can trade its power with the white part
        taus_c = [c[1] if c[0] == "gm" else None for c in comps]
        prof = _white_ridge(G, b, theta, ll, taus_c, dt_s, duration, lo_tau, hi_tau, WHITE_FLOOR * var, full=False)
        if not prof.identified:
            model.white_interval = prof.interval()
            theta, ll, tau_k = prof.settle()
            if prof.k is not None:
                comps[prof.k] = ("gm", tau_k)
    return _settle(model, comps, theta, ll, WHITE_FLOOR * var)


def _tau_grid(dt_s: float, lo_tau: float, hi_tau: float) -> np.ndarray:
    """The Gauss-Markov correlation times tried (s): a grid anchored at half a sample
    (:data:`GM_GRID_FROM`), :data:`GM_PER_DECADE` a decade up to ``hi_tau``, its points below
    ``lo_tau`` dropped."""
    start = GM_GRID_FROM * dt_s
    taus = np.geomspace(start, hi_tau, max(int(GM_PER_DECADE * math.log10(hi_tau / start)) + 1, 2))
    return taus[taus >= lo_tau]


def _settle(model: NoiseModel, comps: list[tuple[str, float | None]], theta: np.ndarray, ll: float,
            w_floor: float) -> NoiseModel:
    """``model`` with the components ``comps`` (white first) at parameters ``theta``."""
    model.loglik = ll
    model.white_var = max(float(theta[0]), w_floor)
    model.flicker_b, model.rrw_k, model.gm = 0.0, 0.0, []
    for (kind, tau), v in zip(comps[1:], theta[1:]):
        if kind == "flicker":
            model.flicker_b = math.sqrt(v)
        elif kind == "rrw":
            model.rrw_k = math.sqrt(v)
        else:
            model.gm.append((math.sqrt(v), float(tau)))
    model.gm.sort(key=lambda g: g[1])
    return model


def _trials(G: np.ndarray, b: _Bands, theta: np.ndarray, ll: float, comps: list[tuple[str, float | None]],
            allow: tuple[str, ...], taus: np.ndarray, dt_s: float, duration: float) -> list[tuple]:
    """Each component of the kinds ``allow`` (Gauss-Markov at each of ``taus``) not yet in ``comps``
    fitted beside the model ``G``·``theta``: (ΔBIC, kind, τ, θ, log-likelihood, column, share)."""
    tried = []
    for kind in allow:
        if kind in ("flicker", "rrw") and any(c[0] == kind for c in comps):
            continue
        options = [(kind, float(t)) for t in taus] if kind == "gm" else [(kind, None)]
        for k_, tau in options:
            if k_ == "gm" and any(c[0] == "gm" and abs(math.log(c[1] / tau)) < 0.5 for c in comps):
                continue
            col = _basis(k_, b.omega, dt_s, duration, tau)
            G2 = np.column_stack([G, col])
            scale = float(np.median(b.mean_i / np.maximum(col, 1e-300)))
            th, ll2 = _fit(G2, b, np.concatenate([theta, [max(0.1 * scale, 1e-300)]]))
            k_params = 2 if k_ == "gm" else 1
            d_bic = -2.0 * (ll2 - ll) + k_params * math.log(b.ordinates)
            share = float(np.max(th[-1] * col / np.maximum(G2 @ th, 1e-300)))
            tried.append((d_bic, k_, tau, th, ll2, col, share))
    return tried


def _accept(tried: list[tuple], G: np.ndarray, b: _Bands, theta: np.ndarray, dt_s: float, duration: float,
            lo_tau: float, hi_tau: float, ic_min: float) -> tuple | None:
    """The best of ``tried`` (:func:`_trials`) that lowers the BIC by more than ``ic_min``, is material
    and, for a Gauss-Markov term, resolved once refined; None when none is."""
    for d_bic, k_, tau, th, ll2, col, share in sorted(tried, key=lambda x: x[0]):
        if k_ == "gm" and not _resolved(tau, lo_tau, hi_tau):
            continue  # a correlation time at an end of the grid is not resolved
        if d_bic < -ic_min and share >= MATERIAL_SHARE:
            if k_ == "gm":
                tau, th, ll2, col = _refine_gm(G, b, theta, tau, dt_s, duration, th, ll2, lo_tau, hi_tau)
                if not _resolved(tau, lo_tau, hi_tau):
                    continue  # the likelihood runs to an end of the grid once refined
            return d_bic, k_, tau, th, ll2, col, share
    return None


def with_slow_part(r: np.ndarray, model: NoiseModel) -> NoiseModel | None:
    """``model`` (fitted to the residual ``r``, without a slow part: :data:`SLOW_SAMPLES`) with its
    best slow component added whatever the BIC says: flicker, a random walk, or a Gauss-Markov process
    of correlation time ≥ :data:`SLOW_SAMPLES` samples, the one of lowest ΔBIC among those that are
    material (:data:`MATERIAL_SHARE`) and, a Gauss-Markov term, resolved; every variance refitted
    jointly. The model a slow structure in time is judged against when the selected model has no slow
    part to judge it with (``bench.analysis.diagnose.noise.beyond_noise``). None when no slow
    component raises the likelihood materially. Its last step records the slow component (accepted,
    with its ΔBIC and ``"asked": True``)."""
    r = np.asarray(r, dtype=float)
    if r.shape[0] < 64 or float(np.var(r)) <= 0:
        return None
    b = _bands(r)
    dt, duration = model.dt_s, model.duration_s
    G, theta = _columns(model, b.omega), _theta(model)
    comps: list[tuple[str, float | None]] = [("white", None)] + [("flicker", None)] * (model.flicker_b > 0) + [
        ("rrw", None)] * (model.rrw_k > 0) + [("gm", t) for _, t in model.gm]
    theta, ll = _fit(G, b, theta)
    lo_tau, hi_tau = max(SLOW_SAMPLES, GM_MIN_SAMPLES) * dt, GM_RESOLVED * duration
    taus = _tau_grid(dt, lo_tau, hi_tau) if hi_tau > lo_tau else np.zeros(0)
    tried = [t for t in _trials(G, b, theta, ll, comps, ("flicker", "rrw", "gm"), taus, dt, duration) if t[4] > ll]
    best = _accept(tried, G, b, theta, dt, duration, lo_tau, hi_tau, -math.inf)
    if best is None:
        return None
    d_bic, kind, tau, th, ll2, _, share = best
    out = NoiseModel(dt, duration, model.white_var, bin_rows=model.bin_rows, steps=list(model.steps))
    _settle(out, comps + [(kind, tau)], th, ll2, WHITE_FLOOR * float(np.var(r)))
    out.steps.append({"component": kind, "tau_s": tau, "d_bic": d_bic, "share": share, "accepted": True, "asked": True})
    return out


@dataclass
class WhiteProfile:
    """The profile likelihood of the white variance w along the white/Gauss-Markov ridge: at each w
    the other parts (and the fastest Gauss-Markov term's τ_c) refitted (:func:`white_profile`)."""

    white_var: np.ndarray
    """w, (deg/s)² per sample: the floor, then (when the white part is not identified) a linear grid
    from the floor to the fitted spectrum's minimum."""
    loglik: np.ndarray
    """Profile band-Whittle log-likelihood at each w."""
    lr_floor: float
    """2·(maximum − profile at the floor): the likelihood ratio of "no white part"."""
    top: float = math.inf
    """The fitted spectrum's minimum over the band: the most white variance any fit could hold."""
    k: int | None = None
    """Column of the Gauss-Markov term whose τ_c is refitted along the ridge (None: none)."""
    _refit: Any = None

    @property
    def identified(self) -> bool:
        """Whether the data reject "no white part" at 5 % (:data:`WHITE_LR`), or reject every
        material one (the 95 % interval stays below :data:`MATERIAL_SHARE` of the spectrum's minimum:
        the band's top falls faster than the Gauss-Markov term allows, as behind a sensor's low-pass
        filter, and there is no white part at this rate)."""
        return self.lr_floor >= WHITE_LR or self.interval()[1] < MATERIAL_SHARE * self.top

    def interval(self) -> tuple[float, float]:
        """The grid's w within the 95 % profile-likelihood interval (2·Δ log L ≤ :data:`WHITE_LR`)."""
        keep = self.white_var[2.0 * (self.loglik.max() - self.loglik) <= WHITE_LR]
        return (0.0 if keep.min() <= self.white_var[0] else float(keep.min())), float(keep.max())

    def mean(self) -> float:
        """The likelihood-weighted mean of w along the ridge (a flat prior in w on the grid's range):
        where the likelihood cannot tell white from the Gauss-Markov term, the centre of what it
        allows rather than its maximum, which may sit at the floor."""
        wts = np.exp(self.loglik - self.loglik.max())
        dw = np.diff(self.white_var)  # trapezoid rule on the grid (numpy 1.26 has no np.trapezoid)
        area = float(np.sum(0.5 * (wts[1:] + wts[:-1]) * dw))
        first = float(np.sum(0.5 * (wts[1:] * self.white_var[1:] + wts[:-1] * self.white_var[:-1]) * dw))
        return first / area

    def settle(self) -> tuple[np.ndarray, float, float | None]:
        """(θ, log-likelihood, τ_c of column k) of the model with w at :meth:`mean`."""
        return self._refit(self.mean())


def white_profile(r: np.ndarray, model: NoiseModel) -> WhiteProfile:
    """The white variance's profile likelihood of ``model`` on the residual ``r`` it was fitted to,
    over the full grid (for studies and tests; :func:`fit_noise_model` computes the grid only when
    the white part is not identified)."""
    r = np.asarray(r, dtype=float)
    b = _bands(r)
    G = _columns(model, b.omega)
    taus = [None] * (G.shape[1] - len(model.gm)) + [t for _, t in model.gm]
    th = _theta(model)
    lo_tau, hi_tau = GM_MIN_SAMPLES * model.dt_s, GM_RESOLVED * model.duration_s
    return _white_ridge(G, b, th, _whittle(th, G, b), taus, model.dt_s, model.duration_s, lo_tau, hi_tau,
                        WHITE_FLOOR * float(np.var(r)), full=True)


def _white_ridge(G: np.ndarray, b: _Bands, theta: np.ndarray, ll: float, taus: list[float | None], dt: float,
                 duration: float, lo_tau: float, hi_tau: float, w_floor: float, full: bool) -> WhiteProfile:
    """The profile of the white variance (column 0 of ``G``); ``taus``: each column's Gauss-Markov
    τ_c or None. The grid is computed when ``full`` or when the white part is not identified."""
    from scipy.optimize import minimize_scalar

    gm_cols = [(t, j) for j, t in enumerate(taus) if t is not None]
    k = min(gm_cols)[1] if gm_cols else None
    step = math.log(10.0) / GM_PER_DECADE

    def at(w: float, th0: np.ndarray) -> tuple[float, np.ndarray, float | None]:
        others = list(range(1, G.shape[1]))
        if k is None:
            th, l_ = _fit(G[:, others], b, th0, offset=w)
            return l_, th, None
        t0 = taus[k]
        lo = max(math.log(t0) - step, math.log(lo_tau))
        hi = max(min(math.log(t0) + step, math.log(hi_tau)), lo)

        def cols(x: float) -> np.ndarray:
            g = G[:, others].copy()
            g[:, k - 1] = _basis("gm", b.omega, dt, duration, math.exp(x))
            return g

        res = minimize_scalar(lambda x: -_fit(cols(x), b, th0, offset=w)[1], bounds=(lo, hi),
                              method="bounded", options={"xatol": 0.02})
        th, l_ = _fit(cols(res.x), b, th0, offset=w)
        return l_, th, math.exp(res.x)

    th_o = np.maximum(theta[1:], 1e-300)
    l_floor = at(w_floor, th_o)[0]
    ws, lls = [w_floor, float(theta[0])], [l_floor, ll]
    lr = 2.0 * (max(ll, l_floor) - l_floor)

    def refit(w: float) -> tuple[np.ndarray, float, float | None]:
        l_, th, tau = at(w, th_o)
        return np.concatenate([[w], th]), l_, tau

    top = max(float(np.min(G @ theta)), w_floor)
    if full or lr < WHITE_LR:
        for w in np.linspace(w_floor, top, WHITE_GRID)[1:]:
            ws.append(float(w))
            lls.append(at(float(w), th_o)[0])
    order = np.argsort(ws)
    return WhiteProfile(np.asarray(ws)[order], np.asarray(lls)[order], lr, top, k, refit)


def _columns(model: NoiseModel, omega: np.ndarray) -> np.ndarray:
    """The spectral basis of ``model``'s components at ω (white first) and their parameters θ."""
    cols = [_basis("white", omega, model.dt_s, model.duration_s)]
    if model.flicker_b > 0:
        cols.append(_basis("flicker", omega, model.dt_s, model.duration_s))
    if model.rrw_k > 0:
        cols.append(_basis("rrw", omega, model.dt_s, model.duration_s))
    for _, tau in model.gm:
        cols.append(_basis("gm", omega, model.dt_s, model.duration_s, tau))
    return np.column_stack(cols)


def _theta(model: NoiseModel) -> np.ndarray:
    th = [model.white_var]
    if model.flicker_b > 0:
        th.append(model.flicker_b ** 2)
    if model.rrw_k > 0:
        th.append(model.rrw_k ** 2)
    th += [s * s for s, _ in model.gm]
    return np.asarray(th, float)


PARTS = 4
"""Stretches of the record the stationarity check compares."""


SLOW_SAMPLES = 20.0
"""Components with correlation times of at least this many samples (and flicker, random walk) are
the slow part the stationarity check tests; faster ones may change level between stretches."""


def stationarity(r: np.ndarray, model: NoiseModel, parts: int = PARTS) -> float:
    """ΔBIC of "each of ``parts`` consecutive stretches has its own slow-component variances" against
    "the slow components of the whole record" (the fast ones, white and short Gauss-Markov, free in
    each stretch under both; band Whittle likelihood of each stretch). Strongly negative when the slow
    part is not stationary noise but a transient, a step, a drift or structure that follows a
    covariate through the run (its power sits in some stretches only). +inf without slow components
    (nothing to test) or when the stretches are too short. (:func:`stationarity_test`: the same
    likelihood ratio as a test of one hypothesis at a stated level.)"""
    lr, dof, m = _stationarity_lr(r, model, parts)
    return math.inf if dof == 0 else -lr + dof * math.log(max(m, 2))


def stationarity_test(r: np.ndarray, model: NoiseModel, parts: int = PARTS) -> tuple[float, float]:
    """(likelihood-ratio statistic, p-value) of :func:`stationarity`'s comparison as a test of the one
    hypothesis "the slow part is the same noise in every stretch": under it the statistic is about χ²
    with ``parts`` × (slow components) degrees of freedom (clipped at 0 per stretch, so the p-value
    errs high). (nan, 1.0) when there is nothing to test."""
    from scipy.stats import chi2

    lr, dof, _ = _stationarity_lr(r, model, parts)
    if dof == 0:
        return float("nan"), 1.0
    return lr, float(chi2.sf(lr, dof))


def _stationarity_lr(r: np.ndarray, model: NoiseModel, parts: int) -> tuple[float, int, int]:
    """(2·Δ log-likelihood summed over the stretches, its degrees of freedom, ordinates used); dof 0:
    no slow component, or stretches too short."""
    fast = [True] + [False] * (model.flicker_b > 0) + [False] * (model.rrw_k > 0) + [
        t < SLOW_SAMPLES * model.dt_s for _, t in model.gm]
    fast = np.asarray(fast)
    k_slow = int((~fast).sum())
    n = r.shape[0] // parts
    if k_slow == 0 or n < 64:
        return 0.0, 0, 0
    th = _theta(model)
    lr, m = 0.0, 0
    for q in range(parts):
        b = _bands(r[q * n:(q + 1) * n])
        G = _columns(model, b.omega)
        _, ll_free = _fit(G, b, th)
        _, ll_shared = _fit(G[:, fast], b, th[fast], offset=G[:, ~fast] @ th[~fast])
        lr += 2.0 * max(ll_free - ll_shared, 0.0)
        m += b.ordinates
    return lr, parts * k_slow, m


def _resolved(tau: float, lo_tau: float, hi_tau: float) -> bool:
    """Whether a Gauss-Markov correlation time lies inside the grid, not at one of its ends
    (:data:`GM_MIN_SAMPLES`, :data:`GM_RESOLVED`): at an end the likelihood would go on past it."""
    return 1.02 * lo_tau < tau < 0.99 * hi_tau


def _refine_gm(G: np.ndarray, b: _Bands, theta: np.ndarray, tau: float, dt: float, duration: float,
               th: np.ndarray, ll: float, lo_tau: float, hi_tau: float) -> tuple[float, np.ndarray, float, np.ndarray]:
    """The Gauss-Markov correlation time refined between the grid neighbours (golden section on
    log τ of the profiled likelihood, within [``lo_tau``, ``hi_tau``])."""
    from scipy.optimize import minimize_scalar

    step = math.log(10.0) / GM_PER_DECADE
    lo = max(math.log(tau) - step, math.log(lo_tau))
    hi = max(min(math.log(tau) + step, math.log(hi_tau)), lo)

    def neg(x: float) -> float:
        col = _basis("gm", b.omega, dt, duration, math.exp(x))
        return -_fit(np.column_stack([G, col]), b, np.concatenate([theta, [th[-1]]]))[1]

    res = minimize_scalar(neg, bounds=(lo, hi), method="bounded", options={"xatol": 0.02})
    if -res.fun > ll:
        tau = math.exp(res.x)
        col = _basis("gm", b.omega, dt, duration, tau)
        th, ll = _fit(np.column_stack([G, col]), b, np.concatenate([theta, [th[-1]]]))
    else:
        col = _basis("gm", b.omega, dt, duration, tau)
    return tau, th, ll, col


# ---- whitening ------------------------------------------------------------------------------------
GAP_FACTOR = 1.5
"""A time step longer than this many median steps starts a new segment of the filter."""
TRANSIENT_TOL = 1e-3
"""The start-up scaling runs until the innovation variance is within this share of its steady state."""
TRANSIENT_MAX = 20_000
"""... and for at most this many samples."""


class Whitener:
    """Prewhitening by the steady-state innovations filter of a :class:`NoiseModel` (module docstring).
    ``apply(x, t)`` whitens (n,) or (n, q) arrays sampled at times ``t``."""

    def __init__(self, model: NoiseModel):
        from scipy.linalg import solve_discrete_are
        from scipy.signal import zpk2sos

        self.model = model
        phi, q = model.states()
        s = phi.size
        F = np.diag(phi)
        H = np.ones((1, s))
        Q = np.diag(q)
        R = np.array([[model.white_var]])
        P = solve_discrete_are(F.T, H.T, Q, R)
        S = float((H @ P @ H.T + R)[0, 0])
        K = (P @ H.T) / S
        A = F @ (np.eye(s) - K @ H)
        poles = np.linalg.eigvals(A)
        self.sos = zpk2sos(phi, poles, 1.0)
        self.innovation_var = S
        self.scale = self._transient(F, H, Q, R, P, S, phi, q)

    @staticmethod
    def _transient(F, H, Q, R, P_inf, S_inf, phi, q) -> np.ndarray:
        """√(S_∞/S_t) for the first samples of a segment: the Riccati recursion from the stationary
        covariance (a random walk's start: its variance over the record length)."""
        p0 = np.where(phi < 1.0, q / np.maximum(1.0 - phi * phi, 1e-300), 0.0)
        if np.any(phi >= 1.0):
            p0 = np.where(phi >= 1.0, q * TRANSIENT_MAX, p0)
        P = np.diag(p0)
        out = []
        for _ in range(TRANSIENT_MAX):
            S = float((H @ P @ H.T + R)[0, 0])
            out.append(math.sqrt(S_inf / S))
            if abs(S - S_inf) <= TRANSIENT_TOL * S_inf:
                break
            K = (P @ H.T) / S
            P = F @ (P - K @ H @ P) @ F.T + Q
        return np.asarray(out)

    def exact_loglik(self, r: np.ndarray, t: np.ndarray) -> float:
        """Exact Gaussian log-likelihood of the series ``r`` under the model, from its innovations
        (prediction error decomposition: −½ Σ ln(2π S_t) + e_t²/S_t, S_t the time-varying innovation
        variance of each segment's start, :meth:`_transient`)."""
        w = self.apply(np.asarray(r, dtype=float) - float(np.mean(r)), t)
        S = self.innovation_var
        log_s = 0.0
        for lo, hi in segments(t):
            k = min(self.scale.size, hi - lo)
            log_s += (hi - lo) * math.log(S) - 2.0 * float(np.sum(np.log(self.scale[:k])))
        return -0.5 * (w.size * math.log(2.0 * math.pi) + log_s + float(np.dot(w, w)) / S)

    def apply(self, x: np.ndarray, t: np.ndarray) -> np.ndarray:
        """``x`` (n,) or (n, q) whitened along its rows, segment by segment (gaps in ``t``)."""
        from scipy.signal import sosfilt

        x = np.asarray(x, dtype=float)
        flat = x.ndim == 1
        z = x[:, None] if flat else x
        out = np.empty_like(z)
        for lo, hi in segments(t):
            seg = sosfilt(self.sos, z[lo:hi], axis=0)
            k = min(self.scale.size, hi - lo)
            seg[:k] *= self.scale[:k, None]
            out[lo:hi] = seg
        return out[:, 0] if flat else out


def segments(t: np.ndarray) -> list[tuple[int, int]]:
    """[lo, hi) row ranges of ``t`` without a gap (a step > GAP_FACTOR × the median step)."""
    if t.shape[0] < 2:
        return [(0, t.shape[0])]
    d = np.diff(t)
    cut = np.flatnonzero(d > GAP_FACTOR * float(np.median(d))) + 1
    edges = np.concatenate([[0], cut, [t.shape[0]]])
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]
