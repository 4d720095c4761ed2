"""The measured data as ``bench diagnose`` uses it: arrays, derived covariates, CV blocks.

Everything in lab units (s, deg/s, °C, Torr, g, deg). Columns with non-finite values are treated
as absent (a run file's monitor that recorded nothing interpolates to NaN); rows whose gyro value
is not finite are dropped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bench.analysis.dataset import ACCEL, AXES, GYRO, REF_RATE, Dataset, constant_columns, constant_text, refuse_nothing_to_fit
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
BIN_MIN_ROWS = 100_000
"""Data with more rows than this are analysed as means of consecutive rows (:func:`bin_length`)."""
BIN_MAX_S = 1.0
"""Longest bin (s): the slowest-sampled sessions diagnose is validated on are 1 Hz, and every
vocabulary term but the fast ones named in :func:`bin_length` varies over tens of seconds or more."""
BIN_MAX_STATIC_S = 5.0
"""Longest bin for static data (no reference rate): nothing in the vocabulary is faster than the
warm-up grid's shortest τ (10 s) there but a spectral line, which the line check keeps. A 74-h
static log at 1 Hz becomes 53,600 five-second means."""
BIN_PER_PERIOD = 4
"""A periodic signal the vocabulary can see (a gear harmonic, a spectral line) keeps at least this
many bins per period: its bin means keep ≥ 90 % of its amplitude (sinc(1/4))."""
MOTION_SIGMA = 12.0
"""Static data (no reference rate): a row whose gyro is this many robust standard deviations
(1.4826·MAD) off its running median on any axis, or whose specific force magnitude is more than
:data:`MOTION_G` off its running median, is the unit being moved (handling between orientations)."""
MOTION_G = 0.1
MOTION_PAD_S = 60.0
"""Rows this close to a moving row are left out with it (the unit settling)."""
MOTION_MAX_SHARE = 0.2
"""More moving rows than this share: the data are not a static test; nothing is left out."""
LINE_FRACTION = 0.02
"""A spectral line above the bins' reach that carries this share of the gyro variance (1 % of its
RMS, the materiality of ``engine.GAIN_MIN``) shortens the bins so that it is kept."""


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
    bin_rows: int = 1
    """Rows averaged into each analysed row (1: the rows as recorded; see :func:`bin_length`)."""
    raw_rows: int = 0
    """Rows of the data before binning (with finite time and gyro values)."""
    raw_fs: float = float("nan")
    """Sample rate of the data before binning (Hz)."""
    bin_reason: str = ""
    """What limited the bin length (empty when not binned or at :data:`BIN_MAX_S`)."""
    motion: tuple[int, int] = (0, 0)
    """(rows, stretches) left out because the unit was being moved (:func:`motion_rows`)."""
    left_out: list[str] = field(default_factory=list)
    """Gyro columns left out because they hold one value (``"gyro_x_dps is constant (0 in all 400 rows)"``)."""
    whiten: dict = field(default_factory=dict)
    """axis -> :class:`bench.analysis.noise_model.Whitener`: the fits on that axis are generalised least
    squares against the axis' noise model (response and every design column prewhitened); empty:
    ordinary least squares (white noise)."""
    power_on_note: str = ""
    """How ``power_on_s`` was obtained when the data had none (``--power-on-at``), else empty."""
    lines: list = field(default_factory=list)
    """Coherent spectral lines above the bins' reach, fitted on the raw samples and removed before
    binning (:func:`fast_lines`): each is a ``periodic`` finding."""

    def w(self, axis: str, z):
        """``z`` (n,) or (n, q) columns (a sparse hat basis made dense) prewhitened by the axis' noise
        model, unchanged without one; None stays None."""
        wh = self.whiten.get(axis)
        if wh is None or z is None:
            return z
        if hasattr(z, "dense"):
            z = z.dense()
        return wh.apply(z, self.t)

    @property
    def n(self) -> int:
        return int(self.t.shape[0])

    def rows_line(self) -> str:
        """What was analysed, e.g. "analysed 13,190 bin means of 100 rows (1 s) from 1,319,000 samples
        at 100 Hz; RMS figures are those of the bin means"."""
        moved = ""
        if self.motion[0]:
            moved = (f"; left out {self.motion[0]:,} rows in {self.motion[1]} stretch(es) where the unit was moved "
                     f"(gyro > {MOTION_SIGMA:g} robust σ off its running median or |specific force| off by > "
                     f"{MOTION_G:g} g, ±{MOTION_PAD_S:g} s)")
        if self.left_out:
            moved += "; left out " + "; ".join(self.left_out)
        if self.power_on_note:
            moved += "; " + self.power_on_note
        if self.bin_rows <= 1:
            return f"analysed {self.n:,} rows at {self.fs:.4g} Hz" + moved
        why = f", {self.bin_reason}" if self.bin_reason else ""
        return (f"analysed {self.n:,} bin means of {self.bin_rows} rows ({self.bin_rows / self.raw_fs:.3g} s{why}) "
                f"from {self.raw_rows:,} samples at {self.raw_fs:.4g} Hz; RMS figures are those of the bin means" + moved)

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


