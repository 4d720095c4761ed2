"""Named physical error terms of a gyro, as forward functions: one place for simulator and analysis.

Each term of the ``bench diagnose`` vocabulary (``docs/diagnose.md``) is a small parameter
dataclass and a forward function giving the term's contribution to the gyro output (deg/s, (n, 3)
in the sensor frame). The simulator adds them to the sensor model's output
(:func:`apply_effects`, called by the gyro model for the ``effects:`` list of a sensor-model YAML);
``bench diagnose`` builds its candidate regressors from the same helpers (:func:`lagged`,
:func:`hysteresis_state`, :func:`pressure_transition`, :func:`delayed`,
:func:`earth_rate_sensor`), so a term fitted by the analysis and re-simulated is the same function.

Inputs are any object with the attributes of ``bench.model.inputs.SensorInputs`` (units in the
names): ``time_s`` (n,), ``rate_dps`` (n, 3) true rate in the sensor frame without Earth rate,
``temp_c`` (n,), ``pressure_torr`` (n,), ``power_on_s`` (n,), ``specific_force_g`` (n, 3),
``table_angle_deg`` (n,). An attribute a term needs but the inputs lack (``None``) raises
:class:`~bench.errors.InputError`.

An effect entry is ``{effect: NAME, axis: x|y|z|all, params: {...}}``. With ``axis: all`` a
per-axis term applies to the three axes; any scalar parameter may then be a list of three values
(x, y, z). ``earth_rate`` and ``time_skew`` act on all axes by nature (``axis: all``; a single axis
restricts them to that axis).

Vocabulary (equations in ``docs/diagnose.md``; defaults cite the seeds, [U] = assumed):

* ``thermal_lag``: the die temperature T_d is ``temp_c`` through a first-order lag τ; the bias
  polynomial p(T) = c1·(T−25) + c2·(T−25)² + c3·(T−25)³ is seen at T_d instead of T:
  contribution p(T_d) − p(T). Default τ = 390 s: the die read up to 4 °C off its thermocouple
  (NPSAT1 section IV.B.3) during 0.62 °C/min ramps (NPSAT1 App. B Table 1): 4/(0.62/60) ≈ 390 s;
  default c = slope and curvature at 25 °C of the ESTCube-2 MPU-6000 bias polynomial (Table 4.1,
  negated as in ``bench/model/imu_simple.py``).
* ``warmup_transient``: A·exp(−t_on/τ); defaults A = 0.019 deg/s, τ = 100 s (NPSAT1 IV.A, Z axis:
  0.019 deg/s change, settled after 5 min = 3τ).
* ``pressure_bias``: shift/(1 + (p/p0)^s): ``shift_dps`` in vacuum, 0 at ambient. Default shift
  0.03 deg/s (NPSAT1 section V summary, Z: "additional biases of ~0.03 deg/s when placed in
  vacuum"), p0 = 3e-4 Torr (Table 6: offsets constant from 1e-4 Torr down, different at 1e-3 Torr
  and above), s = 1 [U].
* ``gear_eccentricity``: the table rate is off by a fraction ε·sin(N·θ + φ) of itself (ESTCube-2
  section 4.3, "periodical noise ... at every speed ... a different period"), on the axis on the
  table: contribution ε·sin(N·θ + φ)·ω_axis. The seed gives no amplitude: default 0.
* ``g_sensitivity``: G·f, deg/s per g of specific force along sensor x, y, z. Default 0 [U].
* ``scale_factor_asymmetry``: a·|ω|: scale factor 1+a for positive, 1−a for negative rates. Default 0.
* ``scale_factor_tempco``: k·(T − T_ref)·ω, k per °C, T_ref = 25 °C. Default 0.
* ``hysteresis``: ±h by whether the temperature last rose or fell by more than a deadband
  (a play operator, 0 before the first such move); default h = 0.002 deg/s (NPSAT1 IV.C: path
  misalignment up to 0.004 deg/s between up and down ramps, so ±0.002), deadband 0.5 °C [U].
* ``time_skew``: the gyro sample at t shows the rate at t − d: contribution ω(t−d) − ω(t), ω
  interpolated by a cubic spline through the samples. Default 0.
* ``rate_random_walk``: bias b with increments N(0, K²·dt); default K = 2.7e-5 deg/s/√s (NPSAT1
  Table 13, X: 5.817 °/h/√h).
* ``earth_rate``: scale·Ω projected into the sensor frame: Ω(sin L·û + cos L·n̂), û the measured
  up (−gravity, i.e. the specific force direction), n̂ north: the table geometry of
  ``bench/sim/world.py`` (tilt about west, table angle 0 = platter x north, ``table_axis`` the
  sensor axis on the platter normal). Latitude default 36.4° (NPSAT1 IV.E, Monterey).
* ``bias_step``: the bias jumps by ``step_dps`` at ``t_step_s`` (IEEE Std 952 lists bias shifts
  among the errors to screen for; a connector re-seated, a latch-up). Default 0.
* ``periodic``: A·sin(2π·f·t + φ), periodic interference (NPSAT1 IV.G.3 names "sinusoidal error"
  among the Allan components). Default 0.
* ``scale_factor_nonlinearity``: k2·ω² + k3·ω³ (IEEE Std 1431 scale-factor nonlinearity). Default 0.
* ``bias_instability``: flicker bias noise, Allan plateau 0.664·B (IEEE Std 952 C.1.3), by the gyro
  model's sum of Gauss-Markov processes; default B = 1.92 deg/h (NPSAT1 Table 13, X).
* ``gauss_markov``: exponentially correlated (first-order Markov) bias noise of standard deviation σ
  and correlation time τ_c (IEEE Std 952 C.1.6 "correlated noise"; the hump of a MEMS Allan curve).
  Default σ = 0: the seeds give no amplitude.

A term is added in one place, :func:`register` (parameters, forward function, inputs); its
diagnose candidate joins with ``bench.analysis.diagnose.terms.register``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any, Callable, Protocol, Sequence

import numpy as np

from bench.errors import InputError
from bench.model.imu_simple import EARTH_RATE_DPS

AXES = ("x", "y", "z")
T_REF_C = 25.0
"""Reference temperature (°C) of the temperature-dependent terms."""


class InputsLike(Protocol):
    """What the effects read (``bench.model.inputs.SensorInputs`` satisfies it)."""

    time_s: np.ndarray
    rate_dps: np.ndarray
    temp_c: np.ndarray | None
    pressure_torr: np.ndarray | None
    power_on_s: np.ndarray | None
    specific_force_g: np.ndarray | None
    table_angle_deg: np.ndarray | None


# ---- parameter dataclasses ----------------------------------------------------------------------
@dataclass
class ThermalLagParams:
    """Die temperature = ``temp_c`` through a first-order lag; bias polynomial seen at the die."""

    tau_s: float = 390.0
    tempco_dps: list[float] = field(default_factory=lambda: [-1.318e-2, -1.124e-4, 0.0])
    """c1, c2, c3 of p(T) = Σ c_k·(T − 25 °C)^k (deg/s per °C^k)."""


@dataclass
class WarmupTransientParams:
    """Bias A·exp(−t_on/τ) after power-on."""

    amplitude_dps: float = 0.019
    tau_s: float = 100.0


@dataclass
class PressureBiasParams:
    """Bias shift in vacuum: shift/(1 + (p/p0)^slope)."""

    shift_dps: float = 0.03
    p0_torr: float = 3e-4
    slope: float = 1.0


@dataclass
class GearEccentricityParams:
    """Table rate error ε·sin(N·θ + φ) as a fraction of the rate, θ the table angle."""

    fraction: float = 0.0
    harmonic: int = 1
    phase_rad: float = 0.0


@dataclass
class GSensitivityParams:
    """Bias per g of specific force along sensor x, y, z (deg/s/g)."""

    dps_per_g: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])


@dataclass
class ScaleFactorAsymmetryParams:
    """Output += a·|ω|: scale factor (1 + a) for positive, (1 − a) for negative rates."""

    asymmetry: float = 0.0


@dataclass
class ScaleFactorTempcoParams:
    """Output += k·(T − T_ref)·ω (k per °C)."""

    tempco_per_c: float = 0.0
    t_ref_c: float = T_REF_C


@dataclass
class HysteresisParams:
    """Bias +h after the temperature rose by more than the deadband, −h after it fell."""

    amplitude_dps: float = 0.002
    deadband_c: float = 0.5


@dataclass
class TimeSkewParams:
    """Gyro samples show the rate ``delay_s`` earlier than their time stamp (s; > 0: gyro late)."""

    delay_s: float = 0.0


@dataclass
class RateRandomWalkParams:
    """Bias random walk: increments N(0, K²·dt) (K in deg/s/√s)."""

    k_dps_per_sqrt_s: float = 2.7e-5


@dataclass
class EarthRateParams:
    """Earth's rotation in the sensor frame, at ``latitude_deg``, times ``scale``."""

    latitude_deg: float = 36.4
    scale: float = 1.0
    table_axis: str = "z"


