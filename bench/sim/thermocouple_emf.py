"""NIST ITS-90 thermocouple reference functions for types K and T, vectorised with numpy.

Source: NIST Monograph 175 (Burns et al., 1993), "Temperature-Electromotive Force Reference
Functions and Tables for the Letter-Designated Thermocouple Types Based on the ITS-90", as
published in the NIST ITS-90 Thermocouple Database (srdata.nist.gov/its90, files ``type_k.tab``
and ``type_t.tab``; the same coefficients are printed in e.g. the Keithley 2700 / 3700A manuals,
appendix "Temperature equations"). Reference junction at 0 °C, temperatures in °C (ITS-90),
EMF in mV.

* Type K reference function (t → E), Monograph 175 Table for type K:
  −270..0 °C: ``E = Σ c_i t^i`` (i = 0..10);
  0..1372 °C: ``E = Σ c_i t^i + a0·exp(a1·(t − a2)²)`` (i = 0..9, the exponential term).
* Type K inverse (E → t), Monograph 175 / database "inverse coefficients", E in mV:
  −5.891..0 mV (−200..0 °C, error −0.02..+0.04 °C), 0..20.644 mV (0..500 °C, error
  −0.05..+0.04 °C), 20.644..54.886 mV (500..1372 °C, error −0.05..+0.06 °C).
* Type T reference function: −270..0 °C (i = 0..14), 0..400 °C (i = 0..8).
* Type T inverse: −5.603..0 mV (−200..0 °C, error −0.02..+0.04 °C), 0..20.872 mV (0..400 °C,
  error −0.03..+0.03 °C).

:func:`emf_to_temp_c` evaluates the inverse polynomials; with ``exact=True`` it then refines the
result by Newton steps on the reference function, so that ``emf_to_temp_c(temp_to_emf_mv(t),
exact=True)`` returns ``t`` to ~1e-9 °C (the inverse of the reference function itself, not of its
±0.05 °C polynomial approximation). Out-of-range inputs raise ``ValueError`` naming the range.
"""

from __future__ import annotations

import math

import numpy as np

TC_TYPES = ("K", "T")

# ---- reference functions t (°C) -> E (mV): (t_low, t_high, c_0..c_n) -------------------------
_FORWARD: dict[str, list[tuple[float, float, tuple[float, ...]]]] = {
    "K": [
        (-270.0, 0.0, (
            0.000000000000E+00, 0.394501280250E-01, 0.236223735980E-04, -0.328589067840E-06,
            -0.499048287770E-08, -0.675090591730E-10, -0.574103274280E-12, -0.310888728940E-14,
            -0.104516093650E-16, -0.198892668780E-19, -0.163226974860E-22)),
        (0.0, 1372.0, (
            -0.176004136860E-01, 0.389212049750E-01, 0.185587700320E-04, -0.994575928740E-07,
            0.318409457190E-09, -0.560728448890E-12, 0.560750590590E-15, -0.320207200030E-18,
            0.971511471520E-22, -0.121047212750E-25)),
    ],
    "T": [
        (-270.0, 0.0, (
            0.000000000000E+00, 0.387481063640E-01, 0.441944343470E-04, 0.118443231050E-06,
            0.200329735540E-07, 0.901380195590E-09, 0.226511565930E-10, 0.360711542050E-12,
            0.384939398830E-14, 0.282135219250E-16, 0.142515947790E-18, 0.487686622860E-21,
            0.107955392700E-23, 0.139450270620E-26, 0.797951539270E-30)),
        (0.0, 400.0, (
            0.000000000000E+00, 0.387481063640E-01, 0.332922278800E-04, 0.206182434040E-06,
            -0.218822568460E-08, 0.109968809280E-10, -0.308157587720E-13, 0.454791352900E-16,
            -0.275129016730E-19)),
    ],
}
# type K, t >= 0 °C: + a0·exp(a1·(t − a2)²)
_K_EXP = (0.118597600000E+00, -0.118343200000E-03, 0.126968600000E+03)

