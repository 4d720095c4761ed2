"""Six static positions and three rotations (Ferraris et al. 1995, as imucal implements it):
``bench calibrate six-position``.

An accelerometer + gyro triad is laid on each of its six faces (``x_p``: +x up, the x accelerometer
reads +1 g; ``x_a``: +x down; ``y_p`` … ``z_a``) and turned once about each axis while that axis
points up (``x_rot`` in the ``x_p`` position, ...). The model is imucal's (``FerrarisCalibrationInfo``)
and the NASA report's multi-position one (seed 001 section III: bias, sensitivity and the
sensitive-axis direction of each axis), written as matrices::

    a_meas = T_a · f + b_a,          T_a = K_a R_a   (K_a diagonal scale, R_a rows unit sensitive axes)
    w_meas = T_g · w + K_ga · f + b_g,  T_g = K_g R_g

f is the specific force (g: a unit lying still reads +1 g on its up axis), w the rate (deg/s).
Units here: accelerometer in g, gyro in deg/s, g-sensitivity K_ga in deg/s per g.

The reading follows Ferraris (imucal's equations, numbered as there):

* accelerometer bias b_a[j] from axis j's own up/down pair, (U_p[j,j] + U_a[j,j])/2 (Eq. 20): a
  hand-placed face tilted by δ changes the on-axis readings by g·δ²/2 only, the other axes' by g·δ;
* T_a[:, i] = (U_p[:, i] − U_a[:, i])/(2g) (Eqs. 21-23), K_a its row norms, R_a = K_a⁻¹T_a;
* gyro bias b_g: the mean of the six static means (imucal: of all static samples, which weighs the
  positions by their length), K_ga[:, i] = (G_p[:, i] − G_a[:, i])/(2g) (Eq. 9);
* rotation i: W[:, i] = ∫(w_meas − b_g − K_ga·a_cal) dt over the section (Eqs. 13/14, a_cal the
  calibrated accelerometer), T_g[:, i] = W[:, i]/θ_i (Eq. 15), K_g its row norms (Eq. 12).

What the data cannot tell, and how it is handled:

* the turned angle θ_i: from the section list (``angle_deg``), from the integrated reference rate
  when the data have ``ref_rate_*_dps`` (a rate table), else the multiple of 360° nearest the
  bias-corrected integral (a hand rotation back to the start; imucal assumes −360°); the output says
  which. A hand rotation that ends a few degrees off its start is a scale error the data do not show
  (``rotation_angle_u_deg`` adds it to the uncertainty);
* the three rotations determine the nine gyro terms exactly: no residual checks them;
* Earth rate (≤ 0.0042 deg/s) is not removed: it is in b_g and in K_ga (the up component flips
  with the face) unless it is below the noise.

Uncertainties (standard, k = 1) propagate the inputs' variances through the whole calculation
(numerical Jacobian): each section mean's noise (std/√n_eff, lag-1 AR(1) n_eff); the positioning
scatter of the faces, estimated from the six off-axis accelerometer residuals (6 degrees of
freedom) and added to every off-axis reading; the gyro statics' scatter beyond their noise (6
degrees of freedom); the noise integrated over each rotation; ``rotation_angle_u_deg``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from bench.analysis.dataset import ACCEL, AXES, GYRO, REF_RATE, Dataset
from bench.analysis.rate_transfer import check_options, effective_samples, jfloat, opt_float
from bench.analysis.result import CalibrationResult, ResultTable
from bench.errors import InputError, Location

STATIC = ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a")
"""The six faces, imucal's names: ``x_p`` +x up (the x accelerometer reads +1 g), ``x_a`` +x down."""
ROTATIONS = ("x_rot", "y_rot", "z_rot")
"""One turn about each axis with that axis up (``x_rot`` in the ``x_p`` position)."""
SECTIONS = STATIC + ROTATIONS

STANDARD_GRAVITY_MS2 = 9.80665
"""1 g (the unit of the accelerometer columns; CGPM 1901)."""

STILL_DPS = 5.0
"""Finding sections: a 0.25-s mean of |gyro − median| below this is still (bench choice: well above
a MEMS gyro's noise averaged over 0.25 s, well below a hand turning a unit at 90-360 deg/s)."""
MIN_STATIC_S = 1.0
"""Finding sections: still stretches shorter than this are pauses inside a motion."""
SETTLE_S = 0.5
"""Finding sections: seconds dropped at each end of a still stretch (the hand letting go)."""
UP_COS = math.cos(math.radians(25.0))
"""A still stretch is a face when one axis holds at least cos 25° of the specific force."""
MIN_TURN_DEG = 180.0
"""A motion is a rotation about the up axis when it turns at least this much about it."""
SMOOTH_S = 0.25
EDGE_S = 0.5
"""The turn measured over this much time just outside each rotation section counts in the angle's
uncertainty (a section cut before the unit came to rest loses that turn)."""