@dataclass
class BiasStepParams:
    """The bias jumps by ``step_dps`` at ``t_step_s`` (s of the session's time axis) and stays."""

    step_dps: float = 0.0
    t_step_s: float = 0.0


@dataclass
class PeriodicParams:
    """Periodic interference A·sin(2π·f·t + φ) (deg/s, Hz, rad): a fan, a pump, a supply ripple."""

    amplitude_dps: float = 0.0
    frequency_hz: float = 0.01
    phase_rad: float = 0.0


@dataclass
class ScaleFactorNonlinearityParams:
    """Output += k2·ω² + k3·ω³ (IEEE Std 1431 scale-factor nonlinearity; k2 per deg/s, k3 per (deg/s)²)."""

    quadratic_per_dps: float = 0.0
    cubic_per_dps2: float = 0.0


@dataclass
class BiasInstabilityParams:
    """Flicker (1/f) bias noise of coefficient B (deg/s; Allan plateau 0.664·B, IEEE Std 952 C.1.3),
    between correlation times ``tau_min_s`` and ``tau_max_s``. Default B: NPSAT1 Table 13 X,
    1.92 deg/h."""

    b_dps: float = 1.92 / 3600.0
    tau_min_s: float = 1.0
    tau_max_s: float = 1.0e4


@dataclass
class GaussMarkovParams:
    """First-order Gauss-Markov bias noise: variance ``sigma_dps``², correlation e^(−|Δt|/τ_c)."""

    sigma_dps: float = 0.0
    tau_s: float = 100.0