# ---- inverse functions E (mV) -> t (°C): (E_low, E_high, d_0..d_n) ----------------------------
_INVERSE: dict[str, list[tuple[float, float, tuple[float, ...]]]] = {
    "K": [
        (-5.891, 0.0, (
            0.0000000E+00, 2.5173462E+01, -1.1662878E+00, -1.0833638E+00, -8.9773540E-01,
            -3.7342377E-01, -8.6632643E-02, -1.0450598E-02, -5.1920577E-04)),
        (0.0, 20.644, (
            0.000000E+00, 2.508355E+01, 7.860106E-02, -2.503131E-01, 8.315270E-02, -1.228034E-02,
            9.804036E-04, -4.413030E-05, 1.057734E-06, -1.052755E-08)),
        (20.644, 54.886, (
            -1.318058E+02, 4.830222E+01, -1.646031E+00, 5.464731E-02, -9.650715E-04, 8.802193E-06,
            -3.110810E-08)),
    ],
    "T": [
        (-5.603, 0.0, (
            0.0000000E+00, 2.5949192E+01, -2.1316967E-01, 7.9018692E-01, 4.2527777E-01,
            1.3304473E-01, 2.0241446E-02, 1.2668171E-03)),
        (0.0, 20.872, (
            0.000000E+00, 2.592800E+01, -7.602961E-01, 4.637791E-02, -2.165394E-03, 6.048144E-05,
            -7.293422E-07)),
    ],
}

TEMP_RANGE_C = {k: (v[0][0], v[-1][1]) for k, v in _FORWARD.items()}
"""Range of the reference function t → E per type (°C)."""
EMF_RANGE_MV = {k: (v[0][0], v[-1][1]) for k, v in _INVERSE.items()}
"""Range of the inverse polynomials E → t per type (mV)."""
_EMF_ROUNDING_MV = 0.0005
"""The inverse ranges are tabulated to 1 µV (e.g. −5.891 mV for E(−200 °C) = −5.8914 mV): inputs
within half a digit of a limit are accepted (and evaluated with the end piece)."""
INVERSE_ERROR_C = {"K": 0.06, "T": 0.04}
"""Largest |error| of the NIST inverse polynomials over their ranges (°C)."""


def _check_type(tc_type: str) -> str:
    t = str(tc_type).upper()
    if t not in TC_TYPES:
        raise ValueError(f"thermocouple type must be one of {TC_TYPES}, got {tc_type!r}")
    return t


def _piecewise(x: np.ndarray, pieces, evaluate) -> np.ndarray:
    """Evaluate piece by piece; a piece owns its upper bound (values at a joint agree), the first
    piece everything below its upper bound and the last everything above its lower bound."""
    out = np.empty_like(x)
    for i, (lo, hi, coeffs) in enumerate(pieces):
        sel = np.ones(x.shape, bool) if i == 0 else x > lo
        if i < len(pieces) - 1:
            sel &= x <= hi
        out[sel] = evaluate(x[sel], lo, coeffs)
    return out


def _piece(x: float, pieces):
    """The piece of ``pieces`` that owns ``x`` (same rule as :func:`_piecewise`)."""
    for i, piece in enumerate(pieces):
        lo, hi, _ = piece
        if (i == 0 or x > lo) and (i == len(pieces) - 1 or x <= hi):
            return piece
    return pieces[-1]


def _horner(x: float, coeffs) -> float:
    acc = 0.0
    for c in reversed(coeffs):
        acc = acc * x + c
    return acc


def _temp_to_emf_scalar(t: float, kind: str) -> float:
    """Scalar fast path of :func:`temp_to_emf_mv` (plain floats: a simulator calls it per reading)."""
    lo, hi = TEMP_RANGE_C[kind]
    if not lo <= t <= hi:
        raise ValueError(f"type {kind} reference function covers {lo:g}..{hi:g} °C, got {t!r}")
    plo, _, coeffs = _piece(t, _FORWARD[kind])
    e = _horner(t, coeffs)
    if kind == "K" and plo == 0.0:
        a0, a1, a2 = _K_EXP
        e += a0 * math.exp(a1 * (t - a2) ** 2)
    return e


