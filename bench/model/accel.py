"""Accelerometer and gyro triad model of the NASA AMS report (seed 001, section III-B/III-C).

Each sensor axis k of a package has a bias B_k, a sensitivity S_k, an azimuth angle A_k and a
coning angle C_k (section III-A, Figure 5). The misalignment turns the desired measurement axis
into the true (excitation) axis of the sensor by two rotations applied one after the other
(Eqs. III-B.7-III-B.12 for accelerometers, III-C.6-III-C.11 for gyros):

* x: azimuth A_x about x, then coning C_x about the intermediate y axis;
* y: azimuth A_y about y, then coning C_y about the intermediate z axis;
* z: azimuth A_z about z, then coning C_z about the intermediate x axis.

Only row k of the product T_sn_k/desired = T(C_k)·T(A_k) matters for axis k (Eqs. III-B.14,
III-C.13). Multiplying out the matrices of Eqs. III-C.6-III-C.11, with (k, p, q) the cyclic order
(x, y, z), (y, z, x), (z, x, y), that row is the sensitive-axis unit vector::

    u_k[k] = cos C_k,   u_k[p] = sin A_k · sin C_k,   u_k[q] = −cos A_k · sin C_k

e.g. x: [cos C, sin A sin C, −cos A sin C]. The package output is (Eqs. III-B.23/24, III-C.14)::

    V_k = B_k + S_k · (u_k · v)                 (III-B.25/26, III-C.15)

with v the true input vector in the desired axes: the gravity vector G_st for the report's
accelerometers (Eq. III-B.6), the angular velocity Ω_m for its gyros (Eq. III-C.2). Substituting
v reproduces the scalar Eqs. III-B.27-III-B.32 and III-C.16-III-C.18 (checked in
``tests/test_sensor_models.py``). With A = C = 0 and S = 1 the model is v + B.

Units are those of the parameters: V and V/g (Table 3) or V/(deg/s) (Table 4). On the bench the
accelerometer input is the specific force in g and the gyro input the rate in deg/s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class NasaSensorParams:
    """One sensor package, per-axis arrays (3,) in x, y, z order.

    ``bias`` (output units, V in the report), ``sensitivity`` (output units per input unit: V/g,
    V/(deg/s)), ``azimuth_rad`` and ``coning_rad`` (rad; the report's tables give degrees).
    """

    bias: np.ndarray
    sensitivity: np.ndarray
    azimuth_rad: np.ndarray
    coning_rad: np.ndarray

    def __post_init__(self) -> None:
        for name in ("bias", "sensitivity", "azimuth_rad", "coning_rad"):
            value = np.asarray(getattr(self, name), dtype=float)
            setattr(self, name, np.broadcast_to(value, (3,)).copy())

    @classmethod
    def from_degrees(cls, bias: object, sensitivity: object, azimuth_deg: object, coning_deg: object) -> "NasaSensorParams":
        """Build from angles in degrees (as in the report's Tables 3 and 4)."""
        return cls(np.asarray(bias, dtype=float), np.asarray(sensitivity, dtype=float),
                   np.radians(np.asarray(azimuth_deg, dtype=float)), np.radians(np.asarray(coning_deg, dtype=float)))

    @classmethod
    def ideal(cls, bias: object = 0.0) -> "NasaSensorParams":
        """Unit sensitivity, no misalignment (output = input + bias)."""
        return cls(np.asarray(bias, dtype=float), np.ones(3), np.zeros(3), np.zeros(3))


def sensitive_axes(azimuth_rad: np.ndarray, coning_rad: np.ndarray) -> np.ndarray:
    """Sensitive-axis unit vectors (3, 3), row k for axis k, in the desired axes (Eqs. III-B.14,
    III-C.13; see the module docstring). Angles in rad, shape (3,)."""
    a = np.broadcast_to(np.asarray(azimuth_rad, dtype=float), (3,))
    c = np.broadcast_to(np.asarray(coning_rad, dtype=float), (3,))
    u = np.zeros((3, 3))
    for k in range(3):
        p, q = (k + 1) % 3, (k + 2) % 3
        u[k, k] = np.cos(c[k])
        u[k, p] = np.sin(a[k]) * np.sin(c[k])
        u[k, q] = -np.cos(a[k]) * np.sin(c[k])
    return u


def nasa_sensor_output(params: NasaSensorParams, true_vectors: np.ndarray) -> np.ndarray:
    """Package outputs V = B + S·(u_k · v) for true input vectors ``true_vectors`` (n, 3) or (3,)
    in the desired axes (Eqs. III-B.25/26, III-C.15). Returns (n, 3), or (3,) for a (3,) input."""
    v = np.asarray(true_vectors, dtype=float)
    single = v.ndim == 1
    v2 = np.atleast_2d(v)
    if v2.shape[-1] != 3:
        raise ValueError(f"true_vectors: expected shape (n, 3) or (3,), got {v.shape}")
    out = params.bias + params.sensitivity * (v2 @ sensitive_axes(params.azimuth_rad, params.coning_rad).T)
    return out[0] if single else out


def nasa_sensor_input(params: NasaSensorParams, outputs: np.ndarray) -> np.ndarray:
    """Inverse of :func:`nasa_sensor_output`: true vectors (n, 3) from outputs (n, 3),
    v = U⁻¹·((V − B)/S) (the construction step of section IV-B/IV-D). Raises ``ValueError`` when a
    sensitivity is zero or the sensitive axes are coplanar."""
    s = np.asarray(params.sensitivity, dtype=float)
    u = sensitive_axes(params.azimuth_rad, params.coning_rad)
    if np.any(s == 0) or abs(np.linalg.det(u)) < 1e-12:
        raise ValueError("the sensor model is not invertible (zero sensitivity or coplanar sensitive axes)")
    y = np.asarray(outputs, dtype=float)
    single = y.ndim == 1
    v = np.linalg.solve(u, ((np.atleast_2d(y) - params.bias) / s).T).T
    return v[0] if single else v


def sting_gravity(pitch_rad: np.ndarray, yaw_rad: np.ndarray, gravity: float = 1.0) -> np.ndarray:
    """Gravity vector in the report's sting axes (n, 3), Eq. III-B.6 with G_t = [0, 0, −G]:
    G_st = G·[−sin Θ cos Ψ, sin Θ sin Ψ, cos Θ]."""
    th, ps = np.broadcast_arrays(np.asarray(pitch_rad, dtype=float), np.asarray(yaw_rad, dtype=float))
    return gravity * np.stack([-np.sin(th) * np.cos(ps), np.sin(th) * np.sin(ps), np.cos(th)], axis=-1)


def model_rate(yaw_rad: np.ndarray, roll_rad: np.ndarray, pitch_rate: np.ndarray, yaw_rate: np.ndarray,
               roll_rate: np.ndarray) -> np.ndarray:
    """Model-axes angular velocity (n, 3) from the Euler angles and rates, Eq. III-C.2-III-C.5:
    Ω_m = T_m/st T_st/i1 [0, Θ̇, 0] + T_m/st [0, 0, Ψ̇] + [Φ̇, 0, 0] (rates in any unit, returned in it)."""
    ps, ph, dth, dps, dph = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (yaw_rad, roll_rad, pitch_rate, yaw_rate, roll_rate)))
    return np.stack([np.sin(ps) * dth + dph,
                     np.cos(ph) * np.cos(ps) * dth + np.sin(ph) * dps,
                     -np.sin(ph) * np.cos(ps) * dth + np.cos(ph) * dps], axis=-1)