PARAMS: dict[str, type] = {
    "thermal_lag": ThermalLagParams,
    "warmup_transient": WarmupTransientParams,
    "pressure_bias": PressureBiasParams,
    "gear_eccentricity": GearEccentricityParams,
    "g_sensitivity": GSensitivityParams,
    "scale_factor_asymmetry": ScaleFactorAsymmetryParams,
    "scale_factor_tempco": ScaleFactorTempcoParams,
    "hysteresis": HysteresisParams,
    "time_skew": TimeSkewParams,
    "rate_random_walk": RateRandomWalkParams,
    "earth_rate": EarthRateParams,
    "bias_step": BiasStepParams,
    "periodic": PeriodicParams,
    "scale_factor_nonlinearity": ScaleFactorNonlinearityParams,
    "bias_instability": BiasInstabilityParams,
    "gauss_markov": GaussMarkovParams,
}
"""The vocabulary: effect name -> parameter dataclass (grown with :func:`register`)."""

VOCABULARY: tuple[str, ...] = tuple(PARAMS)

NEEDS: dict[str, tuple[str, ...]] = {
    "thermal_lag": ("temp_c",),
    "warmup_transient": ("power_on_s",),
    "pressure_bias": ("pressure_torr",),
    "gear_eccentricity": ("table_angle_deg",),
    "g_sensitivity": ("specific_force_g",),
    "scale_factor_asymmetry": (),
    "scale_factor_tempco": ("temp_c",),
    "hysteresis": ("temp_c",),
    "time_skew": (),
    "rate_random_walk": (),
    "earth_rate": ("specific_force_g",),
    "bias_step": (),
    "periodic": (),
    "scale_factor_nonlinearity": (),
    "bias_instability": (),
    "gauss_markov": (),
}
"""Input attributes each effect reads besides ``time_s`` and ``rate_dps``."""

SHARED = frozenset({"earth_rate", "time_skew"})
"""Effects that act on all axes with one set of parameters (``axis: all`` by default)."""


