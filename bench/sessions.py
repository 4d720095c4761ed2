"""Vectorised test sessions of the simulated lab, without the wire protocols: a whole run's
measured data in one numpy pass, for the analysis tests and benchmarks.

Two kinds of session (``kind``):

* ``"tvac"``: a gyro on the 2-axis rate table inside the thermal-vacuum chamber. Power-on at
  t = 0; the chamber (``bench/sim/chamber.py`` physics: rate-limited air loop, air → mount → die
  coupling, roughing + turbo pump-down, vent) runs a thermal cycle: soak, ramp up, pump down,
  ramp down, vent, ramp back; meanwhile the table steps through rates continuously (smooth
  raised-cosine transitions, so the rate derivative is continuous) and changes its tilt a few
  times, so gravity and Earth rate turn in the sensor frame.
* ``"stepper"``: the ESTCube-2 stepper bench (thesis sections 3.2 and 4.3): a level board on the
  worm-gear bench about its z axis at 0.1-3 deg/s (instantaneous speed changes) in a thermal
  chamber at ambient pressure, held at the thesis's plateaus −20, 0, 20 and 60 °C in turn. No
  pressure column (the thesis had no vacuum).

The sensor is a baseline gyro (constant bias + cubic temperature bias + scale-factor/misalignment
matrix on the true rate + white noise: :class:`BaselineSensor`, random per seed or given) plus
hidden effects (``bench/model/effects.py`` vocabulary) applied through
:func:`bench.model.effects.apply_effects`. The sensor model is evaluated behind one seam,
:func:`sensor_output`. ``ref_rate_*`` columns carry the true kinematic rate (table rotation and
tilt rate, no Earth rate), ``table_angle_deg`` the table angle; Earth rate reaches the gyro only
when ``earth_rate`` is among the effects.

Defaults and sources: chamber rates and time constants ``bench/sim/chamber.py`` (NPSAT1 App. B
Table 1, section IV.D.4), sped up for short sessions (``thermal_speedup``, default
``clip(4 h / duration, 1, 4)``) so that a one-hour session still sees a full thermal cycle; gyro
noise density 0.005 deg/s/√Hz and accelerometer 400 µg/√Hz (MPU-6000, ESTCube-2 Tables 2.1, 2.2)
through the 12.5 Hz low-pass bandwidth of ``bench/model/imu_simple.py``; latitude 36.4° (NPSAT1
IV.E); stepper rates 0.1-3 deg/s (ESTCube-2 section 3.2) and plateaus (section 4.3); temperature
channel resolution 0.01 °C (board frame scale, ``drivers/acs_protocol.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from bench.analysis.dataset import ACCEL, AXES, GYRO, REF_RATE, Dataset
from bench.errors import InputError
from bench.model.effects import Effect, apply_effects, parse_effects
from bench.sim.chamber import Chamber, ChamberParams

GYRO_NOISE_DENSITY = 0.005  # deg/s/√Hz, MPU-6000 (ESTCube-2 Table 2.1)
ACCEL_NOISE_DENSITY = 400e-6  # g/√Hz, MPU-6000 (ESTCube-2 Table 2.2)
LOWPASS_HZ = 12.5  # ESTCube-2 section 4.2 test configuration
TEMP_RESOLUTION_C = 0.01


def noise_sigma(density: float, rate_hz: float) -> float:
    """Per-sample white-noise standard deviation for a density through the board low-pass
    (as ``SimpleImuModel.noise_sigma``)."""
    return density * math.sqrt(min(math.pi / 2 * LOWPASS_HZ, rate_hz / 2))


@dataclass
class BaselineSensor:
    """The baseline gyro model that ``bench diagnose`` fits (units in the names).

    ``output = bias + Σ_k poly[:, k-1]·(T − 25)^k + M·ω + noise``, per axis."""

    bias_dps: np.ndarray
    poly_dps: np.ndarray
    """(3, 3): axis × (c1, c2, c3), deg/s per °C^k about 25 °C."""
    matrix: np.ndarray
    """(3, 3) scale-factor/misalignment matrix on the true rate (identity = perfect)."""
    noise_dps: float
    """white-noise standard deviation per sample (deg/s)."""

    @classmethod
    def random(cls, rng: np.random.Generator, rate_hz: float) -> "BaselineSensor":
        """A plausible MEMS gyro: biases up to 0.1 deg/s, ESTCube-2-sized temperature slopes
        (Table 4.1: ~0.01 deg/s/°C), scale/misalignment errors ~0.5 %, MPU-6000 noise."""
        poly = np.stack([rng.uniform(-0.015, 0.015, 3), rng.uniform(-2e-4, 2e-4, 3), rng.uniform(-2e-6, 2e-6, 3)], axis=1)
        return cls(bias_dps=rng.uniform(-0.1, 0.1, 3), poly_dps=poly, matrix=np.eye(3) + rng.normal(0.0, 0.005, (3, 3)),
                   noise_dps=noise_sigma(GYRO_NOISE_DENSITY, rate_hz))

    def as_dict(self) -> dict[str, Any]:
        return {"bias_dps": [float(v) for v in self.bias_dps], "poly_dps": self.poly_dps.tolist(),
                "matrix": self.matrix.tolist(), "noise_dps": float(self.noise_dps)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "BaselineSensor":
        return cls(np.asarray(d["bias_dps"], float), np.asarray(d["poly_dps"], float).reshape(3, 3),
                   np.asarray(d["matrix"], float).reshape(3, 3), float(d["noise_dps"]))


@dataclass
class SessionInputs:
    """What the sensor experiences (the fields of ``bench.model.inputs.SensorInputs``)."""

    time_s: np.ndarray
    rate_dps: np.ndarray
    temp_c: np.ndarray
    pressure_torr: np.ndarray | None
    power_on_s: np.ndarray
    specific_force_g: np.ndarray
    table_angle_deg: np.ndarray


@dataclass
class Session:
    """A generated session: the measured ``dataset`` and the hidden truth that produced it."""

    dataset: Dataset
    base: BaselineSensor
    effects: list[Effect]
    inputs: SessionInputs
    meta: dict[str, Any] = field(default_factory=dict)


def gyro_params_from_base(base: BaselineSensor, rate_hz: float) -> Any:
    """The :class:`bench.model.gyro.GyroModelParams` (``npsat1_gyro``) equal to ``base``: constant
    bias, the cubic re-expanded in powers of T (°C), M − I in percent, white noise as ARW."""
    from bench.model.gyro import GyroModelParams

    return GyroModelParams(**gyro_model_keys(base, rate_hz))


def gyro_model_keys(base: BaselineSensor, rate_hz: float) -> dict[str, Any]:
    """``npsat1_gyro`` model-file keys for ``base`` (plain lists, YAML-ready)."""
    shift = np.polynomial.Polynomial([-25.0, 1.0])
    poly = []
    for a in range(3):
        p = np.polynomial.Polynomial([0.0, *base.poly_dps[a]])(shift)
        c = np.zeros(4)
        c[: p.coef.size] = p.coef[:4]
        poly.append([float(v) for v in c])
    return {
        "b_cons_dps": [float(v) for v in base.bias_dps],
        "in_run_poly": poly,
        "in_run_poly_variable": "temp_c",
        "misalignment_pct": ((base.matrix - np.eye(3)) * 100.0).tolist(),
        "arw_deg_rth": [float(base.noise_dps * 60.0 * math.sqrt(1.0 / rate_hz))] * 3,
    }


def sensor_output(inputs: SessionInputs, base: BaselineSensor, effects: Sequence[Effect],
                  rng: np.random.Generator, rate_hz: float, model: Any = None, engine: str = "auto") -> np.ndarray:
    """The seam where the sensor model is evaluated: gyro output (n, 3) in deg/s.

    ``engine``: ``"gyro"`` evaluates :class:`bench.model.gyro.GyroModel` (the project's sensor
    model; ``model`` = a loaded ``SensorModelSpec`` or None for ``base``), ``"builtin"`` the same
    baseline in a few numpy lines (no dependency on the model package), ``"auto"`` the former when
    importable. Hidden ``effects`` are applied through :func:`bench.model.effects.apply_effects`
    either way."""
    eff = [e.as_dict() for e in effects]
    if engine in ("auto", "gyro") or model is not None:
        try:
            from bench.model.gyro import GyroModel
            from bench.model.inputs import SensorInputs
        except ImportError:
            if engine == "gyro" or model is not None:
                raise
        else:
            si = SensorInputs(time_s=inputs.time_s, rate_dps=inputs.rate_dps, temp_c=inputs.temp_c,
                              pressure_torr=inputs.pressure_torr, power_on_s=inputs.power_on_s,
                              specific_force_g=inputs.specific_force_g, table_angle_deg=inputs.table_angle_deg)
            if model is not None:
                if model.gyro is None:
                    raise InputError(f"sensor model {model.path}: model {model.model!r} is not a gyro model (npsat1_gyro)")
                return GyroModel(model.gyro, rng, list(model.effects) + eff).evaluate(si)
            return GyroModel(gyro_params_from_base(base, 1.0 / float(np.median(np.diff(inputs.time_s)))), rng, eff).evaluate(si)
    u = inputs.temp_c - 25.0
    out = base.bias_dps[None, :] + np.stack([u, u * u, u ** 3], axis=1) @ base.poly_dps.T + inputs.rate_dps @ base.matrix.T
    out = apply_effects(eff, inputs, out, rng)
    return out + rng.standard_normal(out.shape) * base.noise_dps


# ---- motion profiles ----------------------------------------------------------------------------
def _smooth_profile(t: np.ndarray, t_start: np.ndarray, values: np.ndarray, ramp_s: np.ndarray,
                    v0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Value and its integral at ``t`` for steps to ``values[k]`` starting at ``t_start[k]`` with a
    raised-cosine transition of ``ramp_s[k]`` (s). Returns (value, integral from t = 0)."""
    prev = np.concatenate([[v0], values[:-1]])
    # integral at each segment start
    seg_len = np.diff(np.concatenate([t_start, [np.inf]]))
    ramp = np.minimum(ramp_s, seg_len)

    def seg_integral(k_idx: np.ndarray, s: np.ndarray) -> np.ndarray:
        a, b, r = prev[k_idx], values[k_idx], ramp[k_idx]
        s_r = np.minimum(s, r)
        with np.errstate(invalid="ignore", divide="ignore"):
            part = np.where(r > 0, a * s_r + (b - a) / 2 * (s_r - r / np.pi * np.sin(np.pi * s_r / np.where(r > 0, r, 1))), b * s_r)
        return part + b * np.maximum(s - r, 0.0)

    ks = np.arange(values.size)
    finite_len = np.where(np.isfinite(seg_len), seg_len, 0.0)
    start_int = np.concatenate([[0.0], np.cumsum(seg_integral(ks, finite_len))[:-1]]) + v0 * t_start[0]
    k = np.clip(np.searchsorted(t_start, t, side="right") - 1, 0, None)
    before = t < t_start[0]
    s = np.maximum(t - t_start[k], 0.0)
    r = ramp[k]
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(s < r, 0.5 * (1 - np.cos(np.pi * s / np.where(r > 0, r, 1))), 1.0)
    val = prev[k] + (values[k] - prev[k]) * frac
    integ = start_int[k] + seg_integral(k, s)
    val = np.where(before, v0, val)
    integ = np.where(before, v0 * t, integ)
    return val, integ


