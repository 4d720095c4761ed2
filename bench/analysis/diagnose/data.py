"""The measured data as ``bench diagnose`` uses it: arrays, derived covariates, CV blocks.

Everything in lab units (s, deg/s, °C, Torr, g, deg). Columns with non-finite values are treated
as absent (a run file's monitor that recorded nothing interpolates to NaN); rows whose gyro value
is not finite are dropped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bench.analysis.dataset import ACCEL, AXES, GYRO, REF_RATE, Dataset
from bench.errors import InputError

MIN_ROWS = 200
"""Fewest rows diagnose accepts: below this no blocked cross-validation is meaningful."""
BLOCKS_TARGET = 200
"""Number of contiguous CV blocks aimed at (fewer for short data, each at least MIN_BLOCK_S)."""
MIN_BLOCK_S = 30.0
"""Shortest CV block (s): well above the correlation time of white noise, short against the
slowest transients modelled (warm-up, pressure, thermal), so held-out blocks have trained
neighbours on both sides."""
FOLDS = 5
"""Blocks are dealt to folds in turn (block b → fold b mod 5): every fold holds out one block in
five, spread over the whole session. Blocks carrying a rarely excited reference rate (a cross
axis that only turns during tilt moves) are dealt round-robin first (:meth:`Blocks.balance`)."""
RATE_EXCITED_DPS = 0.05
"""An axis whose reference rate RMS is below this (deg/s) has no rate-dependent terms fitted."""


@dataclass
class Blocks:
    """Contiguous blocks of ``length`` samples (the last may be shorter) dealt to ``folds`` folds:
    block b to fold b mod K, except blocks holding rare excitation (:meth:`balance`)."""

    n: int
    length: int
    folds: int = FOLDS
    assignment: np.ndarray | None = None

    @property
    def count(self) -> int:
        return int(math.ceil(self.n / self.length))

    @property
    def fold_of(self) -> np.ndarray:
        """Fold index of each block (B,)."""
        if self.assignment is not None:
            return self.assignment
        return np.arange(self.count) % self.folds

    def row_fold(self) -> np.ndarray:
        """Fold index of each row (n,)."""
        return self.fold_of[np.arange(self.n) // self.length]

    def balance(self, columns: np.ndarray, share: float = 0.5) -> None:
        """Deal the blocks that carry a rarely excited column round-robin over the folds.

        For each column (n, k), the fewest blocks holding ``share`` of its energy are, when they are
        fewer than 4 per fold, dealt to folds in turn (largest first), so that no fold's training
        set misses all of a column's excitation (e.g. the few tilt moves that give a cross axis its
        only rate); the other blocks keep b mod K."""
        fold = np.arange(self.count) % self.folds
        fixed = np.zeros(self.count, bool)
        nxt = 0
        cols = columns.reshape(self.n, -1)
        for k in range(cols.shape[1]):
            e = (self.shaped(cols[:, k] ** 2)).sum(axis=(1, 2))
            total = float(e.sum())
            if total <= 0:
                continue
            order = np.argsort(e)[::-1]
            m = int(np.searchsorted(np.cumsum(e[order]), share * total)) + 1
            if m >= 4 * self.folds:
                continue
            for b in order[:m]:
                if not fixed[b]:
                    fold[b] = nxt % self.folds
                    fixed[b] = True
                    nxt += 1
        self.assignment = fold

    def shaped(self, z: np.ndarray) -> np.ndarray:
        """``z`` (n,) or (n, c) zero-padded and reshaped to (B, L, c)."""
        z = z.reshape(self.n, -1)
        pad = self.count * self.length - self.n
        if pad:
            z = np.concatenate([z, np.zeros((pad, z.shape[1]))])
        return z.reshape(self.count, self.length, -1)

    def gram(self, a: np.ndarray, b: np.ndarray | None = None) -> np.ndarray:
        """Per-block cross-products aᵀb, (B, ca, cb)."""
        sa = self.shaped(a)
        sb = sa if b is None else self.shaped(b)
        return np.matmul(sa.transpose(0, 2, 1), sb)


@dataclass
class Prepared:
    """Arrays of one dataset ready for the fits (``None`` = column absent or unusable)."""

    source: str
    t: np.ndarray
    fs: float
    axes: list[str]
    gyro: dict[str, np.ndarray]
    ref: np.ndarray | None
    temp: np.ndarray | None
    pressure: np.ndarray | None
    power_on: np.ndarray | None
    accel: np.ndarray | None
    angle: np.ndarray | None
    latitude: float | None
    blocks: Blocks
    table_axis: str | None = None
    """Sensor axis on the table's rotation axis with its sign (``"z"``, ``"-x"``), None if no rotation."""
    present: set[str] = field(default_factory=set)
    cache: dict = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(self.t.shape[0])

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0]) + 1.0 / self.fs

    def ref_axis(self, a: str) -> np.ndarray:
        """Reference rate about sensor axis ``a`` (deg/s), zeros without reference columns."""
        return np.zeros(self.n) if self.ref is None else self.ref[:, AXES.index(a)]

    def rate_excited(self, a: str) -> bool:
        """Whether axis ``a`` sees enough reference rate for rate-dependent terms."""
        r = self.ref_axis(a)
        return bool(np.sqrt(np.mean(r * r)) >= RATE_EXCITED_DPS)

    def dtemp(self) -> np.ndarray | None:
        """dT/dt (°C/s), smoothed over ~60 s."""
        if self.temp is None:
            return None
        key = ("dtemp",)
        if key not in self.cache:
            w = max(int(round(60 * self.fs)), 1)
            k = np.ones(w) / w
            sm = np.convolve(np.pad(self.temp, (w // 2, w - 1 - w // 2), mode="edge"), k, mode="valid")
            self.cache[key] = np.gradient(sm, self.t)
        return self.cache[key]


def prepare(ds: Dataset) -> Prepared:
    """Check ``ds`` and extract the arrays; :class:`InputError` when diagnose cannot run on it."""
    if "time_s" not in ds.columns:
        raise InputError(f"{ds.source}: diagnose needs a time_s column")
    axes = [a for a in AXES if GYRO[a] in ds.columns]
    if not axes:
        raise InputError(f"{ds.source}: diagnose needs at least one gyro column (gyro_x_dps, gyro_y_dps, gyro_z_dps)")
    t = np.asarray(ds.columns["time_s"], dtype=float)
    ok = np.isfinite(t)
    for a in axes:
        ok &= np.isfinite(np.asarray(ds.columns[GYRO[a]], dtype=float))
    if int(ok.sum()) < MIN_ROWS:
        raise InputError(f"{ds.source}: diagnose needs at least {MIN_ROWS} rows with finite time and gyro values, "
                         f"got {int(ok.sum())}")
    t = t[ok]
    if np.any(np.diff(t) <= 0):
        raise InputError(f"{ds.source}: time_s must increase from row to row")

    def col(name: str) -> np.ndarray | None:
        if name not in ds.columns:
            return None
        v = np.asarray(ds.columns[name], dtype=float)[ok]
        return v if np.all(np.isfinite(v)) else None

    present: set[str] = set()
    for name in ds.columns:
        if col(name) is not None:
            present.add(name)
    dt = np.diff(t)
    fs = 1.0 / float(np.median(dt))
    gyro = {a: col(GYRO[a]) for a in axes}
    refs = [col(REF_RATE[a]) for a in AXES]
    ref = np.stack([r if r is not None else np.zeros(t.size) for r in refs], axis=1) if any(r is not None for r in refs) else None
    if ref is not None:
        for a, r in zip(AXES, refs):
            if r is None:
                present.discard(REF_RATE[a])
    acc = [col(ACCEL[a]) for a in AXES]
    accel = np.stack(acc, axis=1) if all(x is not None for x in acc) else None
    temp = col("temp_c")
    pressure = col("pressure_torr")
    if pressure is not None and np.any(pressure <= 0):
        pressure = np.clip(pressure, 1e-12, None)
    n = t.size
    length = max(int(round(MIN_BLOCK_S * fs)), int(math.ceil(n / BLOCKS_TARGET)), 1)
    if n / length < 4 * FOLDS:
        length = max(n // (4 * FOLDS), 1)
    prep = Prepared(source=ds.source, t=t, fs=fs, axes=axes, gyro=gyro, ref=ref, temp=temp, pressure=pressure,
                    power_on=col("power_on_s"), accel=accel, angle=col("table_angle_deg"),
                    latitude=ds.latitude_deg(), blocks=Blocks(n, length), present=present)
    prep.table_axis = _table_axis(prep)
    if ref is not None:
        prep.blocks.balance(ref)
    return prep


def _table_axis(p: Prepared) -> str | None:
    """The sensor axis carrying the table rate, signed by the table angle's direction."""
    if p.ref is None:
        return None
    rms = np.sqrt(np.mean(p.ref ** 2, axis=0))
    k = int(np.argmax(rms))
    if rms[k] < RATE_EXCITED_DPS:
        return None
    sign = ""
    if p.angle is not None:
        dtheta = np.gradient(np.degrees(np.unwrap(np.radians(p.angle))), p.t)
        if float(np.dot(dtheta, p.ref[:, k])) < 0:
            sign = "-"
    return sign + AXES[k]