# ---- shared helpers (simulator and analysis) ----------------------------------------------------
def lagged(time_s: np.ndarray, x: np.ndarray, tau_s: float) -> np.ndarray:
    """``x`` through a first-order lag of time constant ``tau_s`` (s), starting at ``x[0]``.

    Exact for ``x`` held between samples; uses the median sample interval (uniform sampling)."""
    x = np.asarray(x, dtype=float)
    if x.size == 0 or tau_s <= 0:
        return x.copy()
    dt = float(np.median(np.diff(time_s))) if x.size > 1 else 1.0
    a = math.exp(-dt / tau_s)
    from scipy.signal import lfilter  # here, not at the top: importing scipy.signal takes ~1 s (every bench process)

    y, _ = lfilter([1.0 - a], [1.0, -a], x, zi=[a * x[0]])
    return y


def hysteresis_state(temp_c: np.ndarray, deadband_c: float) -> np.ndarray:
    """Play operator on temperature: +1 after a rise of more than ``deadband_c`` (°C) from the last
    turning point, −1 after such a fall, 0 before the first one. (n,) float."""
    x = np.asarray(temp_c, dtype=float)
    out = np.zeros(x.size)
    if x.size == 0:
        return out
    d = max(float(deadband_c), 0.0)
    state, start = 0.0, 0
    lo = hi = float(x[0])
    for i, v in enumerate(x.tolist()):
        if v > hi:
            hi = v
        if v < lo:
            lo = v
        if state >= 0.0 and v < hi - d:
            out[start:i] = state
            state, start, lo = -1.0, i, v
        elif state <= 0.0 and v > lo + d:
            out[start:i] = state
            state, start, hi = 1.0, i, v
    out[start:] = state
    return out


def pressure_transition(pressure_torr: np.ndarray, p0_torr: float, slope: float = 1.0) -> np.ndarray:
    """1/(1 + (p/p0)^slope): 1 in vacuum (p ≪ p0), 0 at ambient (p ≫ p0). Dimensionless."""
    p = np.clip(np.asarray(pressure_torr, dtype=float), 1e-12, None)
    z = slope * (np.log(p) - math.log(p0_torr))
    return 0.5 * (1.0 - np.tanh(0.5 * z))  # = 1/(1+exp(z)), overflow-free


def delayed(time_s: np.ndarray, x: np.ndarray, delay_s: float) -> np.ndarray:
    """``x`` (n,) or (n, k) at times ``time_s − delay_s`` by a cubic spline through the samples
    (held at the ends)."""
    from scipy.interpolate import CubicSpline

    x = np.asarray(x, dtype=float)
    if delay_s == 0.0 or x.shape[0] < 4:
        return x.copy()
    t = np.asarray(time_s, dtype=float)
    tq = np.clip(t - delay_s, t[0], t[-1])
    return CubicSpline(t, x, axis=0)(tq)


def rate_derivative(time_s: np.ndarray, x: np.ndarray) -> np.ndarray:
    """d``x``/dt of the cubic spline through the samples (units of x per s)."""
    from scipy.interpolate import CubicSpline

    x = np.asarray(x, dtype=float)
    if x.shape[0] < 4:
        return np.zeros_like(x)
    return CubicSpline(np.asarray(time_s, dtype=float), x, axis=0)(time_s, 1)


def mount_matrix(up: str) -> np.ndarray:
    """Sensor-from-platter rotation for sensor axis ``up`` along the platter normal
    (:func:`bench.model.geometry.mount_matrix`); a bad axis is an input error."""
    from bench.model.geometry import mount_matrix as _mm

    try:
        return _mm(up)
    except ValueError as exc:
        raise InputError(f"earth_rate: table_axis: {exc}") from None


def earth_rate_sensor(specific_force_g: np.ndarray, table_angle_deg: np.ndarray | None,
                      latitude_deg: float, table_axis: str = "z") -> np.ndarray:
    """Earth rate (deg/s, (n, 3)) in the sensor frame of a unit on the tilt/rotate table of
    ``bench/sim/world.py``: up from the specific force, the tilt about west recovered from it,
    north from the tilt and the table angle (0 = platter x north)."""
    f = np.asarray(specific_force_g, dtype=float)
    n = f.shape[0]
    m = mount_matrix(table_axis)
    u = f / np.maximum(np.linalg.norm(f, axis=1, keepdims=True), 1e-9)
    up = u @ m  # platter frame (rows: mᵀ u)
    th = np.zeros(n) if table_angle_deg is None else np.radians(np.asarray(table_angle_deg, dtype=float))
    c, s = np.cos(th), np.sin(th)
    ax = c * up[:, 0] - s * up[:, 1]  # tilted frame: Rz(θ)·u_p, x and z components
    az = up[:, 2]
    norm = np.maximum(np.hypot(ax, az), 1e-9)
    ax, az = ax / norm, az / norm
    lat = math.radians(latitude_deg)
    ex = EARTH_RATE_DPS * (math.sin(lat) * ax + math.cos(lat) * az)
    ez = EARTH_RATE_DPS * (math.sin(lat) * az - math.cos(lat) * ax)
    ep = np.stack([c * ex, -s * ex, ez], axis=1)  # back to the platter frame: Rz(θ)ᵀ·e_t
    return ep @ m.T