OPTIONS = {
    "sections": "section list file: imucal's JSON or CSV, or YAML/JSON {x_p: {start, end | start_s, end_s}, ...}",
    "local_g": "magnitude of gravity at the bench, m/s² (default 9.80665; imucal's default is 9.81)",
    "rotation_deg": "angle of every rotation, deg (default: from the section list, the reference rate, or the "
                    "nearest multiple of 360°)",
    "rotation_angle_u_deg": "standard uncertainty of each rotation's angle, deg (default 0)",
    "still_dps": "finding sections: largest 0.25-s mean rate that counts as still, deg/s (default 5)",
    "min_static_s": "finding sections: shortest still stretch that is a face, s (default 1)",
    "settle_s": "finding sections: seconds dropped at each end of a still stretch (default 0.5)",
}


@dataclass
class Section:
    """Rows ``start`` to ``stop`` (exclusive, 0-based: imucal's ``data.iloc[start:end]``) of a
    dataset; ``angle_deg`` for a rotation (None: inferred); ``origin`` says where it came from."""

    name: str
    start: int
    stop: int
    angle_deg: float | None = None
    origin: str = ""
    notes: list[str] = field(default_factory=list)
    where: Location | None = None
    """Where a listed section was written (its entry in the section list), for messages."""


# ---- section lists --------------------------------------------------------------------------------
def load_sections(path: str | Path, ds: Dataset) -> dict[str, Section]:
    """The sections of a section-list file: imucal's JSON (``{"x_p": {"start": 540, "end": 1271}, ...}``,
    row numbers, end exclusive), imucal's CSV (``section_list.to_csv``: a name column, ``start``,
    ``end``) or YAML with ``start``/``end`` (rows) or ``start_s``/``end_s`` (times, s) and, for
    rotations, ``angle_deg``; optionally under a top-level ``sections:``. :class:`InputError` located
    at the file, line and column of the first problem."""
    p = Path(path)
    if not p.is_file():
        raise InputError("section list not found", Location(p), "sections")
    if p.suffix.lower() == ".csv":
        return _sections_from_csv(p, ds)
    from bench.yamlsrc import load_yaml

    src = load_yaml(p, "section list")
    root = src.root
    if isinstance(root.value, dict) and "sections" in root.value:
        root = root.value["sections"]
    if not isinstance(root.value, dict):
        raise InputError(f"expected a mapping of sections ({', '.join(SECTIONS)}) to start and end", root.location)
    out: dict[str, Section] = {}
    for name, node in root.value.items():
        where = root.key_locations.get(name, node.location)
        if name not in SECTIONS:
            raise InputError(f"unknown section {name!r} (sections: {', '.join(SECTIONS)})", where)
        if not isinstance(node.value, dict):
            raise InputError("expected {start, end} (rows) or {start_s, end_s} (s)", node.location, name)
        fields = {k: v.plain() for k, v in node.value.items()}
        locs = {k: v.location for k, v in node.value.items()}
        allowed = {"start", "end", "start_s", "end_s"} | ({"angle_deg"} if name in ROTATIONS else set())
        for k in fields:
            if k not in allowed:
                raise InputError(f"unknown field {k!r} (fields: {', '.join(sorted(allowed))})",
                                 node.key_locations.get(k, node.location), name)
        start, stop = _rows(ds, name, fields, locs, node.location)
        angle = None
        if "angle_deg" in fields:
            angle = _number(fields["angle_deg"], locs["angle_deg"], f"{name}.angle_deg")
            if angle == 0:
                raise InputError("a rotation's angle cannot be 0", locs["angle_deg"], f"{name}.angle_deg")
        out[name] = Section(name, start, stop, angle, str(node.location), where=node.location)
    return _complete(out, Location(p))


def _sections_from_csv(p: Path, ds: Dataset) -> dict[str, Section]:
    from bench.csvsrc import read_csv_table

    table = read_csv_table(p)
    head = [h.strip() for h in table.header]
    where = Location(p, table.header_line)
    for col in ("start", "end"):
        if col not in head:
            raise InputError(f"missing column (a section list has a name column, start and end; header has: "
                             f"{', '.join(head)})", where, col)
    name_col = 0 if head[0] not in ("start", "end") else None
    if name_col is None:
        raise InputError("the first column must name the section (x_p, ..., z_rot)", where)
    out: dict[str, Section] = {}
    for row, line in zip(table.rows, table.lines):
        loc = Location(p, line)
        if len(row) != len(head):
            raise InputError(f"expected {len(head)} values like the header, got {len(row)}", loc)
        name = row[name_col].strip()
        if name not in SECTIONS:
            raise InputError(f"unknown section {name!r} (sections: {', '.join(SECTIONS)})", loc)
        fields = {"start": row[head.index("start")].strip(), "end": row[head.index("end")].strip()}
        start, stop = _rows(ds, name, fields, {"start": loc, "end": loc}, loc)
        out[name] = Section(name, start, stop, None, str(loc), where=loc)
    return _complete(out, Location(p))


def _number(v: Any, where: Location, name: str) -> float:
    from bench.errors import finite_number

    if isinstance(v, bool):
        raise InputError(f"expected a number, got {v!r}", where, name)
    return finite_number(v, where, name)