POWER_ON_META = "power_on_at_s"
"""Metadata key (CSV ``# power_on_at_s: 12.5``) giving the power-on time of a log without a
``power_on_s`` column, like ``--power-on-at``."""


def power_on_column(ds: Dataset, power_on_at: float | None) -> tuple[np.ndarray | None, str]:
    """Time since power-on (s) for every row and how it was obtained.

    The ``power_on_s`` column when the data have one (``power_on_at`` is then refused: two answers
    to one question); else ``time_s − power_on_at`` from the option or the :data:`POWER_ON_META`
    metadata; else None (the default: the warm-up is not searched, and ``skipped`` says how to
    give the power-on time). The power-on may not be after the first row (rows before it are no
    sensor output)."""
    meta = ds.meta.get(POWER_ON_META)
    if "power_on_s" in ds.columns:
        if power_on_at is not None:
            raise InputError(f"{ds.source}: the data have a power_on_s column; --power-on-at is for logs without one")
        return np.asarray(ds.columns["power_on_s"], dtype=float), ""
    how = "--power-on-at"
    if power_on_at is None and meta is not None:
        if not isinstance(meta, float):
            raise InputError(f"{ds.source}: metadata {POWER_ON_META} must be a number of seconds, got {meta!r}")
        power_on_at, how = float(meta), f"metadata {POWER_ON_META}"
    if power_on_at is None:
        return None, ""
    if not math.isfinite(power_on_at):
        raise InputError(f"{ds.source}: {how} must be a finite time in s, got {power_on_at!r}")
    t = np.asarray(ds.columns["time_s"], dtype=float)
    first = float(np.nanmin(t)) if t.size else 0.0
    if power_on_at > first + 1e-9:
        raise InputError(f"{ds.source}: {how} {power_on_at:g} s is after the first row (time_s {first:g} s): rows "
                         "before the power-on are no sensor output; give a time at or before the first row")
    return t - power_on_at, f"power-on at t = {power_on_at:g} s ({how})"


def prepare(ds: Dataset, power_on_at: float | None = None, fit_lines: bool = True) -> Prepared:
    """Check ``ds`` and extract the arrays; :class:`InputError` when diagnose cannot run on it.
    More than :data:`BIN_MIN_ROWS` rows are averaged into bins (:func:`bin_length`).
    ``power_on_at``: the power-on time of a log without ``power_on_s`` (:func:`power_on_column`);
    ``fit_lines``: coherent spectral lines above the bins' reach are fitted and removed before binning
    (:func:`fast_lines`; False when ``periodic`` is hidden: the bins then average them out)."""
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
    every = bool(ok.all())
    usable = ds if every else ds.select(ok)
    refuse_nothing_to_fit(usable, [GYRO[a] for a in axes], "diagnose needs a gyro output that varies")
    dead = constant_columns(usable, [GYRO[a] for a in axes])
    axes = [a for a in axes if GYRO[a] not in dead]
    t = t if every else t[ok]
    if np.any(np.diff(t) <= 0):
        raise InputError(f"{ds.source}: time_s must increase from row to row")

    power_on, power_note = power_on_column(ds, power_on_at)
    raw: dict[str, np.ndarray] = {}
    for name in ds.columns:
        v = np.asarray(ds.columns[name], dtype=float)
        v = v if every else v[ok]
        if v.ndim == 1 and np.all(np.isfinite(v)):
            raw[name] = v
    if power_on is not None and "power_on_s" not in raw:
        raw["power_on_s"] = power_on if every else power_on[ok]
    present = set(raw)
    raw_fs = 1.0 / float(np.median(np.diff(t)))
    motion = (0, 0)
    if not any(REF_RATE[a] in raw for a in AXES):
        moving = motion_rows(t, [raw[GYRO[a]] for a in axes],
                             [raw[ACCEL[a]] for a in AXES] if all(ACCEL[a] in raw for a in AXES) else None, raw_fs)
        if moving.any() and moving.mean() <= MOTION_MAX_SHARE and (~moving).sum() >= MIN_ROWS:
            starts = int(np.count_nonzero(np.diff(moving.astype(np.int8)) == 1) + moving[0])
            motion = (int(moving.sum()), starts)
            keep = ~moving
            t = t[keep]
            raw = {k_: v[keep] for k_, v in raw.items()}
    raw_rows = t.size
    k, why = 1, ""
    lines: list[Line] = []
    if t.size > BIN_MIN_ROWS:
        refs_raw = [raw[REF_RATE[a]] for a in AXES if REF_RATE[a] in raw]
        k, why = bin_length(t.size, raw_fs, {}, refs_raw)
        span = k / raw_fs if k > 1 else 1.0 / raw_fs
        for a in axes:  # lines above the bins' reach: fitted on the raw samples (coherent ones removed)
            resp = raw[GYRO[a]] - raw.get(REF_RATE[a], 0.0)
            found = fast_lines(t, resp, raw_fs, 1.0 / (BIN_PER_PERIOD * span)) if fit_lines else []
            for ln in found:
                ln.axis = a
                raw[GYRO[a]] = raw[GYRO[a]] - ln.values(t)
            lines += found
        if lines:
            why = (why + "; " if why else "") + "; ".join(ln.text() for ln in lines)
    if k > 1:
        t, raw = _bin_means(t, raw, k, raw_fs)

    def col(name: str) -> np.ndarray | None:
        return raw.get(name)

    fs = raw_fs / k if k > 1 else raw_fs
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
                    latitude=ds.latitude_deg(), blocks=Blocks(n, length), present=present,
                    bin_rows=k, raw_rows=raw_rows, raw_fs=raw_fs, bin_reason=why, motion=motion,
                    left_out=[constant_text(usable, c) for c in dead], power_on_note=power_note, lines=lines)
    prep.table_axis = _table_axis(prep)
    if ref is not None:
        prep.blocks.balance(ref)
    return prep