# ---- effect objects ----------------------------------------------------------------------------
@dataclass
class Effect:
    """One effect entry: ``name`` from :data:`VOCABULARY`, ``axis`` x/y/z/all, ``params`` a dict of
    the effect's parameters (scalars, or 3-lists per axis with ``axis: all``)."""

    name: str
    axis: str
    params: dict[str, Any]

    def as_dict(self) -> dict[str, Any]:
        """The YAML form ``{effect, axis, params}``."""
        return {"effect": self.name, "axis": self.axis, "params": _plain(self.params)}

    def axis_params(self, k: int) -> Any:
        """The parameter dataclass for sensor axis ``k`` (0, 1, 2)."""
        cls = PARAMS[self.name]
        vals = {}
        for f in fields(cls):
            if f.name not in self.params:
                continue
            v = self.params[f.name]
            if self.axis == "all" and isinstance(v, (list, tuple)) and len(v) == 3 and not _is_vector_field(self.name, f.name):
                v = v[k]
            elif (self.axis == "all" and _is_vector_field(self.name, f.name) and isinstance(v, (list, tuple))
                  and len(v) == 3 and isinstance(v[0], (list, tuple))):
                v = list(v[k])
            vals[f.name] = v
        return cls(**vals)

    @property
    def axes(self) -> list[int]:
        """Sensor axes (0, 1, 2) the effect acts on."""
        return [0, 1, 2] if self.axis == "all" else [AXES.index(self.axis)]

    def contribution(self, inputs: InputsLike, rng: np.random.Generator | None = None) -> np.ndarray:
        """The effect's contribution to the gyro output, deg/s, (n, 3)."""
        t = np.asarray(inputs.time_s, dtype=float)
        n = t.shape[0]
        for need in NEEDS[self.name]:
            if getattr(inputs, need, None) is None:
                raise InputError(f"effect {self.name} needs the sensor input {need}, which this simulation does not provide")
        out = np.zeros((n, 3))
        if self.name == "earth_rate":
            p = self.axis_params(0)
            e = earth_rate_sensor(inputs.specific_force_g, inputs.table_angle_deg, p.latitude_deg, p.table_axis) * p.scale
            for k in self.axes:
                out[:, k] = e[:, k]
            return out
        if self.name == "time_skew":
            rate = np.asarray(inputs.rate_dps, dtype=float)
            for k in self.axes:
                d = self.axis_params(k).delay_s
                out[:, k] = delayed(t, rate[:, k], d) - rate[:, k]
            return out
        for k in self.axes:
            out[:, k] = _FORWARD[self.name](self.axis_params(k), inputs, k, t, rng)
        return out


def _is_vector_field(name: str, field_name: str) -> bool:
    return (name, field_name) in {("g_sensitivity", "dps_per_g"), ("thermal_lag", "tempco_dps")}


def _plain(v: Any) -> Any:
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, np.ndarray)):
        return [_plain(x) for x in v]
    if isinstance(v, (np.floating, float)):
        return float(v)
    if isinstance(v, (np.integer,)):
        return int(v)
    return v


def _temp(inp: InputsLike, k: int) -> np.ndarray:
    """Temperature channel of axis ``k`` (°C): ``temp_c`` is (n,) or one channel per axis (n, 3)."""
    t = np.asarray(inp.temp_c, dtype=float)
    return t[:, k] if t.ndim == 2 else t


def _poly_at(temp_c: np.ndarray, coeffs: Sequence[float]) -> np.ndarray:
    u = np.asarray(temp_c, dtype=float) - T_REF_C
    out = np.zeros_like(u)
    for k, c in enumerate(coeffs, start=1):
        out += float(c) * u ** k
    return out


