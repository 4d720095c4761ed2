"""Study (not a timed benchmark): white noise beside a Gauss-Markov process of τ_c ≈ one sample.

For τ_c/Δ in {0.5, 1, 1.5, 2, 3} and σ_gm/σ_white in {0.3, 1, 3} (σ_white 0.01 deg/s), ``--seeds``
seeds each, at n samples (3600: an hour at 1 Hz; 36000: an hour at 10 Hz), prints what
:func:`bench.analysis.noise_model.fit_noise_model` returns: the white part (σ per sample), the
Gauss-Markov terms (σ, τ_c), how often the white part collapsed (below a tenth of the truth), the
model's total low-frequency level (the ARW an Allan curve reads past a few τ_c) against the truth,
and what the Whittle Fisher information says about the white variance: the Cramér-Rao bound of
ln w with (w, σ², τ_c) all free (``crlb``), and the share of seeds whose profile likelihood cannot
reject "no white part" at 5 % (``unid``). docs/diagnose.md 6b quotes the table.

    python benchmarks/study_white_vs_gm.py --n 3600 --seeds 5
    python benchmarks/study_white_vs_gm.py --n 3600 --seeds 20 --taus 1 1.5 --ratios 1 2 3
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from scipy.signal import lfilter

from bench.analysis.noise_model import fit_noise_model

try:
    from bench.analysis.noise_model import white_profile
except ImportError:  # the code before the white part's profile (e63e8cd), for the "before" table
    white_profile = None

SIGMA_WHITE = 0.01


def gauss_markov(rng: np.random.Generator, n: int, sigma: float, tau: float) -> np.ndarray:
    """First-order Gauss-Markov samples (Δ = 1), stationary start (a plain AR(1) recursion)."""
    a = math.exp(-1.0 / tau)
    e = rng.standard_normal(n) * sigma * math.sqrt(1.0 - a * a)
    e[0] = rng.standard_normal() * sigma
    return lfilter([1.0], [1.0, -a], e)


def crlb_ln_white(n: int, w: float, v: float, tau: float) -> float:
    """√(I⁻¹)_ww of the Whittle Fisher information in (ln w, ln v, ln τ_c) at the truth: the
    relative standard error of the white variance an efficient estimator could reach."""
    om = 2.0 * np.pi * np.arange(1, (n - 1) // 2 + 1) / n
    c = np.cos(om)

    def log_s(x: np.ndarray) -> np.ndarray:
        f = math.exp(-math.exp(-x[2]))
        return np.log(math.exp(x[0]) + math.exp(x[1]) * (1 - f * f) / (1 - 2 * f * c + f * f))

    x0 = np.log([w, v, tau])
    d = np.array([(log_s(x0 + h) - log_s(x0 - h)) / 2e-5 for h in np.eye(3) * 1e-5])
    return math.sqrt(np.linalg.inv(d @ d.T)[0, 0])


def total_level(w: float, gm: list[tuple[float, float]]) -> float:
    """√S(0): the white-equivalent σ per sample of white + Gauss-Markov terms at low frequency."""
    return math.sqrt(w + sum(s * s * (1 + math.exp(-1 / t)) / (1 - math.exp(-1 / t)) for s, t in gm))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=3600)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--taus", type=float, nargs="+", default=[0.5, 1.0, 1.5, 2.0, 3.0], help="τ_c/Δ")
    ap.add_argument("--ratios", type=float, nargs="+", default=[0.3, 1.0, 3.0], help="σ_gm/σ_white")
    a = ap.parse_args()
    w = SIGMA_WHITE
    print(f"n = {a.n}, σ_white {w} deg/s per sample, {a.seeds} seeds; white/GM σ per sample, τ_c in samples")
    print("τc/Δ σgm/σw  crlb  unid  collapsed  white σ (min-max)   GM σ (min-max)      τc (min-max)  total/true (min-max)")
    for tau in a.taus:
        for ratio in a.ratios:
            sg = ratio * w
            whites, sig, taus, tot, unid = [], [], [], [], 0
            for s in range(a.seeds):
                rng = np.random.default_rng([s, 32, int(10 * tau), int(10 * ratio), a.n])
                r = rng.standard_normal(a.n) * w + gauss_markov(rng, a.n, sg, tau)
                m = fit_noise_model(r, 1.0)
                whites.append(math.sqrt(m.white_var))
                if m.gm:
                    sig.append(m.gm[0][0])
                    taus.append(m.gm[0][1])
                    unid += white_profile is not None and not white_profile(r, m).identified
                tot.append(total_level(m.white_var, m.gm) / total_level(w * w, [(sg, tau)]))
            rng_ = (lambda x: f"{min(x):.4f}-{max(x):.4f}" if x else "-")
            print(f"{tau:4.1f} {ratio:5.1f} {crlb_ln_white(a.n, w * w, sg * sg, tau):6.2f} {unid:3d}/{len(sig):<2d}"
                  f" {sum(x < 0.1 * w for x in whites):4d}/{a.seeds}   {rng_(whites):17s} "
                  f"{rng_(sig) + f' ({len(sig)})':20s} {(f'{min(taus):.2f}-{max(taus):.2f}' if taus else '-'):12s}"
                  f" {min(tot):.2f}-{max(tot):.2f}", flush=True)


if __name__ == "__main__":
    main()