def motion_rows(t: np.ndarray, gyro: list[np.ndarray], accel: list[np.ndarray] | None, fs: float) -> np.ndarray:
    """Rows where a static unit is being moved: a gyro axis more than :data:`MOTION_SIGMA` robust
    standard deviations off its running median (medians of 5-min blocks, interpolated), or the
    specific force magnitude more than :data:`MOTION_G` off its running median; widened by
    :data:`MOTION_PAD_S` on both sides. (n,) bool."""
    n = t.size
    w = max(int(300.0 * fs), 16)
    moving = np.zeros(n, bool)

    def running_median(x: np.ndarray) -> np.ndarray:
        b = n // w
        if b < 2:
            return np.full(n, float(np.median(x)))
        med = np.median(x[: b * w].reshape(b, w), axis=1)
        centres = t[: b * w].reshape(b, w).mean(axis=1)
        return np.interp(t, centres, med)

    for x in gyro:
        d = x - running_median(x)
        sigma = 1.4826 * float(np.median(np.abs(d)))
        if sigma > 0:
            moving |= np.abs(d) > MOTION_SIGMA * sigma
    if accel is not None:
        g = np.sqrt(sum(a * a for a in accel))
        moving |= np.abs(g - running_median(g)) > MOTION_G
    if moving.any():
        pad = max(int(round(MOTION_PAD_S * fs)), 0)
        moving = np.convolve(moving.astype(float), np.ones(2 * pad + 1), mode="same") > 0
    return moving