def _thermal_lag(p: ThermalLagParams, inp: InputsLike, k: int, t: np.ndarray, rng) -> np.ndarray:
    temp = _temp(inp, k)
    return _poly_at(lagged(t, temp, p.tau_s), p.tempco_dps) - _poly_at(temp, p.tempco_dps)


def _warmup(p: WarmupTransientParams, inp: InputsLike, k: int, t: np.ndarray, rng) -> np.ndarray:
    return p.amplitude_dps * np.exp(-np.clip(np.asarray(inp.power_on_s, dtype=float), 0.0, None) / p.tau_s)


def _pressure(p: PressureBiasParams, inp: InputsLike, k: int, t: np.ndarray, rng) -> np.ndarray:
    return p.shift_dps * pressure_transition(inp.pressure_torr, p.p0_torr, p.slope)


def _gear(p: GearEccentricityParams, inp: InputsLike, k: int, t: np.ndarray, rng) -> np.ndarray:
    th = np.radians(np.asarray(inp.table_angle_deg, dtype=float))
    return p.fraction * np.sin(p.harmonic * th + p.phase_rad) * np.asarray(inp.rate_dps, dtype=float)[:, k]


def _gsens(p: GSensitivityParams, inp: InputsLike, k: int, t: np.ndarray, rng) -> np.ndarray:
    return np.asarray(inp.specific_force_g, dtype=float) @ np.asarray(p.dps_per_g, dtype=float)


def _sf_asym(p: ScaleFactorAsymmetryParams, inp: InputsLike, k: int, t: np.ndarray, rng) -> np.ndarray:
    return p.asymmetry * np.abs(np.asarray(inp.rate_dps, dtype=float)[:, k])


def _sf_tempco(p: ScaleFactorTempcoParams, inp: InputsLike, k: int, t: np.ndarray, rng) -> np.ndarray:
    return p.tempco_per_c * (_temp(inp, k) - p.t_ref_c) * np.asarray(inp.rate_dps, dtype=float)[:, k]


def _hyst(p: HysteresisParams, inp: InputsLike, k: int, t: np.ndarray, rng) -> np.ndarray:
    return p.amplitude_dps * hysteresis_state(_temp(inp, k), p.deadband_c)


def _rrw(p: RateRandomWalkParams, inp: InputsLike, k: int, t: np.ndarray, rng) -> np.ndarray:
    rng = rng if rng is not None else np.random.default_rng()
    dt = np.diff(t, prepend=t[0])
    return np.cumsum(rng.standard_normal(t.shape[0]) * p.k_dps_per_sqrt_s * np.sqrt(dt))


def _bias_step(p: BiasStepParams, inp: InputsLike, k: int, t: np.ndarray, rng) -> np.ndarray:
    return p.step_dps * (t >= p.t_step_s)


def _periodic(p: PeriodicParams, inp: InputsLike, k: int, t: np.ndarray, rng) -> np.ndarray:
    return p.amplitude_dps * np.sin(2.0 * math.pi * p.frequency_hz * t + p.phase_rad)


def _sf_nonlinear(p: ScaleFactorNonlinearityParams, inp: InputsLike, k: int, t: np.ndarray, rng) -> np.ndarray:
    w = np.asarray(inp.rate_dps, dtype=float)[:, k]
    return p.quadratic_per_dps * w * w + p.cubic_per_dps2 * w ** 3


def flicker_noise(t: np.ndarray, b_dps: float, tau_min_s: float, tau_max_s: float,
                  rng: np.random.Generator) -> np.ndarray:
    """Flicker (1/f) noise of bias-instability coefficient B (deg/s) at sample times ``t`` (s).

    The gyro model's Gauss-Markov sum (:func:`bench.model.gyro.flicker_processes`: correlation
    times two per decade between ``tau_min_s`` and ``tau_max_s``, each of variance B²·ln r/π), whose
    Lorentzian spectra add up to the one-sided 1/f spectrum B²/(2π f) of IEEE Std 952 C.1.3: the
    Allan deviation is flat at 0.664·B for averaging times between about 2·tau_min and tau_max/2."""
    from bench.model.gyro import flicker_processes

    t = np.asarray(t, dtype=float)
    n = t.shape[0]
    out = np.zeros(n)
    if n == 0 or b_dps == 0:
        return out
    taus, per_b = flicker_processes(tau_min_s, tau_max_s)
    q = abs(b_dps) * per_b
    for tc in taus:
        out += gauss_markov_noise(t, q, float(tc), rng)  # each from its stationary start
    return out * (1.0 if b_dps > 0 else -1.0)


