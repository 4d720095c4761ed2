"""Whether the baseline's temperature cubic could equally be a drift in time (``docs/diagnose.md``,
Output, "A temperature that moved only with time").

The baseline fits a cubic in the ``temp_c`` channel per axis, and ``-o`` writes it as the sensor's
temperature coefficient. When the temperature moved only with time (a die self-heating after
power-on on a bench at room temperature: monotone, or reproduced by a smooth function of time), any
smooth function of time is a function of that temperature: the cubic takes a warm-up or a drift in
time as readily as a temperature coefficient, and one run cannot tell which. This module says so;
it names nothing and changes no fit.

The test, per axis, is two χ² comparisons with the same threshold :data:`CHI2_MATERIAL`, in units
of the axis' white-noise variance σ² (the result's noise floor, deg/s):

* material: the cubic's contribution over the run, c(T(t)) less its mean, has Σ(c − c̄)²/σ² above
  the threshold. With no temperature effect and white noise the fitted cubic's three coefficients
  make that sum a χ²₃ variable, so the threshold (χ²₃ at 99.9 %) is what noise alone exceeds once
  in a thousand runs;
* in time: the temperature is monotone (then any function of it is one of time, exactly), or,
  with S(t) its least-squares fit by a smooth function of time (a cubic in time, plus the warm-up
  family e^(−t_on/τ) in time since power-on t_on, or since the first row when power-on is not
  known), the part of the contribution no function of time reproduces, r = c(T(t)) − c(S(t))
  (less its mean), has Σ r²/σ² at or below the threshold: replacing the temperature by a drift
  in time then changes the fit by less than the noise can show.

Only then is the axis reported. A temperature cycle (a chamber) reverses and leaves a remainder far
above the threshold, so it is not. A one-way chamber ramp is: over one ramp a temperature
coefficient and a drift in time are the same function of time.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.polynomial import polynomial as P

CHI2_MATERIAL = 16.27
"""χ²₃ at 99.9 %: the threshold of both comparisons (three temperature coefficients)."""
SMOOTH_BLOCKS = 50
"""The temperature is averaged over this many consecutive blocks of the run before the
monotonicity check (its own noise averaged down)."""
TAU_GRID_S = np.geomspace(10.0, 1.0e5, 40)
"""Time constants (s) of the warm-up family e^(−t_on/τ) tried against the contribution."""


def temperature_in_time(t: np.ndarray, temp: np.ndarray, power_on: np.ndarray | None,
                        poly: dict[str, list[float]], sigma: dict[str, float],
                        every_axis: bool = False) -> dict[str, dict[str, Any]]:
    """Axis → entry for each axis whose temperature cubic is material and could be a drift in time.

    ``t`` (s) and ``temp`` (°C) the analysed rows; ``power_on`` time since power-on (s) or None;
    ``poly`` axis → the fitted ``in_run_poly`` [B, m1, m2, m3] in °C (deg/s per °C^k); ``sigma``
    axis → white-noise RMS (deg/s). Each entry: ``held_dps`` (max − min of the cubic's contribution
    over the run), ``first_last_dps`` (first row − last row), ``temp_first_c``/``temp_last_c``,
    ``temp_min_c``/``temp_max_c``, ``monotone``, ``since_power_on``, ``chi2`` (materiality),
    ``chi2_not_in_time`` (the remainder's), ``threshold``. ``every_axis``: every axis with its
    figures and ``said`` (the measurements behind the thresholds)."""
    if temp.size < 8 or not np.all(np.isfinite(temp)):
        return {}
    smooth, since = smooth_in_time(t, temp, power_on)
    mono = monotone(temp)
    out: dict[str, dict[str, Any]] = {}
    for a, c in poly.items():
        s = sigma.get(a, float("nan"))
        if not (math.isfinite(s) and s > 0):
            continue
        cubic = [0.0] + list(c[1:])
        v = P.polyval(temp, cubic)
        vc = v - v.mean()
        rem = v - P.polyval(smooth, cubic)
        rem = rem - rem.mean()
        chi2, chi2_rem = float(vc @ vc) / (s * s), float(rem @ rem) / (s * s)
        said = chi2 > CHI2_MATERIAL and (mono or chi2_rem <= CHI2_MATERIAL)
        if not (said or every_axis):
            continue
        out[a] = {"axis": a, "held_dps": float(np.ptp(v)), "first_last_dps": float(v[0] - v[-1]),
                  "temp_first_c": float(temp[0]), "temp_last_c": float(temp[-1]),
                  "temp_min_c": float(temp.min()), "temp_max_c": float(temp.max()), "monotone": mono,
                  "since_power_on": since, "chi2": chi2, "chi2_not_in_time": chi2_rem, "threshold": CHI2_MATERIAL}
        if every_axis:
            out[a]["said"] = said
    return out


def white_rms(x: np.ndarray) -> float:
    """The white-noise RMS of ``x`` (its unit) from successive differences, robust to slow
    structure and outliers: 1.4826·MAD/√2 (the diagnose result's noise floor, deg/s)."""
    d = np.diff(x)
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(2))


def monotone(temp: np.ndarray) -> bool:
    """True when the temperature, averaged over :data:`SMOOTH_BLOCKS` blocks, never reverses by more
    than its resolution (smallest step between readings) plus four standard errors of a block mean
    (its sample-to-sample noise from successive differences, 1.4826·MAD/√2)."""
    n = temp.size
    m = max(1, n // SMOOTH_BLOCKS)
    g = n // m
    if g < 3:
        return False
    means = temp[: g * m].reshape(g, m).mean(axis=1)
    steps = np.abs(np.diff(np.unique(temp)))
    quantum = float(steps.min()) if steps.size else 0.0
    tol = quantum + 4.0 * white_rms(temp) / math.sqrt(m)
    rise = float(np.max(np.maximum.accumulate(means) - means))
    fall = float(np.max(means - np.minimum.accumulate(means)))
    return min(rise, fall) <= tol and float(np.ptp(means)) > tol


def _shape(t: np.ndarray) -> np.ndarray:
    """Columns 1, s, s², s³ of the scaled time s ∈ [−1, 1]."""
    span = float(t[-1] - t[0]) or 1.0
    s = 2.0 * (t - t[0]) / span - 1.0
    return np.column_stack([np.ones_like(s), s, s * s, s ** 3])


def smooth_in_time(t: np.ndarray, temp: np.ndarray, power_on: np.ndarray | None) -> tuple[np.ndarray, bool]:
    """(the temperature's least-squares fit by a smooth function of time, whether the warm-up family
    in time since power-on gave it): a cubic in time, plus e^(−t_on/τ) (τ on :data:`TAU_GRID_S`;
    t_on the time since power-on, or since the first row when power-on is not known: a settling
    from the start of the log is as much a drift in time), the τ that removes most, when it removes
    at least half the squared remainder."""
    q, _ = np.linalg.qr(_shape(t))
    fit = q @ (q.T @ temp)
    r0 = temp - fit
    sse = float(r0 @ r0)
    on = np.clip(power_on, 0.0, None) if power_on is not None else t - t[0]
    x = np.exp(-on[:, None] / TAU_GRID_S[None, :])
    x -= q @ (q.T @ x)  # each settle column less its part in the cubic in time
    nx = np.einsum("ij,ij->j", x, x)
    ok = nx > 1e-12 * max(float(nx.max()), 1e-300)
    gain = np.where(ok, (x.T @ r0) ** 2 / np.where(ok, nx, 1.0), 0.0)
    k = int(np.argmax(gain))
    settle = bool(gain[k] > 0.5 * sse)
    if settle:
        fit = fit + x[:, k] * (float(x[:, k] @ r0) / nx[k])
    return fit, settle and power_on is not None


def line(entry: dict[str, Any]) -> str:
    """The summary sentence for one axis' entry."""
    how = "time since power-on" if entry["since_power_on"] else "time"
    if entry["monotone"]:
        moved = f"({entry['temp_first_c']:.1f} → {entry['temp_last_c']:.1f} °C, monotone)"
    else:
        moved = f"({entry['temp_min_c']:.1f} to {entry['temp_max_c']:.1f} °C, a smooth function of time)"
    return (f"{entry['axis']}: the temperature coefficient holds {entry['held_dps']:.3g} deg/s over the run, but the "
            f"temperature moved only with {how} {moved}: one run cannot tell it from a warm-up or a drift in time; "
            "a temperature cycle (a chamber) or runs at other temperatures separate them")