def temp_to_emf_mv(temp_c, tc_type: str = "K"):
    """Thermo-EMF (mV) of a ``tc_type`` thermocouple at ``temp_c`` (°C) against a 0 °C reference.

    Array in, array out (a float for a scalar). ``ValueError`` outside the reference function's
    range (K: −270..1372 °C, T: −270..400 °C).
    """
    kind = _check_type(tc_type)
    if isinstance(temp_c, (float, int)):
        return _temp_to_emf_scalar(float(temp_c), kind)
    t = np.asarray(temp_c, dtype=float)
    lo, hi = TEMP_RANGE_C[kind]
    if not np.all((t >= lo) & (t <= hi)):
        raise ValueError(f"type {kind} reference function covers {lo:g}..{hi:g} °C, got {t[~((t >= lo) & (t <= hi))].ravel()[:3]}")
    tt = np.atleast_1d(t)

    def evaluate(x, lo_piece, coeffs):
        e = np.polynomial.polynomial.polyval(x, coeffs)
        if kind == "K" and lo_piece == 0.0:
            a0, a1, a2 = _K_EXP
            e = e + a0 * np.exp(a1 * (x - a2) ** 2)
        return e

    e = _piecewise(tt, _FORWARD[kind], evaluate)
    return float(e[0]) if t.ndim == 0 else e.reshape(t.shape)


def seebeck_uv_per_c(temp_c, tc_type: str = "K"):
    """Sensitivity dE/dt (µV/°C) of the reference function at ``temp_c`` (°C)."""
    kind = _check_type(tc_type)
    t = np.asarray(temp_c, dtype=float)
    lo, hi = TEMP_RANGE_C[kind]
    if not np.all((t >= lo) & (t <= hi)):
        raise ValueError(f"type {kind} reference function covers {lo:g}..{hi:g} °C")
    tt = np.atleast_1d(t)

    def evaluate(x, lo_piece, coeffs):
        d = np.polynomial.polynomial.polyval(x, np.polynomial.polynomial.polyder(coeffs))
        if kind == "K" and lo_piece == 0.0:
            a0, a1, a2 = _K_EXP
            d = d + a0 * np.exp(a1 * (x - a2) ** 2) * 2.0 * a1 * (x - a2)
        return d * 1000.0

    s = _piecewise(tt, _FORWARD[kind], evaluate)
    return float(s[0]) if t.ndim == 0 else s.reshape(t.shape)


def emf_to_temp_c(emf_mv, tc_type: str = "K", exact: bool = False):
    """Temperature (°C) of a ``tc_type`` thermocouple giving ``emf_mv`` (mV) against 0 °C.

    The NIST inverse polynomials (error within ±0.06 °C for K, ±0.04 °C for T); ``exact=True``
    refines them to the inverse of the reference function. ``ValueError`` outside the inverse
    polynomials' range (K: −5.891..54.886 mV, T: −5.603..20.872 mV).
    """
    kind = _check_type(tc_type)
    lo, hi = EMF_RANGE_MV[kind]
    if isinstance(emf_mv, (float, int)) and not exact:
        x = float(emf_mv)
        if not lo - _EMF_ROUNDING_MV <= x <= hi + _EMF_ROUNDING_MV:
            raise ValueError(f"type {kind} inverse function covers {lo:g}..{hi:g} mV, got {x!r}")
        return _horner(x, _piece(x, _INVERSE[kind])[2])
    e = np.asarray(emf_mv, dtype=float)
    ok = (e >= lo - _EMF_ROUNDING_MV) & (e <= hi + _EMF_ROUNDING_MV)
    if not np.all(ok):
        raise ValueError(f"type {kind} inverse function covers {lo:g}..{hi:g} mV, got {e[~ok].ravel()[:3]}")
    ee = np.atleast_1d(e)
    t = _piecewise(ee, _INVERSE[kind], lambda x, _lo, c: np.polynomial.polynomial.polyval(x, c))
    if exact:
        tlo, thi = TEMP_RANGE_C[kind]
        for _ in range(4):  # Newton on the reference function; quadratic convergence from ±0.06 °C
            t = np.clip(t, tlo, thi)
            t = t - (temp_to_emf_mv(t, kind) - ee) * 1000.0 / seebeck_uv_per_c(t, kind)
    return float(t[0]) if e.ndim == 0 else t.reshape(e.shape)