def _bias_instability(p: BiasInstabilityParams, inp: InputsLike, k: int, t: np.ndarray, rng) -> np.ndarray:
    rng = rng if rng is not None else np.random.default_rng()
    return flicker_noise(t, p.b_dps, p.tau_min_s, p.tau_max_s, rng)


def gauss_markov_noise(t: np.ndarray, sigma_dps: float, tau_s: float, rng: np.random.Generator) -> np.ndarray:
    """A stationary first-order Gauss-Markov process of standard deviation ``sigma_dps`` and
    correlation time ``tau_s`` at sample times ``t`` (exact AR(1) at the median interval)."""
    t = np.asarray(t, dtype=float)
    n = t.shape[0]
    if n == 0 or sigma_dps == 0:
        return np.zeros(n)
    dt = float(np.median(np.diff(t))) if n > 1 else 1.0
    a = math.exp(-dt / tau_s)
    w = rng.standard_normal(n) * sigma_dps * math.sqrt(1.0 - a * a)
    w[0] = rng.standard_normal() * sigma_dps
    from scipy.signal import lfilter  # here, not at the top: importing scipy.signal takes ~1 s (every bench process)

    return lfilter([1.0], [1.0, -a], w)


def _gauss_markov(p: GaussMarkovParams, inp: InputsLike, k: int, t: np.ndarray, rng) -> np.ndarray:
    rng = rng if rng is not None else np.random.default_rng()
    return gauss_markov_noise(t, p.sigma_dps, p.tau_s, rng)


_FORWARD: dict[str, Callable[..., np.ndarray]] = {
    "thermal_lag": _thermal_lag,
    "warmup_transient": _warmup,
    "pressure_bias": _pressure,
    "gear_eccentricity": _gear,
    "g_sensitivity": _gsens,
    "scale_factor_asymmetry": _sf_asym,
    "scale_factor_tempco": _sf_tempco,
    "hysteresis": _hyst,
    "rate_random_walk": _rrw,
    "bias_step": _bias_step,
    "periodic": _periodic,
    "scale_factor_nonlinearity": _sf_nonlinear,
    "bias_instability": _bias_instability,
    "gauss_markov": _gauss_markov,
}


def register(name: str, params: type, forward: Callable[..., np.ndarray], needs: tuple[str, ...] = ()) -> None:
    """Add a term to the vocabulary: ``params`` a dataclass of its parameters (defaults cited),
    ``forward(p, inputs, k, time_s, rng) -> (n,)`` its contribution to axis ``k`` in deg/s,
    ``needs`` the input attributes it reads. The simulator (``effects:`` of a sensor model) applies
    it from then on; ``bench.analysis.diagnose.terms.register`` adds its candidate for diagnose."""
    if not name or not name.replace("_", "").isalnum():
        raise ValueError(f"effect name must be an identifier, got {name!r}")
    if name in PARAMS and PARAMS[name] is not params:
        raise ValueError(f"effect {name!r} is already in the vocabulary")
    PARAMS[name] = params
    NEEDS[name] = tuple(needs)
    _FORWARD[name] = forward
    global VOCABULARY
    VOCABULARY = tuple(PARAMS)


# ---- parsing and validation ---------------------------------------------------------------------
def parse_effect(entry: dict[str, Any] | Effect, where: str = "effects") -> Effect:
    """One ``{effect, axis, params}`` mapping as a validated :class:`Effect`; :class:`InputError`
    names the entry and the problem."""
    if isinstance(entry, Effect):
        entry = entry.as_dict()
    if not isinstance(entry, dict):
        raise InputError(f"{where}: expected a mapping {{effect, axis, params}}, got {type(entry).__name__}")
    unknown = set(entry) - {"effect", "axis", "params", "source", "description"}
    if unknown:
        raise InputError(f"{where}: unknown key(s) {', '.join(sorted(unknown))} (expected effect, axis, params, source, description)")
    name = entry.get("effect")
    if name not in PARAMS:
        raise InputError(f"{where}: unknown effect {name!r}; the vocabulary is {', '.join(VOCABULARY)}")
    axis = str(entry.get("axis", "all")).lower()
    if axis not in (*AXES, "all"):
        raise InputError(f"{where}: {name}: axis must be x, y, z or all, got {entry.get('axis')!r}")
    params = entry.get("params") or {}
    if not isinstance(params, dict):
        raise InputError(f"{where}: {name}: params must be a mapping, got {type(params).__name__}")
    names = {f.name for f in fields(PARAMS[name])}
    bad = set(params) - names
    if bad:
        raise InputError(f"{where}: {name}: unknown parameter(s) {', '.join(sorted(bad))} (known: {', '.join(sorted(names))})")
    eff = Effect(name, axis, dict(params))
    for k in eff.axes:
        try:
            _check(name, eff.axis_params(k))
        except (TypeError, ValueError) as exc:
            raise InputError(f"{where}: {name} ({axis}): {exc}") from None
    return eff


