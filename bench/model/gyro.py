"""Gyro error model of the NPSAT1 thesis (seed 000), Eq. (1)-(3), vectorised over samples.

Forward model (what the sensor outputs for a true rate), per sample, vector form (X, Y, Z)::

    I = ω + b_cons + b_run-to-run + b_in-run(T, P) + M·ω + ε            (Eq. 1, 2; M Eq. 3)
          + b_two-level(T, ω) + G·f + A·exp(−t_on/τ) + R·t_on             (extensions, below)

* ω: the true rate in the sensor frame, deg/s, **including Earth rate** — the caller supplies it
  (:class:`bench.model.inputs.SensorInputs`); the model adds no Earth rate.
* b_cons: constant bias, deg/s (Table 15 / IV.E "b_no ref").
* b_run-to-run: repeatability bias, drawn once per power-on from N(0, σ²) per axis
  ("errors of up to ~0.016 °/sec have been observed to occur at random", Table 14).
* b_in-run(T, P) = poly(T) + pressure term. poly is a polynomial per axis in ascending powers
  (B, m₁, m₂, m₃: "y = B + m₁T + m₂T² + m₃T³", section IV.C.c), either in °C → deg/s (Tables 4,
  8) or, with ``in_run_poly_variable: temp_channel_v``, in temperature-channel volts → rate-channel
  volts (Tables 3, 7, 15) converted with the ideal S_f (Eq. 8) and T_m from Eq. (10)-(12)
  (:mod:`bench.model.adc`). Pressure term (Table 6, IV.D.2: vacuum acts as a fixed offset below
  ~1e-4 Torr and "much of the output changes are expected to be seen at higher pressures")::

      b_P(P) = Δ_vac · (w(P) − w(P_ref)),   w(P) = 1 / (1 + P / P_t)

  w goes smoothly from 1 (vacuum) to 0 (P ≫ P_t). P_ref is the pressure the polynomial was fitted
  at (760 Torr for the ground polynomials, vacuum for the spacecraft ones, whose B already holds
  the vacuum shift, IV.D.3.b).
* M: scale-factor errors on the diagonal, misalignments off it, in percent (Eq. 3, Table 15:
  "converted to ... % for M"). Applied as the matrix product M·ω of Eq. (2)/(3).
* ε: noise, stateful across calls (:class:`GyroModel`):
  - angle random walk N (deg/√h, Table 13): white rate noise of σ = N/√Δt per sample, Δt the
    sample period, so the Allan deviation is N/√τ (Eq. 21);
  - bias instability B (deg/h, Table 13): flicker noise approximated by a sum of first-order
    Gauss-Markov processes with correlation times log-spaced over [τ_min, τ_max]
    (``bias_instability_per_decade`` per decade, ratio r). Each has variance B²·ln(r)/π, which
    makes the summed two-sided PSD ≈ B²/(2πf) inside the band, i.e. the IEEE Std 952 flicker
    term with the Allan plateau 0.664·B (Eq. 22) for τ_min ≪ τ ≪ τ_max;
  - rate random walk K (deg/h/√h): a random walk of the bias, σ(τ) = K·√(τ/3); reset at power-on;
  - rate ramp R (deg/h per h, Table 13 "+1 slope"): deterministic R·t_on, σ(τ) = R·τ/√2 (Eq. 23).
* b_two-level(T, ω): the ESTCube-2 two-level calibration (seed 004, Table 4.1, Eq. 4.1):
  pᵢ(ω) = aᵢω² + bᵢω + cᵢ (a row of Table 4.1), correction(T) = p₁T² + p₂T + p₃ is "the offset
  which needs to be added to the taken measurement", so the bias is −correction (ω in deg/s of
  that axis, T in °C).
* G·f: g-sensitivity, deg/s per g (3×3), f the specific force (g); QRS11 datasheet ≤ 0.02
  deg/s/g (NPSAT1 Appendix A), zero unless configured.
* A·exp(−t_on/τ): warm-up transient on the time since power-on (NPSAT1 IV.A).

Output paths (``output``): ``none`` (physical deg/s), ``adc`` (NPSAT1 12-bit ADC, Eq. 4-8:
encode then decode, :mod:`bench.model.adc`) or ``digital`` (16-bit counts and a moving average,
ESTCube-2 section 3.3, :mod:`bench.model.digital`).

Extra physical terms found by the discrepancy engine (``effects:`` in a model file) are applied by
:func:`bench.model.effects.apply_effects` to the physical output, before the output path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np

from bench.model import adc as adc_mod
from bench.model import digital as dig_mod
from bench.model.adc import AdcParams
from bench.model.digital import DigitalParams, MovingAverage
from bench.model.inputs import AMBIENT_PRESSURE_TORR, SensorInputs

AXES = ("x", "y", "z")
OUTPUTS = ("none", "adc", "digital")
POLY_VARIABLES = ("temp_c", "temp_channel_v")

DPH = 1.0 / 3600.0
"""deg/s per deg/h."""
ARW_UNIT = 1.0 / 60.0
"""deg/√s per deg/√h (√3600 = 60)."""
RRW_UNIT = 1.0 / (3600.0 * 60.0)
"""deg/s/√s per deg/h/√h."""
RAMP_UNIT = 1.0 / 3600.0**2
"""deg/s² per deg/h/h."""


def _zeros3() -> list[float]:
    return [0.0, 0.0, 0.0]


def _zeros33() -> list[list[float]]:
    return [[0.0, 0.0, 0.0] for _ in range(3)]


@dataclass
class GyroModelParams:
    """Parameters of the gyro error model (units in the names; x, y, z order).

    Defaults are "no error" (zeros), except the physical constants of the pressure transition and
    the bias-instability band, whose sources are noted. Model files (``configs/sensors/*.yaml``)
    give the published values with citations.
    """

    b_cons_dps: list[float] = field(default_factory=_zeros3)
    run_to_run_sigma_dps: list[float] = field(default_factory=_zeros3)
    in_run_poly: list[list[float]] = field(default_factory=lambda: [[0.0], [0.0], [0.0]])
    """Per axis, ascending powers [B, m1, m2, m3]; units set by ``in_run_poly_variable``:
    ``temp_c``: deg/s vs °C; ``temp_channel_v``: rate-channel V vs temperature-channel V."""
    in_run_poly_variable: str = "temp_c"
    pressure_shift_vacuum_dps: list[float] = field(default_factory=_zeros3)
    """Δ_vac: bias in vacuum minus bias at ambient, deg/s (NPSAT1 Table 6 / S_f)."""
    pressure_transition_torr: float = 200.0
    """P_t of w(P) = 1/(1 + P/P_t). [U] order-of-magnitude estimate: NPSAT1 Table 5 (Z at
    190-250 Torr, ambient-compensated, 0.025 deg/s) is about half the Table 6 vacuum shift."""
    pressure_reference_torr: float = AMBIENT_PRESSURE_TORR
    """Pressure at which ``in_run_poly`` was fitted (b_P = 0 there)."""
    misalignment_pct: list[list[float]] = field(default_factory=_zeros33)
    """M of Eq. (3) in percent: diagonal S (scale-factor error), off-diagonal m (misalignment)."""
    two_level_correction: dict[str, list[list[float]]] = field(default_factory=dict)
    """ESTCube-2 Table 4.1 per axis ('x'/'y'/'z' → 3×3 rows p1, p2, p3 of [ω², ω, 1] coefficients);
    the correction is added to a measurement, so the model's bias is its negative."""
    g_sensitivity_dps_per_g: list[list[float]] = field(default_factory=_zeros33)
    warmup_amplitude_dps: list[float] = field(default_factory=_zeros3)
    warmup_tau_s: list[float] = field(default_factory=lambda: [1.0, 1.0, 1.0])
    arw_deg_rth: list[float] = field(default_factory=_zeros3)
    bias_instability_dph: list[float] = field(default_factory=_zeros3)
    bias_instability_tau_range_s: list[float] = field(default_factory=lambda: [1.0, 1.0e4])
    """[τ_min, τ_max] of the Gauss-Markov sum. [U] modelling choice: spans the NPSAT1 Allan plots
    (2-hour records, Fig. 64, cluster times up to ~1e3-1e4 s)."""
    bias_instability_per_decade: int = 2
    """Gauss-Markov processes per decade of correlation time (2: PSD ripple < ±10 %)."""
    rrw_deg_h_rth: list[float] = field(default_factory=_zeros3)
    rate_ramp_dph_per_h: list[float] = field(default_factory=_zeros3)
    output: str = "none"
    adc: AdcParams = field(default_factory=AdcParams)
    digital: DigitalParams = field(default_factory=DigitalParams)

    def m_matrix(self) -> np.ndarray:
        """M as a fraction (3, 3)."""
        return np.asarray(self.misalignment_pct, dtype=float) / 100.0


# ---- deterministic terms ------------------------------------------------------------------------
def in_run_temperature_bias_dps(p: GyroModelParams, temp_c: np.ndarray) -> np.ndarray:
    """poly(T) of b_in-run (n, 3) in deg/s for temperatures ``temp_c`` (n,) or (n, 3), °C."""
    t = np.asarray(temp_c, dtype=float)
    t3 = t if t.ndim == 2 else np.repeat(np.atleast_1d(t)[:, None], 3, axis=1)
    if p.in_run_poly_variable == "temp_channel_v":
        x = adc_mod.temp_c_to_channel_v(t3, p.adc)
        scale = 1.0 / p.adc.scale_factor_v_per_dps  # rate-channel volts → deg/s, Eq. (8)
    else:
        x, scale = t3, 1.0
    out = np.empty_like(x)
    for a in range(3):
        out[:, a] = np.polynomial.polynomial.polyval(x[:, a], np.asarray(p.in_run_poly[a], dtype=float)) * scale
    return out


def vacuum_weight(pressure_torr: np.ndarray, transition_torr: float) -> np.ndarray:
    """w(P) = 1/(1 + P/P_t): 1 in vacuum, 0 well above P_t (dimensionless)."""
    return 1.0 / (1.0 + np.asarray(pressure_torr, dtype=float) / transition_torr)


def pressure_bias_dps(p: GyroModelParams, pressure_torr: np.ndarray) -> np.ndarray:
    """Pressure part of b_in-run (n, 3), deg/s: Δ_vac·(w(P) − w(P_ref))."""
    w = vacuum_weight(pressure_torr, p.pressure_transition_torr) - vacuum_weight(p.pressure_reference_torr, p.pressure_transition_torr)
    return np.atleast_1d(w)[:, None] * np.asarray(p.pressure_shift_vacuum_dps, dtype=float)


def two_level_bias_dps(p: GyroModelParams, rate_dps: np.ndarray, temp_c: np.ndarray) -> np.ndarray:
    """ESTCube-2 Table 4.1 bias (n, 3), deg/s: −(p1(ω)T² + p2(ω)T + p3(ω)) on the configured axes."""
    rate = np.asarray(rate_dps, dtype=float)
    t = np.asarray(temp_c, dtype=float)
    t3 = t if t.ndim == 2 else np.repeat(t[:, None], 3, axis=1)
    out = np.zeros_like(rate)
    for axis, rows in p.two_level_correction.items():
        a = AXES.index(axis)
        w = rate[:, a]
        coef = [np.polyval(np.asarray(r, dtype=float), w) for r in rows]  # p1, p2, p3 (Eq. 4.1 in ω)
        out[:, a] = -(coef[0] * t3[:, a] ** 2 + coef[1] * t3[:, a] + coef[2])  # Eq. 4.1 in T, negated
    return out


def warmup_dps(p: GyroModelParams, power_on_s: np.ndarray) -> np.ndarray:
    """Warm-up transient A·exp(−t_on/τ) (n, 3), deg/s, at times since power-on ``power_on_s`` (s)."""
    t = np.maximum(np.asarray(power_on_s, dtype=float), 0.0)[:, None]
    return np.asarray(p.warmup_amplitude_dps, dtype=float) * np.exp(-t / np.asarray(p.warmup_tau_s, dtype=float))


def deterministic_output_dps(p: GyroModelParams, inputs: SensorInputs) -> np.ndarray:
    """Every term of Eq. (1) except the random ones (b_run-to-run, ε), (n, 3) deg/s:
    ω + b_cons + b_in-run(T, P) + M·ω + b_two-level + G·f + warm-up + rate ramp."""
    w = inputs.rate_dps
    out = w + np.asarray(p.b_cons_dps, dtype=float)
    out = out + in_run_temperature_bias_dps(p, inputs.temp_c) + pressure_bias_dps(p, inputs.pressure_torr)
    out = out + w @ p.m_matrix().T
    if p.two_level_correction:
        out = out + two_level_bias_dps(p, w, inputs.temp_c)
    g = np.asarray(p.g_sensitivity_dps_per_g, dtype=float)
    if np.any(g):
        out = out + inputs.specific_force_g @ g.T
    out = out + warmup_dps(p, inputs.power_on_s)
    ramp = np.asarray(p.rate_ramp_dph_per_h, dtype=float) * RAMP_UNIT
    if np.any(ramp):
        out = out + np.maximum(inputs.power_on_s, 0.0)[:, None] * ramp
    return out


def flicker_processes(tau_min_s: float, tau_max_s: float, per_decade: int = 2) -> tuple[np.ndarray, float]:
    """Correlation times τ_j (J,) in s of the Gauss-Markov sum approximating flicker (bias
    instability) noise, and the standard deviation of each process per unit B (σ_j = B·√(ln r/π),
    r the ratio of neighbouring τ_j; module docstring)."""
    decades = math.log10(tau_max_s / tau_min_s)
    count = max(int(round(decades * per_decade)) + 1, 2)
    taus = np.logspace(math.log10(tau_min_s), math.log10(tau_max_s), count)
    ratio = (tau_max_s / tau_min_s) ** (1.0 / (count - 1))
    return taus, math.sqrt(math.log(ratio) / math.pi)  # σ_j² = B² ln r / π, equal for every j


def bias_instability_processes(p: GyroModelParams) -> tuple[np.ndarray, np.ndarray]:
    """Correlation times τ_j (J,) in s and standard deviations σ (3, J) in deg/s of the
    Gauss-Markov sum approximating bias instability (module docstring)."""
    b = np.asarray(p.bias_instability_dph, dtype=float) * DPH
    lo, hi = (float(x) for x in p.bias_instability_tau_range_s)
    taus, per_b = flicker_processes(lo, hi, p.bias_instability_per_decade)
    return taus, np.repeat((per_b * b)[:, None], taus.size, axis=1)


# ---- the stateful model -------------------------------------------------------------------------
@dataclass
class GyroNoiseState:
    """State carried between :meth:`GyroModel.evaluate` calls."""

    t_last_s: float | None = None
    power_on_last_s: float | None = None
    power_on_instant_s: float | None = None
    period_s: float | None = None
    b_run_to_run_dps: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gauss_markov_dps: np.ndarray | None = None  # (3, J)
    rrw_dps: np.ndarray = field(default_factory=lambda: np.zeros(3))


class GyroModel:
    """Parameters + random generator + noise state. :meth:`evaluate` successive batches of samples
    (in time order) gives the same statistics as one call on their concatenation.

    A power-on is detected at the first sample ever and wherever ``power_on_s`` decreases or the
    power-on instant ``time_s − power_on_s`` moves (within a batch or from the previous batch): it draws a new run-to-run bias, restarts
    the rate random walk, redraws the Gauss-Markov states from their stationary distribution and
    empties the moving-average buffer.
    """

    def __init__(self, params: GyroModelParams, rng: np.random.Generator | None = None,
                 effects: Sequence[dict[str, Any]] = ()):
        self.p = params
        self.rng = rng if rng is not None else np.random.default_rng()
        self.effects = list(effects)
        self._taus, self._gm_sigma = bias_instability_processes(params)
        self._gm_on = bool(np.any(self._gm_sigma))
        self._arw = np.asarray(params.arw_deg_rth, dtype=float) * ARW_UNIT
        self._rrw = np.asarray(params.rrw_deg_h_rth, dtype=float) * RRW_UNIT
        self._ma = MovingAverage(params.digital.moving_average_n)
        self.state = GyroNoiseState()

    def reset(self) -> None:
        """Forget all state: the next sample is treated as a power-on."""
        self.state = GyroNoiseState()
        self._ma.reset()

    # ---- public -------------------------------------------------------------------------------
    def evaluate(self, inputs: SensorInputs) -> np.ndarray:
        """Sensor output (n, 3) in deg/s for ``inputs`` (after the output path's quantisation)."""
        return self._evaluate(inputs)[0]

    def evaluate_raw(self, inputs: SensorInputs) -> np.ndarray:
        """Raw output (n, 3): ADC counts (``adc``, int) or moving-averaged counts (``digital``)."""
        if self.p.output == "none":
            raise ValueError("the model has output 'none': there are no raw counts")
        return self._evaluate(inputs)[1]

    def physical_dps(self, inputs: SensorInputs) -> np.ndarray:
        """Output (n, 3) in deg/s before the output path (no quantisation, no moving average)."""
        return self._physical(inputs)[0]

    # ---- internals ----------------------------------------------------------------------------
    def _segments(self, inputs: SensorInputs) -> list[tuple[int, int, bool]]:
        """(start, stop, is_power_on) per run in the batch. A new run starts where the time since
        power-on decreases or the power-on instant (time_s − power_on_s) moves."""
        on = np.asarray(inputs.power_on_s, dtype=float)
        instant = inputs.time_s - on
        tol = 1e-6 + 1e-9 * np.abs(instant)
        n = on.shape[0]
        cuts = list(np.nonzero((np.diff(on) < 0) | (np.abs(np.diff(instant)) > tol[1:]))[0] + 1)
        s = self.state
        first_new = (s.power_on_last_s is None or on[0] < s.power_on_last_s
                     or (s.power_on_instant_s is not None and abs(instant[0] - s.power_on_instant_s) > tol[0]))
        bounds = [0, *cuts, n]
        return [(bounds[i], bounds[i + 1], first_new if i == 0 else True) for i in range(len(bounds) - 1)]

    def _power_on(self) -> None:
        s = self.state
        s.b_run_to_run_dps = self.rng.standard_normal(3) * np.asarray(self.p.run_to_run_sigma_dps, dtype=float)
        s.gauss_markov_dps = self.rng.standard_normal(self._gm_sigma.shape) * self._gm_sigma if self._gm_on else None
        s.rrw_dps = np.zeros(3)
        s.t_last_s = None
        self._ma.reset()

    def _physical(self, inputs: SensorInputs) -> tuple[np.ndarray, list[tuple[int, int, bool]]]:
        n = inputs.n
        out = deterministic_output_dps(self.p, inputs)
        segments = self._segments(inputs) if n else []
        for a, b, new in segments:
            if new:
                self._power_on()
            out[a:b] += self.state.b_run_to_run_dps + self._noise(inputs.time_s[a:b])
            self.state.power_on_last_s = float(inputs.power_on_s[b - 1])
            self.state.power_on_instant_s = float(inputs.time_s[b - 1] - inputs.power_on_s[b - 1])
        if self.effects:
            from bench.model import effects as effects_mod  # written separately; imported only when used

            out = np.asarray(effects_mod.apply_effects(self.effects, inputs, out, self.rng), dtype=float)
        return out, segments

    def _evaluate(self, inputs: SensorInputs) -> tuple[np.ndarray, np.ndarray | None]:
        out, segments = self._physical(inputs)
        if self.p.output == "adc":
            raw = adc_mod.encode_rate(out, self.p.adc)
            return adc_mod.decode_rate(raw, self.p.adc), raw
        if self.p.output == "digital":
            counts = dig_mod.quantise(out, self.p.digital).astype(float)
            raw = np.empty_like(counts)
            for a, b, new in segments:
                if new:
                    self._ma.reset()
                raw[a:b] = self._ma(counts[a:b])
            return dig_mod.counts_to_dps(raw, self.p.digital), raw
        return out, None

    def _noise(self, t: np.ndarray) -> np.ndarray:
        """ε for one run's samples at times ``t`` (m,), updating the state."""
        s = self.state
        m = t.shape[0]
        out = np.zeros((m, 3))
        if m >= 2:
            s.period_s = float(np.median(np.diff(t)))
        period = s.period_s if s.period_s and s.period_s > 0 else 1.0
        dt = np.diff(np.concatenate([[t[0] if s.t_last_s is None else s.t_last_s], t]))
        dt = np.maximum(dt, 0.0)
        if np.any(self._arw):
            out += self.rng.standard_normal((m, 3)) * (self._arw / math.sqrt(period))
        if self._gm_on and s.gauss_markov_dps is not None:
            out += self._gauss_markov(dt)
        if np.any(self._rrw):
            walk = s.rrw_dps + np.cumsum(self.rng.standard_normal((m, 3)) * np.sqrt(dt)[:, None] * self._rrw, axis=0)
            s.rrw_dps = walk[-1].copy()
            out += walk
        s.t_last_s = float(t[-1])
        return out

    def _gauss_markov(self, dt: np.ndarray) -> np.ndarray:
        """Sum over j of x_k = φ_k x_{k−1} + σ_j √(1−φ_k²) w_k, φ_k = exp(−Δt_k/τ_j) (exact
        discretisation), summed over the processes; (m, 3) deg/s."""
        s = self.state
        m = dt.shape[0]
        total = np.zeros((m, 3))
        rest = dt[1:]
        uniform = m > 1 and float(np.ptp(rest)) <= 1e-9 * max(float(rest.max()), 1e-12)
        for j, tau in enumerate(self._taus):
            sig = self._gm_sigma[:, j]
            w = self.rng.standard_normal((m, 3))
            phi = np.exp(-dt / tau)
            q = np.sqrt(1.0 - phi**2)[:, None] * sig
            x = np.empty((m, 3))
            x[0] = phi[0] * s.gauss_markov_dps[:, j] + q[0] * w[0]
            if m > 1:
                if uniform:
                    from scipy.signal import lfilter  # here, not at the top: importing scipy.signal takes ~1 s

                    a = float(phi[1])
                    y, _ = lfilter([1.0], [1.0, -a], q[1:] * w[1:], axis=0, zi=(a * x[0])[None, :])
                    x[1:] = y
                else:
                    for k in range(1, m):
                        x[k] = phi[k] * x[k - 1] + q[k] * w[k]
            s.gauss_markov_dps[:, j] = x[-1]
            total += x
        return total


def gyro_output(params: GyroModelParams, inputs: SensorInputs, rng: np.random.Generator,
                effects: Sequence[dict[str, Any]] = ()) -> np.ndarray:
    """Gyro output (n, 3) in deg/s for one run of samples (a fresh :class:`GyroModel`: power-on at
    the first sample). Pure apart from drawing from ``rng``."""
    return GyroModel(params, rng, effects).evaluate(inputs)


def with_output(params: GyroModelParams, output: str) -> GyroModelParams:
    """A copy of ``params`` with another output path (``none``, ``adc``, ``digital``)."""
    if output not in OUTPUTS:
        raise ValueError(f"output must be one of {OUTPUTS}, got {output!r}")
    return replace(params, output=output)