def _rows(ds: Dataset, name: str, fields: dict[str, Any], locs: dict[str, Location], where: Location) -> tuple[int, int]:
    n = len(ds)
    if "start" in fields or "end" in fields:
        if not ("start" in fields and "end" in fields) or "start_s" in fields or "end_s" in fields:
            raise InputError("give start and end (rows) or start_s and end_s (s)", where, name)
        vals = []
        for k in ("start", "end"):
            v = _number(fields[k], locs[k], f"{name}.{k}")
            if not float(v).is_integer():
                raise InputError(f"a row number is a whole number, got {fields[k]!r}", locs[k], f"{name}.{k}")
            vals.append(int(v))
        start, stop = vals
        if not 0 <= start < stop <= n:
            raise InputError(f"rows {start}..{stop} are not inside the data (rows 0..{n}, end exclusive as in "
                             "imucal's data.iloc[start:end])", where, name)
        return start, stop
    if "start_s" in fields and "end_s" in fields:
        t = np.asarray(ds["time_s"], dtype=float)
        a = _number(fields["start_s"], locs["start_s"], f"{name}.start_s")
        b = _number(fields["end_s"], locs["end_s"], f"{name}.end_s")
        start, stop = int(np.searchsorted(t, a, "left")), int(np.searchsorted(t, b, "left"))
        if stop - start < 2:
            raise InputError(f"{a:g}-{b:g} s holds {max(stop - start, 0)} samples (data: {t[0]:g}-{t[-1]:g} s)", where, name)
        return start, stop
    raise InputError("give start and end (rows) or start_s and end_s (s)", where, name)


def _complete(out: dict[str, Section], where: Location) -> dict[str, Section]:
    missing = [s for s in SECTIONS if s not in out]
    if missing:
        raise InputError(f"the section list lacks {', '.join(missing)} (a six-position session needs "
                         f"{', '.join(SECTIONS)})", where, "sections")
    return out


# ---- finding the sections -------------------------------------------------------------------------
def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of the runs of True in ``mask`` (stop exclusive)."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def _face(f: np.ndarray) -> str | None:
    """``x_p`` … ``z_a`` for a specific-force direction within 25° of an axis, else None."""
    norm = float(np.linalg.norm(f))
    if norm == 0 or not math.isfinite(norm):
        return None
    k = int(np.argmax(np.abs(f)))
    if abs(f[k]) < UP_COS * norm:
        return None
    return f"{AXES[k]}_{'p' if f[k] > 0 else 'a'}"


def find_sections(ds: Dataset, *, still_dps: float = STILL_DPS, min_static_s: float = MIN_STATIC_S,
                  settle_s: float = SETTLE_S, nominal_force: np.ndarray | None = None) -> tuple[dict[str, Section], list[str]]:
    """Find the six faces and three rotations in a session: still stretches (0.25-s mean of
    |gyro − median| < ``still_dps`` for ``min_static_s`` or longer, ``settle_s`` dropped at each end)
    labelled by the face their specific force points out of (``nominal_force`` per row, from the
    commanded table positions, else the accelerometer's mean), the longest per face; rotations are
    the motions between two still stretches of one face that turn ≥ 180° about its up axis, the
    largest per axis. Returns the sections and one line per section saying what was found.
    :class:`InputError` naming what is missing when a face or rotation is not found."""
    t = np.asarray(ds["time_s"], dtype=float)
    g = np.column_stack([np.asarray(ds[GYRO[a]], dtype=float) for a in AXES])
    acc = np.column_stack([np.asarray(ds[ACCEL[a]], dtype=float) for a in AXES])
    fs = ds.sample_rate_hz
    w = max(1, int(round(SMOOTH_S * fs)))
    dev = g - np.median(g, axis=0)
    kernel = np.ones(w) / w
    smooth = np.sqrt(sum(np.convolve(dev[:, k], kernel, "same") ** 2 for k in range(3)))
    still = smooth < still_dps
    stretches = [(a, b) for a, b in _runs(still) if t[b - 1] - t[a] >= min_static_s]
    force = acc if nominal_force is None else nominal_force
    faces: list[tuple[int, int, str | None]] = []
    for a, b in stretches:
        faces.append((a, b, _face(force[a:b].mean(axis=0))))
    found: dict[str, Section] = {}
    lines: list[str] = []
    for name in STATIC:
        cands = [(a, b) for a, b, f in faces if f == name]
        if not cands:
            continue
        a, b = max(cands, key=lambda r: t[r[1] - 1] - t[r[0]])
        keep = np.flatnonzero((t[a:b] >= t[a] + settle_s) & (t[a:b] <= t[b - 1] - settle_s)) + a
        if keep.size < 2:
            continue
        found[name] = Section(name, int(keep[0]), int(keep[-1]) + 1, None, "found",
                              [f"{len(cands)} still stretch(es) with +{name[0]} {'up' if name[2] == 'p' else 'down'}; "
                               "the longest taken"])
    dt = _dt(t)
    bias = np.median(g, axis=0)
    turns: dict[str, float] = {}
    margin = max(1, int(round(settle_s * fs)))  # the motion's slow ends are still below still_dps: keep them
    for (a0, b0, f0), (a1, b1, f1) in zip(faces, faces[1:]):
        if f0 is None or f0 != f1 or f0[2] != "p":
            continue
        k = AXES.index(f0[0])
        lo, hi = max(a0, b0 - margin), min(b1, a1 + margin)
        turn = float(((g[lo:hi, k] - bias[k]) * dt[lo:hi]).sum())
        name = f"{f0[0]}_rot"
        if abs(turn) >= MIN_TURN_DEG and abs(turn) > abs(turns.get(name, 0.0)):
            turns[name] = turn
            found[name] = Section(name, int(lo), int(hi), None, "found",
                                  [f"a motion between two still stretches with +{f0[0]} up turning {turn:.0f}° about it"])
    missing = [s for s in SECTIONS if s not in found]
    if missing:
        seen = ", ".join(f"{f or '?'} {t[a]:.1f}-{t[b - 1]:.1f} s" for a, b, f in faces) or "none"
        raise InputError(f"cannot find {', '.join(missing)} in the data (still stretches found: {seen}); give a "
                         "section list (sections option, --sections FILE)", Location(ds.source or "data"), "sections")
    for s in found.values():
        what = s.notes[0]
        s.notes = []
        lines.append(f"{s.name}: rows {s.start}-{s.stop} (t {t[s.start]:.2f}-{t[s.stop - 1]:.2f} s), {what}")
    return {name: found[name] for name in SECTIONS}, lines


