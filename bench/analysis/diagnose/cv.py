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


def fold_grams(A: np.ndarray, blocks: Blocks) -> tuple[np.ndarray, np.ndarray]:
    """(whole-data Gram (m+1, m+1), per-fold Grams (K, m+1, m+1)) of block Grams ``A``: what every
    fit of ``A`` needs whatever the penalty (a grid of smoothness reuses them, :func:`cv_fit`)."""
    K = blocks.folds
    onehot = np.zeros((K, A.shape[0]))
    onehot[blocks.fold_of, np.arange(A.shape[0])] = 1.0
    per_fold = (onehot @ A.reshape(A.shape[0], -1)).reshape(K, *A.shape[1:])
    return A.sum(axis=0), per_fold


def cv_fit(A: np.ndarray, P: np.ndarray | None, blocks: Blocks, need_df: bool = True,
           S: np.ndarray | None = None, gls: bool = False,
           folded: tuple[np.ndarray, np.ndarray] | None = None) -> CVFit:
    """Fit by blocked CV. ``A`` (B, m+1, m+1) augmented block Grams, ``P`` (m, m) penalty or None,
    ``S`` (B, m+1) block sums of [X | y] for the held-out residual's block sums (default: row 0 of
    ``A``, the sums when column 0 is the constant 1; a prewhitened design passes its own).

    ``gls``: the rows are prewhitened by a correlated noise model. Held-out blocks would then leak
    (a whitened row depends on the rows before it, in other folds), so the per-block errors and sums
    are those of the whole-data fit (the generalised least-squares likelihood), and ``df`` is always
    computed (the criterion charges it). ``folded``: :func:`fold_grams` of ``A`` when already
    computed (the same Grams under another penalty)."""
    m = A.shape[1] - 1
    fold = blocks.fold_of
    K = blocks.folds
    tot, per_fold = fold_grams(A, blocks) if folded is None else folded
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
    sse_block = _quad(A, vb)
    if S is not None:
        sum_block = -np.einsum("bj,bj->b", S, vb)
    else:
        sum_block = -np.einsum("bj,bj->b", A[:, 0, :], vb) if m else np.zeros(A.shape[0])
    sse_train = _quad(train, v)
    vf = np.concatenate([beta, [-1.0]])
    sse_full = float(vf @ tot @ vf)
    df = float(m)
    if (need_df or gls) and P is not None:
        df = float(np.trace(_solve(Gf[None], tot[None, :m, :m])[0]))
    if gls:
        sse_block = _quad(A, np.broadcast_to(vf, (A.shape[0], vf.size)))
        sum_block = -(S if S is not None else A[:, 0, :]) @ vf
    return CVFit(np.maximum(sse_block, 0.0), np.maximum(sse_train, 0.0), beta, df, max(sse_full, 0.0), beta_k, sum_block)


