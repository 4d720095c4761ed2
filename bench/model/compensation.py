"""Gyro compensation, NPSAT1 Eq. (2): the estimated rate from the raw output.

    ω̃ = I − (b_in-run(T) + M·ω̃ + b_cons)   ⇒   ω̃ = (1 + M)⁻¹ · (I − b_in-run(T) − b_cons)

(NPSAT1 thesis section II, Eq. 2-3; the terms of Table 15). b_run-to-run is unknown at run time and
ε is noise: neither is compensated. Units: rates and biases deg/s, temperature °C, M a fraction.

The terms come from files (:func:`load_compensation`), any combination of

* ``bench calibrate thermal -o`` calibration files (``method: thermal``): b_in-run per axis;
* ``bench calibrate rate-transfer -o`` files (``method: rate-transfer``): b_cons and M;
* ``bench calibrate six-position -o`` files (``method: six-position``): b_cons (the gyro bias), M
  (T_g − I: scale and misalignment) and the g-sensitivity K_ga (deg/s per g, applied when the
  specific force is given);
* sensor-model files (``model: npsat1_gyro``, e.g. ``configs/sensors/npsat1_qrs11_ground.yaml``,
  Table 15 values): b_in-run (°C form), b_cons and M.

Later files override the terms they carry. A rate-transfer calibration fitted on data that were not
thermally compensated holds the in-run bias at the test temperature in its b_cons: combine it with
a thermal calibration only when the rate-transfer data were compensated (``docs/calibration.md``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.errors import InputError, Location
from bench.yamlsrc import load_yaml

AXES = ("x", "y", "z")


@dataclass
class Compensation:
    """The compensation terms: ``in_run_poly_degc`` per axis ascending powers in °C (deg/s), or None;
    ``b_cons_dps`` (3,); ``m`` (3, 3) fraction, rows output axis, columns rate axis; ``sources``:
    the files the terms came from."""

    in_run_poly_degc: list[list[float]] | None = None
    b_cons_dps: np.ndarray = field(default_factory=lambda: np.zeros(3))
    m: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    sources: list[str] = field(default_factory=list)
    g_sensitivity: np.ndarray | None = None
    """(3, 3) deg/s per g, rows output axis, columns specific-force axis (six-position K_ga), or None."""

    def apply(self, gyro_dps: np.ndarray, temp_c: np.ndarray, accel_g: np.ndarray | None = None) -> np.ndarray:
        """Compensated rates (n, 3) deg/s from raw outputs ``gyro_dps`` (n, 3) and the gyro
        temperature ``temp_c`` (n,) or (n, 3), °C; with ``accel_g`` (n, 3) the specific force (g)
        the g-sensitivity term K_ga·f is taken off too."""
        g = np.asarray(gyro_dps, dtype=float)
        y = g - self.b_cons_dps
        if self.g_sensitivity is not None and accel_g is not None:
            y = y - np.asarray(accel_g, dtype=float) @ self.g_sensitivity.T
        if self.in_run_poly_degc is not None:
            t = np.asarray(temp_c, dtype=float)
            t3 = t if t.ndim == 2 else np.repeat(np.atleast_1d(t)[:, None], 3, axis=1)
            for a in range(3):
                y[:, a] -= np.polynomial.polynomial.polyval(t3[:, a], self.in_run_poly_degc[a])
        return np.linalg.solve(np.eye(3) + self.m, y.T).T

    def describe(self) -> str:
        """One line for the run file's instrument record."""
        terms = (["b_in-run"] if self.in_run_poly_degc is not None else []) + \
                (["b_cons"] if np.any(self.b_cons_dps) else []) + (["M"] if np.any(self.m) else []) + \
                (["K_ga"] if self.g_sensitivity is not None and np.any(self.g_sensitivity) else [])
        return f"NPSAT1 Eq. 2 ({', '.join(terms) or 'nothing'}) from {', '.join(self.sources)}"


def load_compensation(paths: list[str | Path], texts: dict[str, str] | None = None) -> Compensation:
    """Merge the compensation terms of ``paths`` (see the module docstring); :class:`InputError`
    (located) for a file that is missing, malformed or carries no gyro compensation. ``texts``:
    receives path -> text of every file read (each is read once; a config keeps them for replay)."""
    comp = Compensation()
    for path in paths:
        p = Path(path)
        src = load_yaml(p, "calibration file")
        if texts is not None:
            texts[str(p)] = src.text
        data = src.root.plain()
        where = src.root.location
        if not isinstance(data, dict):
            raise InputError("expected a calibration or sensor-model mapping", where)
        try:
            if data.get("method") == "thermal":
                comp.in_run_poly_degc = [[float(c) for c in data["axes"][a]["coefficients"]] for a in AXES]
            elif data.get("method") == "rate-transfer":
                comp.b_cons_dps = np.array([float(data["b_cons_dps"][a]) for a in AXES])
                comp.m = _matrix(data["M"])
            elif data.get("method") == "six-position":
                comp.b_cons_dps = np.array([float(data["b_cons_dps"][a]) for a in AXES])
                comp.m = _matrix(data["M"])
                comp.g_sensitivity = _matrix(data["gyro"]["g_sensitivity_dps_per_g"])
            elif data.get("model") == "npsat1_gyro":
                _from_sensor_model(p, src.text, comp)
            else:
                raise InputError("expected a thermal, rate-transfer or six-position calibration (bench calibrate ... -o) or an npsat1_gyro "
                                 "sensor model", where, "method")
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise InputError(f"incomplete gyro compensation terms ({type(exc).__name__}: {exc}); expected the file "
                             "`bench calibrate` wrote", Location(p, where.line if where else None)) from None
        comp.sources.append(str(p))
    return comp


def _matrix(rows) -> np.ndarray:
    m = np.array([[0.0 if v is None else float(v) for v in (r or [None] * 3)] for r in rows], dtype=float)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise ValueError(f"M must be 3x3 finite numbers, got shape {m.shape}")
    return m


def _from_sensor_model(p: Path, text: str, comp: Compensation) -> None:
    from bench.model.loader import parse_sensor_model

    g = parse_sensor_model(text, str(p)).gyro  # the text already read, not the file again
    if g is None or g.in_run_poly_variable != "temp_c":
        raise InputError("a sensor model compensates only with its in-run polynomial in temp_c (the °C form, "
                         "e.g. npsat1_qrs11_ground.yaml)", Location(p), "in_run_poly_variable")
    comp.in_run_poly_degc = [[float(c) for c in row] for row in g.in_run_poly]
    comp.b_cons_dps = np.asarray(g.b_cons_dps, dtype=float)
    comp.m = g.m_matrix()