def _dt(t: np.ndarray) -> np.ndarray:
    """Each sample's time step (s): forward differences, the last one the median step (for uniform
    sampling Σ x·dt is imucal's Σ x / f_s)."""
    if t.size < 2:
        return np.ones_like(t)
    d = np.diff(t)
    return np.concatenate([d, [float(np.median(d))]])


# ---- the calibration -----------------------------------------------------------------------------
@dataclass
class Inputs:
    """What the calibration is computed from: per face (order :data:`STATIC`) the accelerometer and
    gyro means (6, 3); per rotation (order :data:`ROTATIONS`) ∫gyro dt and ∫accel dt (3, 3: row =
    rotation) and the duration (3,); the angles turned (3,); g (in g)."""

    acc: np.ndarray
    gyro: np.ndarray
    w_raw: np.ndarray
    a_int: np.ndarray
    dur: np.ndarray
    angle: np.ndarray
    g: float

    def vector(self) -> np.ndarray:
        return np.concatenate([self.acc.ravel(), self.gyro.ravel(), self.w_raw.ravel(), self.angle])

    def with_vector(self, x: np.ndarray) -> "Inputs":
        return Inputs(x[:18].reshape(6, 3), x[18:36].reshape(6, 3), x[36:45].reshape(3, 3), self.a_int, self.dur,
                      x[45:48], self.g)


def ferraris(inp: Inputs) -> dict[str, np.ndarray]:
    """The calibration from the section means (see the module docstring; Eq. numbers imucal's)."""
    up, down = inp.acc[0::2].T, inp.acc[1::2].T  # columns: the x, y, z faces
    b_a = np.diag(up + down) / 2.0  # Eq. 20
    t_a = (up - down) / (2.0 * inp.g)  # Eqs. 21-22 (K_a R_a)
    k_a = np.linalg.norm(t_a, axis=1)  # Eq. 23
    gu, gd = inp.gyro[0::2].T, inp.gyro[1::2].T
    b_g = inp.gyro.mean(axis=0)
    k_ga = (gu - gd) / (2.0 * inp.g)  # Eq. 9, deg/s per g
    t_a_inv = np.linalg.inv(t_a)
    w = np.zeros((3, 3))
    for i in range(3):
        a_cal = t_a_inv @ (inp.a_int[i] - b_a * inp.dur[i])  # ∫ calibrated specific force dt
        w[:, i] = inp.w_raw[i] - b_g * inp.dur[i] - k_ga @ a_cal  # Eqs. 13/14
    t_g = w / inp.angle[None, :]  # Eq. 15
    k_g = np.linalg.norm(t_g, axis=1)  # Eq. 12
    return {"b_a": b_a, "T_a": t_a, "K_a": k_a, "R_a": t_a / k_a[:, None], "b_g": b_g, "K_ga": k_ga,
            "T_g": t_g, "K_g": k_g, "R_g": t_g / k_g[:, None]}


def _outputs(res: dict[str, np.ndarray]) -> np.ndarray:
    """The reported quantities as one vector (for the uncertainty propagation): b_a, K_a, the
    accelerometer misalignment angles (deg, off-diagonal), b_g, K_g, the gyro misalignment angles,
    K_ga."""
    off = ~np.eye(3, dtype=bool)
    mis = lambda r: np.degrees(np.arcsin(np.clip(r[off], -1, 1)))  # noqa: E731
    return np.concatenate([res["b_a"], res["K_a"], mis(res["R_a"]), res["b_g"], res["K_g"], mis(res["R_g"]),
                           res["K_ga"].ravel()])