def _rate_schedule(rng: np.random.Generator, duration_s: float, levels: Sequence[float], seg_s: tuple[float, float],
                   accel_dps2: tuple[float, float] | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    starts, vals, ramps = [], [], []
    t, prev = 0.0, 0.0
    while t < duration_s:
        v = float(rng.choice(levels)) * (1 if rng.random() < 0.5 else -1)
        if accel_dps2 is None:
            r = 0.0
        else:
            a = rng.uniform(*accel_dps2)
            r = max(abs(v - prev) * math.pi / 2 / a, 2.0)
        starts.append(t)
        vals.append(v)
        ramps.append(r)
        prev = v
        t += rng.uniform(*seg_s)
    return np.array(starts), np.array(vals), np.array(ramps)


# ---- sessions -----------------------------------------------------------------------------------
def make_session(duration_s: float = 3600.0, rate_hz: float = 1.0, effects: Sequence[dict[str, Any] | Effect] = (),
                 seed: int = 0, kind: str = "tvac", mount: str = "z", latitude_deg: float = 36.4,
                 base: BaselineSensor | dict[str, Any] | None = None, thermal_speedup: float | None = None,
                 quantize_gyro_dps: float | None = None, model: Any = None, engine: str = "auto",
                 extra: Any = None) -> Session:
    """Generate a session (see module docstring) and return it with its hidden truth.

    :param duration_s: length (s)
    :param rate_hz: sample rate (Hz), e.g. 1 or 10
    :param effects: hidden effects, ``{effect, axis, params}`` entries of the vocabulary
    :param seed: seeds the profiles, the baseline sensor (when ``base`` is None) and the noise
    :param kind: ``"tvac"`` (rate table in the chamber) or ``"stepper"`` (ESTCube-2 bench)
    :param mount: sensor axis on the table axis (x, y, z, -x, -y, -z)
    :param latitude_deg: written to the metadata; used by an ``earth_rate`` effect without its own
    :param base: the baseline sensor (:class:`BaselineSensor` or its dict); random when None
    :param thermal_speedup: chamber rate multiplier (default ``clip(14400 s / duration, 1, 4)``)
    :param quantize_gyro_dps: gyro LSB (deg/s) to quantise the output to; None = no quantisation
    :param model: a sensor-model file (path or loaded ``SensorModelSpec``, ``npsat1_gyro``) to
        simulate instead of ``base``, its ``effects:`` included (e.g. ``bench diagnose -o`` output)
    :param engine: ``"auto"``/``"gyro"``/``"builtin"``, see :func:`sensor_output`
    :param extra: an error outside the vocabulary: ``extra(inputs) -> (n, 3)`` deg/s added to the
        gyro output (``inputs`` a :class:`SessionInputs`); what a real bench produces that nobody
        wrote a term for (tests hide such effects from diagnose)
    """
    if kind not in ("tvac", "stepper"):
        raise InputError(f"session kind must be 'tvac' or 'stepper', got {kind!r}")
    if not duration_s > 0 or not rate_hz > 0:
        raise InputError("session duration and sample rate must be > 0")
    from bench.model.geometry import mount_matrix

    try:
        m = mount_matrix(mount)
    except ValueError as exc:
        raise InputError(f"session mount: {exc}") from None
    rng = np.random.default_rng(seed)
    prof_rng, base_rng, noise_rng = (np.random.default_rng(s) for s in rng.integers(0, 2**63, 3))
    n = int(round(duration_s * rate_hz))
    t = np.arange(n) / rate_hz
    eff = parse_effects(list(effects))
    for e in eff:
        if e.name == "earth_rate" and "latitude_deg" not in e.params:
            e.params["latitude_deg"] = latitude_deg
            e.params.setdefault("table_axis", mount)

    # ---- chamber: thermal cycle, pump-down and vent ----
    k = thermal_speedup if thermal_speedup is not None else min(max(14400.0 / duration_s, 1.0), 4.0)
    cp = ChamberParams(heat_rate_ambient_c_per_min=0.62 * k, cool_rate_ambient_c_per_min=0.47 * k,
                       rate_vacuum_c_per_min=0.20 * k, tau_ambient_s=100.0 / k ** 0.5, tau_vacuum_s=1800.0 / k,
                       history_s=duration_s + 10.0, set_point_low_c=-60.0)
    t0c = prof_rng.uniform(15.0, 25.0)
    ch = Chamber(cp, ambient_temp_c=t0c)
    ch.set_unit_power(0.0, True)
    D = duration_s
    if kind == "tvac":
        hi = t0c + prof_rng.uniform(18.0, 30.0)
        lo = t0c - prof_rng.uniform(15.0, 25.0)
        plan = [(0.04, "sp", hi), (0.28, "pump", True), (0.42, "sp", lo), (0.70, "vent", True), (0.80, "sp", t0c + 5.0)]
        ch.command_ramp_rate(0.0, 0.62 * k)
    else:
        plateaus = [-20.0, 0.0, 20.0, 60.0]  # ESTCube-2 section 4.3 (−20.4, 0.1, 20.2, 59.8 °C)
        order = prof_rng.permutation(4)
        plan = [(0.02 + 0.245 * i, "sp", plateaus[j]) for i, j in enumerate(order)]
        ch.command_ramp_rate(0.0, 0.0)
    for frac, what, val in plan:
        ts = frac * D
        if what == "sp":
            ch.command_set_point(ts, float(val))
        elif what == "pump":
            ch.set_pump(ts, True)
        elif what == "vent":
            ch.set_pump(ts, False)
            ch.set_vent(ts, True)
    ch.advance(D + 1.0)
    die = ch.unit_temperature_c(t)
    temp = np.round(die / TEMP_RESOLUTION_C) * TEMP_RESOLUTION_C
    air = ch._query(t, "air")  # noqa: SLF001 - the chamber's own vectorised history read
    pressure = ch._query(t, "p") if kind == "tvac" else None  # noqa: SLF001

    # ---- table: rotation and tilt ----
    if kind == "tvac":
        st, sv, sr = _rate_schedule(prof_rng, D, [0.0, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0], (30.0, 90.0), (0.5, 2.0))
        tilt_times = np.sort(prof_rng.uniform(0.08, 0.95, 5)) * D
        tilt_vals = prof_rng.choice([0.0, 30.0, -30.0, 45.0, -45.0, 60.0, -60.0, 90.0, -90.0, -36.4], 5)
        tilt_ramps = np.abs(np.diff(np.concatenate([[0.0], tilt_vals]))) / 3.0 * math.pi / 2 + 1.0
        phi_deg, _ = _smooth_profile(t, tilt_times, tilt_vals, tilt_ramps)
        # tilt rate: derivative of the raised-cosine profile, analytically via a small step
        h = 1e-3
        phi_rate = (_smooth_profile(t + h, tilt_times, tilt_vals, tilt_ramps)[0]
                    - _smooth_profile(t - h, tilt_times, tilt_vals, tilt_ramps)[0]) / (2 * h)
    else:
        st, sv, sr = _rate_schedule(prof_rng, D, [0.1, 0.2, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0], (60.0, 150.0), None)
        phi_deg = np.zeros(n)
        phi_rate = np.zeros(n)
    omega, theta = _smooth_profile(t, st, sv, sr)
    th = np.radians(theta)
    c, s = np.cos(th), np.sin(th)
    ph = np.radians(phi_deg)
    # platter frame: tilt rate about the (tilted) west axis turned by θ, plus the rotation rate
    rate_p = np.stack([s * phi_rate, c * phi_rate, omega], axis=1)
    grav_t = np.stack([-np.sin(ph), np.zeros(n), np.cos(ph)], axis=1)
    grav_p = np.stack([c * grav_t[:, 0], -s * grav_t[:, 0], grav_t[:, 2]], axis=1)
    rate_s = rate_p @ m.T
    force_s = grav_p @ m.T
    inputs = SessionInputs(time_s=t, rate_dps=rate_s, temp_c=temp, pressure_torr=pressure, power_on_s=t.copy(),
                           specific_force_g=force_s, table_angle_deg=np.mod(theta, 360.0))

    # ---- sensor ----
    if base is None:
        base = BaselineSensor.random(base_rng, rate_hz)
    elif isinstance(base, dict):
        base = BaselineSensor.from_dict(base)
    spec = None
    if model is not None:
        from bench.model.loader import load_sensor_model

        spec = load_sensor_model(model) if isinstance(model, (str, Path)) else model
    gyro = sensor_output(inputs, base, eff, noise_rng, rate_hz, spec, engine)
    if extra is not None:
        add = np.asarray(extra(inputs), dtype=float)
        if add.shape != gyro.shape:
            raise InputError(f"session extra: expected an array of shape {gyro.shape}, got {add.shape}")
        gyro = gyro + add
    if quantize_gyro_dps:
        gyro = np.round(gyro / quantize_gyro_dps) * quantize_gyro_dps
    accel = force_s + noise_rng.standard_normal((n, 3)) * noise_sigma(ACCEL_NOISE_DENSITY, rate_hz)

    cols: dict[str, np.ndarray] = {"time_s": t, "power_on_s": t.copy()}
    for j, a in enumerate(AXES):
        cols[REF_RATE[a]] = rate_s[:, j]
    cols["table_angle_deg"] = inputs.table_angle_deg
    cols["temp_c"] = temp
    cols["chamber_temp_c"] = air
    if pressure is not None:
        cols["pressure_torr"] = pressure
    for j, a in enumerate(AXES):
        cols[ACCEL[a]] = accel[:, j]
    for j, a in enumerate(AXES):
        cols[GYRO[a]] = gyro[:, j]
    meta: dict[str, float | str] = {"sample_rate_hz": float(rate_hz), "latitude_deg": float(latitude_deg),
                                    "session": kind}
    ds = Dataset(cols, meta, f"session:{kind}:{seed}")
    return Session(ds, base, eff, inputs, {"seed": seed, "kind": kind, "mount": mount, "thermal_speedup": k})


def simulate_session(duration_s: float = 3600.0, rate_hz: float = 1.0, effects: Sequence[dict[str, Any] | Effect] = (),
                     seed: int = 0, kind: str = "tvac", **kwargs: Any) -> Dataset:
    """:func:`make_session`'s dataset only (the measured data, no truth)."""
    return make_session(duration_s, rate_hz, effects, seed, kind, **kwargs).dataset


def write_csv(ds: Dataset, path: str | Path) -> Path:
    """Write ``ds`` as a measured-data CSV (``# key: value`` metadata, header, rows)."""
    p = Path(path)
    names = list(ds.columns)
    data = np.column_stack([ds.columns[c] for c in names])
    with open(p, "w", encoding="utf-8", newline="\n") as fh:
        for k, v in ds.meta.items():
            fh.write(f"# {k}: {v}\n")
        fh.write(",".join(names) + "\n")
        np.savetxt(fh, data, delimiter=",", fmt="%.10g")
    return p
