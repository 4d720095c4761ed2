"""Structure of a residual: spectra in time and in table angle, correlation with covariates,
Allan deviation against white noise. Used for the report and the structure lines of the summary."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.signal import welch

from bench.analysis.diagnose.data import Prepared
from bench.analysis.diagnose.terms import GearEccentricity


def covariates(p: Prepared, axis: str) -> dict[str, np.ndarray]:
    """The covariates a residual is checked against (units in the names; absent ones left out)."""
    out: dict[str, np.ndarray] = {}
    if p.temp is not None:
        out["temperature (°C)"] = p.temp
        out["dT/dt (°C/s)"] = p.dtemp()
    if p.pressure is not None:
        out["log10 pressure (Torr)"] = np.log10(p.pressure)
    if p.power_on is not None:
        out["time since power-on (s)"] = p.power_on
    if p.ref is not None:
        r = p.ref_axis(axis)
        out["reference rate (deg/s)"] = r
        out["|rate| (deg/s)"] = np.abs(r)
        if p.temp is not None:
            out["rate × temperature (deg/s·°C)"] = r * (p.temp - 25.0)
        out["rate derivative (deg/s²)"] = np.gradient(r, p.t)
    if p.accel is not None:
        for k, a in enumerate("xyz"):
            out[f"specific force {a} (g)"] = p.accel[:, k]
    if p.angle is not None:
        th = np.radians(p.angle)
        out["table angle sin θ"] = np.sin(th)
        out["table angle cos θ"] = np.cos(th)
    return out


def correlations(r: np.ndarray, covs: dict[str, np.ndarray]) -> dict[str, float]:
    """Pearson correlation of ``r`` with each covariate (NaN when the covariate is constant)."""
    out = {}
    rc = r - r.mean()
    rn = float(np.sqrt(np.dot(rc, rc)))
    for name, c in covs.items():
        cc = c - c.mean()
        cn = float(np.sqrt(np.dot(cc, cc)))
        out[name] = float(np.dot(rc, cc) / (rn * cn)) if rn > 0 and cn > 1e-12 else float("nan")
    return out


STOP_RATIO = 8
"""Longest cluster of the structure plot: n/8 samples (the shortest residuals are 8 samples long)."""


def allan(r: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping Allan deviation (deg/s) of rate samples ``r`` (deg/s at ``fs`` Hz) against the
    cluster time (s), clusters of 1, 2, 4 … n/:data:`STOP_RATIO` samples; empty for fewer than
    :data:`STOP_RATIO` samples. Computed by :func:`bench.analysis.allan.overlapping_adev`, the one
    home of the Allan deviation."""
    from bench.analysis.allan import octave_m, overlapping_adev

    if r.shape[0] < STOP_RATIO:
        return np.zeros(0), np.zeros(0)
    res = overlapping_adev(r, fs, m=octave_m(r.shape[0], STOP_RATIO))
    return res.taus_s, res.adev


def psd(r: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """One-sided Welch PSD of ``r`` ((deg/s)²/Hz) against frequency (Hz)."""
    nper = int(min(r.shape[0], max(256, 2 ** int(math.log2(max(r.shape[0] // 8, 256))))))
    f, s = welch(r - r.mean(), fs=fs, nperseg=nper)
    return f[1:], s[1:]


def angle_spectrum(p: Prepared, axis: str, r: np.ndarray, n_max: int = 200) -> np.ndarray | None:
    """Amplitude (fraction of the rate) of the residual's component ε·sin(Nθ + φ)·ω for N = 1..n_max,
    None when the axis sees no table rotation."""
    if p.angle is None or p.ref is None or not p.rate_excited(axis):
        return None
    power = GearEccentricity().spectrum(p, axis, r, n_max)
    w2 = float(np.sum(p.ref_axis(axis) ** 2))
    return np.sqrt(np.maximum(2.0 * power / w2, 0.0)) if w2 > 0 else None


def analyse(p: Prepared, axis: str, r: np.ndarray, floor: float) -> dict[str, Any]:
    """Everything above for one residual, plus the Allan-deviation ratio to white noise of the
    noise-floor level at the longest cluster time."""
    taus, adev = allan(r, p.fs)
    white = floor / np.sqrt(taus * p.fs) if taus.size else taus
    f, s = psd(r, p.fs)
    out: dict[str, Any] = {
        "rms": float(np.sqrt(np.mean(r * r))),
        "correlations": correlations(r, covariates(p, axis)),
        "allan_tau_s": taus, "allan_dev": adev, "allan_white": white,
        "allan_ratio_max": float(adev[-1] / white[-1]) if taus.size and white[-1] > 0 else float("nan"),
        "psd_f": f, "psd": s,
    }
    spec = angle_spectrum(p, axis, r)
    if spec is not None:
        k = int(np.argmax(spec))
        out["angle_spectrum"] = spec
        out["angle_peak"] = (k + 1, float(spec[k]))
    return out