def _propagate(f: Callable[[np.ndarray], np.ndarray], x: np.ndarray, var: np.ndarray) -> np.ndarray:
    """Standard uncertainties of f(x) for independent inputs of variances ``var`` (first order, central
    differences; GUM 5.1.2)."""
    y0 = f(x)
    cov = np.zeros((y0.size, y0.size))
    for i in np.flatnonzero(var > 0):
        h = 1e-6 * max(abs(x[i]), math.sqrt(var[i]), 1e-12)
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        d = (f(xp) - f(xm)) / (2 * h)
        cov += np.outer(d, d) * var[i]
    return np.sqrt(np.diag(cov))


def _mean_u(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column means of ``v`` (n, 3) and their standard uncertainties std/√n_eff (AR(1))."""
    m = v.mean(axis=0)
    u = np.array([float(np.std(v[:, k], ddof=1)) / math.sqrt(effective_samples(v[:, k])) if v.shape[0] > 1 else 0.0
                  for k in range(v.shape[1])])
    return m, u


def calibrate(ds: Dataset, **opts: Any) -> CalibrationResult:
    """``bench calibrate six-position``: see the module docstring. Options: :data:`OPTIONS`.
    Raises :class:`InputError` (located) for data or sections it cannot use."""
    opts = {k: v for k, v in opts.items() if v is not None}
    check_options("six-position", opts, OPTIONS)
    where = Location(ds.source or "data")
    missing = [c for c in list(ACCEL.values()) + list(GYRO.values()) if c not in ds]
    if missing:
        raise InputError(f"a six-position calibration needs columns {', '.join(missing)} (present: "
                         f"{', '.join(ds.columns)}); map other names with --map", where)
    local_g = _local_g(opts.get("local_g", STANDARD_GRAVITY_MS2))
    g = local_g / STANDARD_GRAVITY_MS2
    angle_u = opt_float(opts, "rotation_angle_u_deg", 0.0, 0.0, 360.0)
    t = np.asarray(ds["time_s"], dtype=float)
    acc = np.column_stack([np.asarray(ds[ACCEL[a]], dtype=float) for a in AXES])
    gyro = np.column_stack([np.asarray(ds[GYRO[a]], dtype=float) for a in AXES])
    notes: list[str] = []
    if "sections" in opts:
        sections = load_sections(opts["sections"], ds)
        source = str(opts["sections"])
        found_lines: list[str] = []
    else:
        nominal, how = _nominal_force(ds)
        sections, found_lines = find_sections(
            ds, still_dps=opt_float(opts, "still_dps", STILL_DPS, 1e-6, 1e6),
            min_static_s=opt_float(opts, "min_static_s", MIN_STATIC_S, 0.0, 1e6),
            settle_s=opt_float(opts, "settle_s", SETTLE_S, 0.0, 1e6), nominal_force=nominal)
        source = f"found in the data (faces from {how})"
        notes.append(f"sections found in the data (no section list given; faces from {how}); check them:")
        notes += ["  " + line for line in found_lines]
    for s in sections.values():
        if s.stop - s.start < 2:
            raise InputError(f"holds {s.stop - s.start} sample(s)", s.where or where, s.name)
    dt = _dt(t)
    acc_m, acc_u, gyro_m, gyro_u = (np.zeros((6, 3)) for _ in range(4))
    for i, name in enumerate(STATIC):
        s = sections[name]
        acc_m[i], acc_u[i] = _mean_u(acc[s.start:s.stop])
        gyro_m[i], gyro_u[i] = _mean_u(gyro[s.start:s.stop])
    for i, name in enumerate(STATIC):
        got = _face(acc_m[i])
        if got != name:
            sec = sections[name]
            raise InputError(f"the accelerometer's mean over rows {sec.start}-{sec.stop} of {ds.source or 'the data'} "
                             f"({', '.join(f'{v:.3g}' for v in acc_m[i])} g) points out of "
                             f"{'no face' if got is None else 'face ' + got}, not {name}", sec.where or where, name)
    w_raw, a_int, dur, outside = np.zeros((3, 3)), np.zeros((3, 3)), np.zeros(3), np.zeros((3, 3))
    var_w = np.zeros((3, 3))
    static_dev = np.concatenate([gyro[sections[n].start:sections[n].stop] - gyro_m[i] for i, n in enumerate(STATIC)])
    per_sample_var = np.mean(static_dev ** 2, axis=0)  # gyro noise per sample, pooled over the faces
    angle = np.zeros(3)
    angle_how: list[str] = []
    b_g_guess = gyro_m.mean(axis=0)  # the gyro bias (before the calibration: equal to its b_g)
    for i, name in enumerate(ROTATIONS):
        s = sections[name]
        sl = slice(s.start, s.stop)
        w_raw[i] = (gyro[sl] * dt[sl, None]).sum(axis=0)
        a_int[i] = (acc[sl] * dt[sl, None]).sum(axis=0)
        dur[i] = float(dt[sl].sum())
        steps = float((dt[sl] ** 2).sum())
        var_w[i] = per_sample_var * steps * np.array([s_ratio(static_dev[:, k]) for k in range(3)])
        # motion just outside the section (an end cut while the unit still turned): ∫(w − b) over EDGE_S
        # before and after, each a possible error of the turned angle, beyond its noise
        edge = max(1, int(round(EDGE_S * ds.sample_rate_hz)))
        for lo, hi in ((max(0, s.start - edge), s.start), (s.stop, min(len(t), s.stop + edge))):
            if hi > lo:
                out_turn = ((gyro[lo:hi] - b_g_guess) * dt[lo:hi, None]).sum(axis=0)
                var_w[i] += np.maximum(out_turn ** 2 - per_sample_var * float((dt[lo:hi] ** 2).sum()), 0.0)
                outside[i] += np.abs(out_turn)
        angle[i], how = _angle(name, s, opts, ds, dt, float(w_raw[i, i] - b_g_guess[i] * dur[i]))
        angle_how.append(how)
    inp = Inputs(acc_m, gyro_m, w_raw, a_int, dur, angle, g)
    try:
        res = ferraris(inp)
    except np.linalg.LinAlgError:
        raise InputError("the six faces do not determine the accelerometer (its matrix is singular): check the "
                         "section list", where, "sections") from None
    # residuals per face and the scatter beyond the noise they show
    f_nom = np.array([_face_vector(n) for n in STATIC]) * g
    r_acc = acc_m - (f_nom @ res["T_a"].T + res["b_a"])
    r_gyro = gyro_m - (f_nom @ res["K_ga"].T + res["b_g"])
    pair_noise = np.array([[(acc_u[2 * c, j] ** 2 + acc_u[2 * c + 1, j] ** 2) / 4 for c in range(3)] for j in range(3)])
    r_off = np.array([[r_acc[2 * c, j] for c in range(3) if c != j] for j in range(3)])
    noise_off = np.array([[pair_noise[j, c] + pair_noise[j, j] for c in range(3) if c != j] for j in range(3)])
    pos_var = max(0.0, 2.0 * float(np.mean(r_off ** 2 - noise_off)))  # (g·δ)², 6 degrees of freedom
    d_g = (gyro_m[0::2] + gyro_m[1::2]) / 2.0  # (3 faces, 3 axes)
    gyro_scatter = max(0.0, float(np.sum((d_g - d_g.mean(axis=0)) ** 2)) / 3.0 - float(np.mean(gyro_u ** 2)))
    # a face tilted by δ moves reading (face i, axis j) by g·Σ_{k≠i} T_a[j, k]·δ_k: ≈ g·δ off the face's
    # axis, and the misalignment (T_a[i, k], k ≠ i) times g·δ on it
    t_a = res["T_a"]
    tilt_gain = np.array([[sum(t_a[j, k] ** 2 for k in range(3) if k != AXES.index(STATIC[i][0])) for j in range(3)]
                          for i in range(6)])
    var_acc = acc_u ** 2 + pos_var * tilt_gain
    var_gyro = gyro_u ** 2 + gyro_scatter
    var = np.concatenate([var_acc.ravel(), var_gyro.ravel(), var_w.ravel(), np.full(3, angle_u ** 2)])
    se = _propagate(lambda x: _outputs(ferraris(inp.with_vector(x))), inp.vector(), var)
    return _result(ds, res, se, inp, sections, source, angle_how, r_acc, r_gyro, acc_u, gyro_u, local_g,
                   math.degrees(math.sqrt(pos_var) / g), math.sqrt(gyro_scatter), t, acc, outside, notes)


def s_ratio(v: np.ndarray) -> float:
    """n/n_eff of a series (≥ 1): how much its autocorrelation inflates the variance of its sum."""
    return max(1.0, v.size / effective_samples(v)) if v.size > 2 else 1.0


def _face_vector(name: str) -> np.ndarray:
    v = np.zeros(3)
    v[AXES.index(name[0])] = 1.0 if name[2] == "p" else -1.0
    return v


def _local_g(v: Any) -> float:
    from bench.units import to_units

    try:
        x = float(v) if not isinstance(v, str) else float(to_units(v if any(c.isalpha() for c in v) else f"{v} m/s^2",
                                                                   "m/s^2", None, "local_g"))
    except InputError:
        raise
    except (TypeError, ValueError):
        raise InputError(f"expected an acceleration such as 9.81 or '9.81 m/s^2', got {v!r}", None, "local_g") from None
    if not 9.7 <= x <= 9.9:
        raise InputError(f"{x:g} m/s² is not gravity at the Earth's surface (9.78-9.83 m/s²)", None, "local_g")
    return x


def _nominal_force(ds: Dataset) -> tuple[np.ndarray | None, str]:
    """Specific force per row from the commanded table positions (``table_angle_deg`` and the tilt
    from a column, the metadata or the mapping), or None (faces from the accelerometer)."""
    if "table_angle_deg" not in ds:
        return None, "the accelerometer's direction"
    from bench.analysis.gauss_newton import mount_of, tilt_per_row
    from bench.model.accel import sting_gravity

    where = Location(ds.source or "data")
    try:
        tilt, _ = tilt_per_row(ds, {}, where)
    except InputError:
        return None, "the accelerometer's direction (table angles but no tilt)"
    mount = mount_of(ds.meta.get("mount", "z"), where)
    f = sting_gravity(np.radians(tilt), np.radians(np.asarray(ds["table_angle_deg"], dtype=float)), 1.0) @ mount.T
    return f, "the commanded table angle and tilt"


def _angle(name: str, s: Section, opts: dict[str, Any], ds: Dataset, dt: np.ndarray, turned: float) -> tuple[float, str]:
    """The angle turned in rotation ``name`` (deg) and where it came from."""
    if "rotation_deg" in opts:
        v = opt_float(opts, "rotation_deg", 0.0, -3600.0, 3600.0)
        if v == 0:
            raise InputError("a rotation's angle cannot be 0", None, "rotation_deg")
        return v, "rotation_deg option"
    if s.angle_deg is not None:
        return float(s.angle_deg), f"section list ({s.origin})"
    k = AXES.index(name[0])
    if REF_RATE[AXES[k]] in ds:
        ref = np.asarray(ds[REF_RATE[AXES[k]]], dtype=float)[s.start:s.stop]
        a = float((ref * dt[s.start:s.stop]).sum())
        if abs(a) >= MIN_TURN_DEG:
            return a, "the integrated reference rate"
    turns = round(turned / 360.0)
    if turns == 0:
        raise InputError(f"turns {turned:.0f}° about {AXES[k]} over rows {s.start}-{s.stop}: not a rotation (give "
                         "angle_deg in the section list, or the rotation_deg option)", s.where or Location(ds.source or "data"),
                         name)
    return 360.0 * turns, f"the nearest multiple of 360° to the measured {turned:.1f}° (imucal assumes −360°)"


def _fmt_u(v: float, u: float, digits: int = 6) -> str:
    return f"{v:.{digits}g} ± {u:.2g}"


def _result(ds: Dataset, res: dict[str, np.ndarray], se: np.ndarray, inp: Inputs, sections: dict[str, Section],
            source: str, angle_how: list[str], r_acc: np.ndarray, r_gyro: np.ndarray, acc_u: np.ndarray,
            gyro_u: np.ndarray, local_g: float, pos_deg: float, gyro_scatter: float, t: np.ndarray, acc: np.ndarray,
            outside: np.ndarray, notes: list[str]) -> CalibrationResult:
    off = ~np.eye(3, dtype=bool)
    se_b_a, se_k_a, se_m_a, se_b_g, se_k_g, se_m_g, se_kga = (se[0:3], se[3:6], se[6:12], se[12:15], se[15:18],
                                                              se[18:24], se[24:33].reshape(3, 3))

    def mis(r: np.ndarray, s: np.ndarray) -> tuple[list, list]:
        m = np.full((3, 3), np.nan)
        u = np.full((3, 3), np.nan)
        m[off] = np.degrees(np.arcsin(np.clip(r[off], -1, 1)))
        u[off] = s
        return _matrix(m), _matrix(u)

    mis_a, mis_a_u = mis(res["R_a"], se_m_a)
    mis_g, mis_g_u = mis(res["R_g"], se_m_g)
    accel = {"bias_g": res["b_a"].tolist(), "bias_se_g": se_b_a.tolist(), "scale": res["K_a"].tolist(),
             "scale_se": se_k_a.tolist(), "misalignment_deg": mis_a, "misalignment_se_deg": mis_a_u,
             "T": res["T_a"].tolist(), "R": res["R_a"].tolist()}
    gyro = {"bias_dps": res["b_g"].tolist(), "bias_se_dps": se_b_g.tolist(), "scale": res["K_g"].tolist(),
            "scale_se": se_k_g.tolist(), "misalignment_deg": mis_g, "misalignment_se_deg": mis_g_u,
            "g_sensitivity_dps_per_g": res["K_ga"].tolist(), "g_sensitivity_se_dps_per_g": se_kga.tolist(),
            "T": res["T_g"].tolist(), "R": res["R_g"].tolist()}
    a_cal_mean = []
    sec_json = []
    for i, name in enumerate(SECTIONS):
        s = sections[name]
        entry: dict[str, Any] = {"name": name, "start_row": s.start, "stop_row": s.stop, "t_start_s": float(t[s.start]),
                                 "t_end_s": float(t[s.stop - 1]), "samples": s.stop - s.start,
                                 "origin": s.origin or "found"}
        if name in STATIC:
            entry.update({"residual_accel_g": r_acc[i].tolist(), "u_mean_accel_g": acc_u[i].tolist(),
                          "residual_gyro_dps": r_gyro[i].tolist(), "u_mean_gyro_dps": gyro_u[i].tolist()})
        else:
            k = ROTATIONS.index(name)
            a_cal = np.linalg.solve(res["T_a"], (acc[s.start:s.stop] - res["b_a"]).T).T
            norm_err = float(np.mean(np.linalg.norm(a_cal, axis=1)) - inp.g)
            a_cal_mean.append(norm_err)
            entry.update({"angle_deg": float(inp.angle[k]), "angle_from": angle_how[k],
                          "turned_raw_deg": inp.w_raw[k].tolist(), "duration_s": float(inp.dur[k]),
                          "accel_norm_error_g": norm_err, "turn_outside_deg": outside[k].tolist(),
                          "residual": None})
        sec_json.append(entry)
    imucal_form = {  # the same calibration in imucal's FerrarisCalibrationInfo form and units
        "K_a": np.diag(res["K_a"]).tolist(), "R_a": res["R_a"].tolist(),
        "b_a": (res["b_a"] * STANDARD_GRAVITY_MS2).tolist(),
        "K_g": np.diag(res["K_g"]).tolist(), "R_g": res["R_g"].tolist(), "b_g": res["b_g"].tolist(),
        "K_ga": (res["K_ga"] / STANDARD_GRAVITY_MS2).tolist(),
        "acc_unit": "m/s^2", "gyr_unit": "deg/s", "grav": local_g}
    payload = {
        "method": "six-position", "sections_from": source, "sections": sec_json,
        "local_g_ms2": local_g, "accel": accel, "gyro": gyro,
        "positioning_scatter_deg": pos_deg, "static_gyro_scatter_dps": gyro_scatter,
        "imucal_form": imucal_form,
        "units": {"accel": "g", "gyro": "deg/s", "g_sensitivity": "deg/s per g", "angles": "deg",
                  "scale": "output per input (1 = nominal)"},
    }
    tables = [
        ResultTable("Six-position calibration: accelerometer (g)", ["axis", "bias (g)", "scale", "misalignment toward "
                    "the other axes (deg)"],
                    [[a, _fmt_u(res["b_a"][k], se_b_a[k]), _fmt_u(res["K_a"][k], se_k_a[k]),
                      "; ".join(f"{AXES[i]}: {mis_a[k][i]:+.4f} ± {mis_a_u[k][i]:.2g}" for i in range(3) if i != k)]
                     for k, a in enumerate(AXES)]),
        ResultTable("Six-position calibration: gyro (deg/s)", ["axis", "bias (deg/s)", "scale", "misalignment (deg)",
                    "g-sensitivity to x, y, z (deg/s per g)"],
                    [[a, _fmt_u(res["b_g"][k], se_b_g[k]), _fmt_u(res["K_g"][k], se_k_g[k]),
                      "; ".join(f"{AXES[i]}: {mis_g[k][i]:+.4f} ± {mis_g_u[k][i]:.2g}" for i in range(3) if i != k),
                      ", ".join(f"{res['K_ga'][k, i]:+.4g} ± {se_kga[k, i]:.2g}" for i in range(3))]
                     for k, a in enumerate(AXES)]),
        ResultTable("Sections and residuals", ["section", "rows", "t (s)", "accel residual (g)", "gyro residual (deg/s)",
                                               "angle (deg)"],
                    [[e["name"], f"{e['start_row']}-{e['stop_row']}", f"{e['t_start_s']:.2f}-{e['t_end_s']:.2f}",
                      ", ".join(f"{v:+.2e}" for v in e["residual_accel_g"]) if "residual_accel_g" in e
                      else f"|a| after calibration {e['accel_norm_error_g']:+.2e} from g",
                      ", ".join(f"{v:+.2e}" for v in e["residual_gyro_dps"]) if "residual_gyro_dps" in e else "-",
                      f"{e['angle_deg']:g} ({e['angle_from']})" if "angle_deg" in e else "-"] for e in sec_json]),
    ]
    notes = list(notes)
    notes.append(f"faces placed with a scatter of {pos_deg:.3g}° (from the off-axis accelerometer residuals, 6 degrees of "
                 "freedom); it is in the misalignment uncertainties")
    notes.append("the three rotations determine the nine gyro scale and misalignment terms exactly: no residual checks "
                 "them; a rotation that does not end at its start heading is a scale error the data do not show "
                 "(rotation_angle_u_deg adds it to the uncertainty)")
    notes.append("Earth rate (up to 0.0042 deg/s) is not removed: it is in the gyro bias and the g-sensitivity")
    calibration = {
        "method": "six-position",
        "model": "a = T_a f + b_a; w = T_g w_true + K_ga f + b_g (T = K R; Ferraris 1995, imucal)",
        "accel": {"bias_g": accel["bias_g"], "T": accel["T"], "bias_se_g": accel["bias_se_g"],
                  "scale": accel["scale"], "scale_se": accel["scale_se"]},
        "gyro": {"bias_dps": gyro["bias_dps"], "T": gyro["T"], "g_sensitivity_dps_per_g": gyro["g_sensitivity_dps_per_g"],
                 "bias_se_dps": gyro["bias_se_dps"], "scale": gyro["scale"], "scale_se": gyro["scale_se"]},
        "b_cons_dps": {a: float(res["b_g"][k]) for k, a in enumerate(AXES)},
        "M": (res["T_g"] - np.eye(3)).tolist(),
        "local_g_ms2": local_g,
    }
    return CalibrationResult("six-position", payload, tables, calibration, notes)


def _matrix(m: np.ndarray) -> list[list[float | None]]:
    return [[jfloat(v) for v in row] for row in m]