def bin_length(n: int, fs: float, response: dict[str, np.ndarray], refs: list[np.ndarray]) -> tuple[int, str]:
    """Rows per bin for ``n`` rows at ``fs`` Hz (1: no binning), and what limited it.

    Diagnose fits slow effects; above :data:`BIN_MIN_ROWS` rows, means of consecutive rows keep what
    the vocabulary can see while the fits get k times fewer rows (the white noise of a k-row mean is
    still white, with variance σ²/k, so the held-out statistics stay valid). The bin is the longest of

    * :data:`BIN_MAX_S` (:data:`BIN_MAX_STATIC_S` without a reference rate);
    * with a reference rate: :data:`BIN_PER_PERIOD` bins per period of the highest table-angle
      harmonic the gear term searches at the highest rate, 1/(N_max·max|ω|/360°)/4 (this also
      keeps rate changes resolved for the time-skew and scale-factor terms);
    * with a spectral line in ``response`` (gyro − reference, per axis) above 1/(4·bin) that carries
      at least :data:`LINE_FRACTION` of the variance: 4 bins per period of the highest such line;

    and no binning when that is less than two rows."""
    top = BIN_MAX_S if refs else BIN_MAX_STATIC_S
    if n <= BIN_MIN_ROWS or not math.isfinite(fs) or fs * top < 2:
        return 1, ""
    span, why = top, ""
    w = max((float(np.max(np.abs(r))) for r in refs), default=0.0)
    if w > 0:
        from bench.analysis.diagnose.terms import GearEccentricity

        f_gear = GearEccentricity.N_MAX * w / 360.0
        if 1.0 / (BIN_PER_PERIOD * f_gear) < span:
            span, why = 1.0 / (BIN_PER_PERIOD * f_gear), f"table-angle harmonic N ≤ {GearEccentricity.N_MAX} at {w:.3g} deg/s"
    for a, r in response.items():
        f_line = _highest_line(r, fs, 1.0 / (BIN_PER_PERIOD * span))
        if f_line is not None and 1.0 / (BIN_PER_PERIOD * f_line) < span:
            span, why = 1.0 / (BIN_PER_PERIOD * f_line), f"spectral line at {f_line:.4g} Hz on {a}"
    k = int(math.floor(span * fs * (1.0 + 1e-6)))  # a median interval a hair over 1/fs must not lose a row
    cap = int(math.ceil(n / ANALYSED_MAX))
    if k < cap:
        k, why = cap, (why + "; " if why else "") + f"at most {ANALYSED_MAX:,} rows analysed"
    return (k, why) if k >= 2 else (1, "")


def _highest_line(r: np.ndarray, fs: float, f_min: float) -> float | None:
    """Frequency (Hz) of the highest spectral line of ``r`` above ``f_min`` that carries at least
    :data:`LINE_FRACTION` of its variance, None when there is none. Averaged periodogram of
    1024-row segments (each detrended, Hann window); a line's power is its excess over a running
    median of the spectrum summed over ±2 bins (its leakage)."""
    from scipy.ndimage import median_filter

    m = 1024
    segs = r.shape[0] // m
    if segs < 4:
        return None
    x = r[: segs * m].reshape(segs, m)
    u = np.linspace(-1.0, 1.0, m)
    x = x - x.mean(axis=1, keepdims=True)
    x = x - np.outer(x @ u / (u @ u), u)
    win = np.hanning(m)
    spec = np.fft.rfft(x * win, axis=1)
    s = np.mean(spec.real ** 2 + spec.imag ** 2, axis=0)
    f = np.fft.rfftfreq(m, 1.0 / fs)
    total = float(np.sum(s))
    if total <= 0:
        return None
    floor = median_filter(s, size=31, mode="nearest")
    excess = np.maximum(s - floor, 0.0)
    power = np.convolve(excess, np.ones(5), mode="same")
    peak = (s >= np.roll(s, 1)) & (s >= np.roll(s, -1))
    hits = np.nonzero((f > f_min) & peak & (power >= LINE_FRACTION * total))[0]
    if not hits.size:
        return None
    i = int(hits[-1])
    near = slice(max(i - 2, 0), i + 3)
    return float(np.dot(f[near], excess[near]) / np.sum(excess[near]))  # between the periodogram's bins


LINE_MAX = 3
"""Most spectral lines above the bins' reach fitted per axis."""
ANALYSED_MAX = 200_000
"""Most rows analysed after binning: longer data get longer bins (table-angle harmonics faster than
4 bins per period are then averaged out, and the summary says so), so the fits' memory does not
grow with the length of the data."""


@dataclass
class Line:
    """A coherent sinusoid A·sin(2πft + φ) (deg/s, Hz, rad) of an axis, fitted on the raw samples;
    ``rms_before``/``rms_after`` the raw response's RMS without and with it; ``gain_heldout`` the
    relative drop of the held-out variance (odd blocks fitted, even predicted, and back)."""

    frequency_hz: float
    amplitude_dps: float
    phase_rad: float
    rms_before: float
    rms_after: float
    gain_heldout: float
    axis: str = ""

    def values(self, t: np.ndarray) -> np.ndarray:
        return self.amplitude_dps * np.sin(2.0 * math.pi * self.frequency_hz * t + self.phase_rad)

    def text(self) -> str:
        return (f"spectral line at {self.frequency_hz:.4g} Hz on {self.axis} ({self.amplitude_dps:.2g} deg/s) fitted "
                "on the raw samples and removed before binning")


LINE_BLOCK_S = 60.0
"""Blocks of the held-out check of a fast line (odd blocks fitted, even ones predicted, and back)."""