def _quad(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """vᵦᵀ A_b vᵦ for stacked matrices ``A`` (B, m, m) and vectors ``v`` (B, m) (batched products:
    a three-operand einsum does not use BLAS)."""
    return np.sum(np.matmul(A, v[:, :, None])[:, :, 0] * v, axis=1)


def _solve(G: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Solve the stacked systems G[k] x = h[k]; ``h`` (K, m) or (K, m, r)."""
    vec = h.ndim == G.ndim - 1
    rhs = h[..., None] if vec else h
    try:
        x = np.linalg.solve(G, rhs)
    except np.linalg.LinAlgError:
        x = np.stack([np.linalg.lstsq(g, r, rcond=None)[0] for g, r in zip(G, rhs)])
    return x[..., 0] if vec else x


class SparseHat:
    """Linear-spline (hat) columns without the dense (n, k) matrix: row i has value a_i in column
    j_i and b_i in column j_i + 1. Used for the random-walk spline's candidate evaluation."""

    def __init__(self, j: np.ndarray, a: np.ndarray, b: np.ndarray, k: int):
        self.j, self.a, self.b, self.k = j, a, b, int(k)
        self.shape = (int(j.shape[0]), self.k)

    def col_rms(self) -> np.ndarray:
        n = self.shape[0]
        sq = np.bincount(self.j, self.a ** 2, minlength=self.k + 1)[: self.k + 1]
        sq = sq + np.concatenate([[0.0], np.bincount(self.j, self.b ** 2, minlength=self.k)[: self.k]])
        return np.sqrt(sq[: self.k] / n)

    def scaled(self, s: np.ndarray) -> "SparseHat":
        return SparseHat(self.j, self.a / s[self.j], self.b / s[self.j + 1], self.k)

    def dense(self) -> np.ndarray:
        out = np.zeros(self.shape)
        rows = np.arange(self.shape[0])
        out[rows, self.j] = self.a
        out[rows, self.j + 1] += self.b
        return out

    def block_products(self, blocks: Blocks, V: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-block Zᵀ V (B, k, c) and ZᵀZ (B, k, k)."""
        B, k = blocks.count, self.k
        blk = np.arange(self.shape[0]) // blocks.length
        i0 = blk * (k + 1) + self.j
        i1 = i0 + 1
        size = B * (k + 1)
        V = V.reshape(self.shape[0], -1)
        zv = np.empty((B, k + 1, V.shape[1]))
        for c in range(V.shape[1]):
            col = np.bincount(i0, self.a * V[:, c], minlength=size) + np.bincount(i1, self.b * V[:, c], minlength=size)
            zv[:, :, c] = col.reshape(B, k + 1)
        d0 = np.bincount(i0, self.a ** 2, minlength=size) + np.bincount(i1, self.b ** 2, minlength=size)
        off = np.bincount(i0, self.a * self.b, minlength=size).reshape(B, k + 1)
        zz = np.zeros((B, k + 1, k + 1))
        idx = np.arange(k + 1)
        zz[:, idx, idx] = d0.reshape(B, k + 1)
        zz[:, idx[:-1], idx[1:]] = off[:, :-1]
        zz[:, idx[1:], idx[:-1]] = off[:, :-1]
        return zv[:, :k], zz[:, :k, :k]


def augment(A: np.ndarray, Xb: np.ndarray, yb: np.ndarray, blocks: Blocks, Z: np.ndarray | None = None,
            y_new: np.ndarray | None = None) -> np.ndarray:
    """Augmented block Grams of [X | Z | y_new] from those of [X | y] (``A``) without recomputing XᵀX.

    ``Xb`` (B, L, m) and ``yb`` (B, L, 1) are X and y in block layout (:meth:`Blocks.shaped`);
    ``Z`` (n, q) new columns or None; ``y_new`` a changed response (a fixed offset subtracted) or
    None to keep y."""
    m = Xb.shape[2]
    q = 0 if Z is None else Z.shape[1]
    B = A.shape[0]
    out = np.empty((B, m + q + 1, m + q + 1))
    out[:, :m, :m] = A[:, :m, :m]
    if y_new is None:
        ybn = yb
        out[:, :m, -1] = A[:, :m, m]
        out[:, -1, -1] = A[:, m, m]
    else:
        ybn = blocks.shaped(y_new)
        out[:, :m, -1] = np.matmul(Xb.transpose(0, 2, 1), ybn)[:, :, 0] if m else 0.0
        out[:, -1, -1] = np.einsum("bl,bl->b", ybn[:, :, 0], ybn[:, :, 0])
    out[:, -1, :m] = out[:, :m, -1]
    if q and isinstance(Z, SparseHat):
        X = Xb.reshape(-1, m)[: blocks.n] if m else np.zeros((blocks.n, 0))
        zv, zz = Z.block_products(blocks, np.column_stack([X, ybn.reshape(-1)[: blocks.n]]))
        out[:, m:m + q, :m] = zv[:, :, :m]
        out[:, :m, m:m + q] = zv[:, :, :m].transpose(0, 2, 1)
        out[:, m:m + q, m:m + q] = zz
        out[:, m:m + q, -1] = zv[:, :, m]
        out[:, -1, m:m + q] = zv[:, :, m]
    elif q:
        Zb = blocks.shaped(Z)
        Zt = Zb.transpose(0, 2, 1)
        zx = np.matmul(Zt, Xb)
        out[:, m:m + q, :m] = zx
        out[:, :m, m:m + q] = zx.transpose(0, 2, 1)
        out[:, m:m + q, m:m + q] = np.matmul(Zt, Zb)
        zy = np.matmul(Zt, ybn)[:, :, 0]
        out[:, m:m + q, -1] = zy
        out[:, -1, m:m + q] = zy
    return out


def block_sums(blocks: Blocks, z: np.ndarray) -> np.ndarray:
    """Per-block column sums (B, q) of ``z`` (n,) or (n, q)."""
    return blocks.shaped(z).sum(axis=1)


def full_gram(X: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Whole-data augmented Gram [X | y]ᵀ[X | y] (m+1, m+1)."""
    Xy = np.column_stack([X, y])
    return Xy.T @ Xy