def _num(name: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not math.isfinite(float(v)):
        raise ValueError(f"{name} must be a finite number, got {v!r}")
    return float(v)


def _check(name: str, p: Any) -> None:
    for f in fields(p):
        v = getattr(p, f.name)
        if f.name in ("tempco_dps", "dps_per_g"):
            if not isinstance(v, (list, tuple)) or len(v) != 3:
                raise ValueError(f"{f.name} must be a list of 3 numbers, got {v!r}")
            for x in v:
                _num(f.name, x)
        elif f.name == "table_axis":
            if str(v).lstrip("+-") not in AXES:
                raise ValueError(f"table_axis must be x, y, z, -x, -y or -z, got {v!r}")
        else:
            _num(f.name, v)
    if name in ("thermal_lag", "warmup_transient") and not p.tau_s > 0:
        raise ValueError(f"tau_s must be > 0 s, got {p.tau_s!r}")
    if name == "pressure_bias" and not (p.p0_torr > 0 and p.slope > 0):
        raise ValueError("p0_torr and slope must be > 0")
    if name == "gear_eccentricity":
        if int(p.harmonic) != p.harmonic or p.harmonic < 1:
            raise ValueError(f"harmonic must be an integer >= 1, got {p.harmonic!r}")
        if not abs(p.fraction) < 1:
            raise ValueError(f"fraction must be below 1 in magnitude, got {p.fraction!r}")
    if name == "hysteresis" and p.deadband_c < 0:
        raise ValueError("deadband_c must be >= 0 °C")
    if name == "rate_random_walk" and p.k_dps_per_sqrt_s < 0:
        raise ValueError("k_dps_per_sqrt_s must be >= 0")
    if name == "periodic" and not p.frequency_hz > 0:
        raise ValueError(f"frequency_hz must be > 0 Hz, got {p.frequency_hz!r}")
    if name == "gauss_markov" and not (p.tau_s > 0 and p.sigma_dps >= 0):
        raise ValueError("gauss_markov needs tau_s > 0 s and sigma_dps >= 0")
    if name == "bias_instability" and not 0 < p.tau_min_s < p.tau_max_s:
        raise ValueError("tau_min_s and tau_max_s must satisfy 0 < tau_min_s < tau_max_s")
    if name == "earth_rate" and not -90 <= p.latitude_deg <= 90:
        raise ValueError(f"latitude_deg must be within ±90°, got {p.latitude_deg!r}")


def parse_effects(entries: Sequence[dict[str, Any] | Effect] | None) -> list[Effect]:
    """A validated list of effects from the ``effects:`` list of a sensor model (``None`` = none)."""
    if entries is None:
        return []
    if not isinstance(entries, (list, tuple)):
        raise InputError(f"effects: expected a list, got {type(entries).__name__}")
    return [parse_effect(e, f"effects[{i}]") for i, e in enumerate(entries)]


def apply_effects(effects: Sequence[dict[str, Any] | Effect] | None, inputs: InputsLike, output_dps: np.ndarray,
                  rng: np.random.Generator | None = None) -> np.ndarray:
    """``output_dps`` (n, 3) plus every effect's contribution (deg/s); a new array."""
    out = np.array(output_dps, dtype=float, copy=True)
    for eff in parse_effects(effects):
        out += eff.contribution(inputs, rng)
    return out


def default_params(name: str) -> dict[str, Any]:
    """The default parameters of effect ``name`` as a plain dict."""
    if name not in PARAMS:
        raise InputError(f"unknown effect {name!r}; the vocabulary is {', '.join(VOCABULARY)}")
    return _plain(asdict(PARAMS[name]()))