def fast_lines(t: np.ndarray, r: np.ndarray, fs: float, f_min: float) -> list[Line]:
    """Spectral lines of ``r`` above ``f_min`` Hz (each carrying :data:`LINE_FRACTION` of the
    variance, :func:`_highest_line`) that are coherent over the record: the sinusoid fitted on every
    other :data:`LINE_BLOCK_S` block predicts the blocks between (held-out variance drop of at least
    half the line's share). Narrow-band noise is not coherent and is left to the bins (it averages
    out). Highest line first, at most :data:`LINE_MAX`."""
    out: list[Line] = []
    r = r - float(np.mean(r))
    var = float(np.mean(r * r))
    for _ in range(LINE_MAX):
        f0 = _highest_line(r, fs, f_min)
        if f0 is None:
            break
        f = _refine_line(t, r, f0, t[-1] - t[0])
        ph = 2.0 * math.pi * f * t
        X = np.column_stack([np.sin(ph), np.cos(ph)])
        odd = (np.floor((t - t[0]) / LINE_BLOCK_S).astype(np.int64) % 2).astype(float)
        # normal equations of the two halves from weighted sums (no copies of the rows)
        half = [(_line_normal(X, r, w)) for w in (odd, 1.0 - odd)]
        sse0 = sse1 = 0.0
        for (g_fit, h_fit, _), (g_out, h_out, rr_out) in ((half[0], half[1]), (half[1], half[0])):
            c = np.linalg.solve(g_fit, h_fit)
            sse0 += rr_out
            sse1 += rr_out - 2.0 * float(c @ h_out) + float(c @ g_out @ c)
        gain = 1.0 - sse1 / sse0 if sse0 > 0 else 0.0
        if gain < 0.5 * LINE_FRACTION:
            break
        c = np.linalg.solve(half[0][0] + half[1][0], half[0][1] + half[1][1])
        line = Line(f, float(math.hypot(*c)), float(math.atan2(c[1], c[0])), math.sqrt(var), 0.0, gain)
        r = r - X @ c
        var = float(np.mean(r * r))
        line.rms_after = math.sqrt(var)
        out.append(line)
    return out


def _line_normal(X: np.ndarray, r: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(XᵀWX, XᵀWr, rᵀWr) of the rows weighted by ``w`` (0/1: a subset without copying it)."""
    Xw = X * w[:, None]
    return Xw.T @ X, Xw.T @ r, float(np.dot(r * w, r))


def _refine_line(t: np.ndarray, r: np.ndarray, f0: float, span_s: float) -> float:
    """The frequency of the line near ``f0`` to a small fraction of 1/span: ``r`` demodulated at
    ``f0`` and averaged over blocks of a tenth of its period's inverse resolution (a zoom), whose
    zero-padded periodogram peak near 0 Hz is the offset (one pass over the rows)."""
    fs = 1.0 / float(np.median(np.diff(t[: min(t.size, 1000)])))
    z = r * np.exp(-2j * math.pi * f0 * t)
    k = max(int(fs / (8.0 * 2.0 * fs / 1024)), 1)  # blocks short against the offset's period
    m = z.shape[0] // k
    zb = z[: m * k].reshape(m, k).mean(axis=1)
    nfft = 1 << int(math.ceil(math.log2(max(8 * m, 2))))
    spec = np.abs(np.fft.fft(zb, nfft)) ** 2
    df = np.fft.fftfreq(nfft, k / fs)
    near = np.abs(df) <= 2.0 * fs / 1024
    i = int(np.argmax(np.where(near, spec, -1.0)))
    return float(f0 + df[i])


def _bin_means(t: np.ndarray, cols: dict[str, np.ndarray], k: int, fs: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Means of consecutive rows in bins of ``k`` sample intervals on the time grid (a gap starts a new
    bin; bins with fewer than k/2 rows, at gaps and at the end, are dropped). Time is the bin's mean
    time; the table angle is averaged unwrapped (then taken mod 360)."""
    dt = 1.0 / fs
    b = np.floor((t - t[0] + 0.5 * dt) / (k * dt)).astype(np.int64)
    starts = np.flatnonzero(np.concatenate([[True], b[1:] != b[:-1]]))
    counts = np.diff(np.append(starts, t.size))
    keep = 2 * counts >= k

    def mean(v: np.ndarray) -> np.ndarray:
        return (np.add.reduceat(v, starts) / counts)[keep]

    out = {}
    for name, v in cols.items():
        if name == "table_angle_deg":
            out[name] = mean(np.degrees(np.unwrap(np.radians(v)))) % 360.0
        else:
            out[name] = mean(v)
    return mean(t), out


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
