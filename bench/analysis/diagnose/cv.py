"""Blocked cross-validation of (penalised) linear least squares from per-block sufficient statistics.

A design [X | y] is reduced once to per-block augmented Gram matrices A_b = [X_b y_b]ᵀ[X_b y_b]
(B, m+1, m+1). Every fold's training fit is then a solve of the summed Grams of the other folds
(plus the penalty), and every held-out block's squared error is vᵀA_b v with v = [β; −1]: no pass
over the rows after the Grams. Adding candidate columns only needs their cross-products with the
current design (:func:`augment`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.analysis.diagnose.data import Blocks

RIDGE = 1e-10
"""Relative ridge on the normal equations (× largest diagonal element): keeps collinear or
unexcited columns (e.g. a constant next to a random-walk spline) solvable without changing fits."""


@dataclass
class CVFit:
    """Result of one blocked CV: held-out SSE per block, training SSE per fold (unpenalised),
    full-data coefficients, effective parameter count and full-data SSE."""

    sse_block: np.ndarray
    sse_train: np.ndarray
    beta: np.ndarray
    df: float
    sse_full: float
    beta_folds: np.ndarray
    """(K, m) coefficients of each fold's training fit."""
    sum_block: np.ndarray
    """(B,) held-out residual summed over each block (column 0 of the design must be the constant 1)."""

    @property
    def sse(self) -> float:
        return float(self.sse_block.sum())


def cv_fit(A: np.ndarray, P: np.ndarray | None, blocks: Blocks, need_df: bool = True) -> CVFit:
    """Fit by blocked CV. ``A`` (B, m+1, m+1) augmented block Grams, ``P`` (m, m) penalty or None."""
    m = A.shape[1] - 1
    fold = blocks.fold_of
    K = blocks.folds
    tot = A.sum(axis=0)
    per_fold = np.stack([A[fold == k].sum(axis=0) for k in range(K)])
    train = tot[None] - per_fold
    G = train[:, :m, :m].copy()
    h = train[:, :m, m]
    Gf = tot[:m, :m].copy()
    if P is not None:
        G += P[None]
        Gf += P
    eps = RIDGE * max(float(np.max(np.diagonal(Gf))), 1e-30)
    idx = np.arange(m)
    G[:, idx, idx] += eps
    Gf[idx, idx] += eps
    beta_k = _solve(G, h)
    beta = _solve(Gf[None], tot[None, :m, m])[0]
    v = np.concatenate([beta_k, -np.ones((K, 1))], axis=1)
    vb = v[fold]
    sse_block = np.einsum("bi,bij,bj->b", vb, A, vb)
    sum_block = -np.einsum("bj,bj->b", A[:, 0, :], vb) if m else np.zeros(A.shape[0])
    sse_train = np.einsum("ki,kij,kj->k", v, train, v)
    vf = np.concatenate([beta, [-1.0]])
    sse_full = float(vf @ tot @ vf)
    df = float(m)
    if need_df and P is not None:
        df = float(np.trace(_solve(Gf[None], tot[None, :m, :m])[0]))
    return CVFit(np.maximum(sse_block, 0.0), np.maximum(sse_train, 0.0), beta, df, max(sse_full, 0.0), beta_k, sum_block)


def _solve(G: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Solve the stacked systems G[k] x = h[k]; ``h`` (K, m) or (K, m, r)."""
    vec = h.ndim == G.ndim - 1
    rhs = h[..., None] if vec else h
    try:
        x = np.linalg.solve(G, rhs)
    except np.linalg.LinAlgError:
        x = np.stack([np.linalg.lstsq(g, r, rcond=None)[0] for g, r in zip(G, rhs)])
    return x[..., 0] if vec else x


def augment(A: np.ndarray, X: np.ndarray, y: np.ndarray, blocks: Blocks, Z: np.ndarray | None = None,
            y_new: np.ndarray | None = None) -> np.ndarray:
    """Augmented block Grams of [X | Z | y_new] from those of [X | y] (``A``) without recomputing XᵀX.

    ``Z`` (n, q) new columns or None; ``y_new`` a changed response (a fixed offset subtracted) or
    None to keep ``y``."""
    m = X.shape[1]
    q = 0 if Z is None else Z.shape[1]
    B = A.shape[0]
    out = np.empty((B, m + q + 1, m + q + 1))
    out[:, :m, :m] = A[:, :m, :m]
    yy = y if y_new is None else y_new
    if y_new is None:
        out[:, :m, -1] = A[:, :m, m]
        out[:, -1, -1] = A[:, m, m]
    else:
        xy = blocks.gram(X, yy[:, None])[:, :, 0] if m else np.zeros((B, 0))
        out[:, :m, -1] = xy
        out[:, -1, -1] = blocks.gram(yy[:, None])[:, 0, 0]
    out[:, -1, :m] = out[:, :m, -1]
    if q:
        zr = blocks.gram(Z, np.column_stack([X, Z, yy]))  # (B, q, m+q+1)
        out[:, m:m + q, :] = zr
        out[:, :, m:m + q] = zr.transpose(0, 2, 1)
    return out


def full_gram(X: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Whole-data augmented Gram [X | y]ᵀ[X | y] (m+1, m+1)."""
    Xy = np.column_stack([X, y])
    return Xy.T @ Xy
