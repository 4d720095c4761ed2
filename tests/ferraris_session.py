"""A six-position + three-rotation (Ferraris) session with known truth, from bench's own sensor models.

The attitude of the unit is scripted as an operator would move it (imucal's protocol: x_p, x_a, y_p,
y_a, z_p, z_a still on a table, then one turn about each axis with that axis up, the turn made in
four quarter turns with short pauses as in imucal's example session), turned into the specific force
and body rate in the sensor frame, and fed to the models the simulator uses: the accelerometer through
the NASA model (:func:`bench.model.accel.nasa_sensor_output`: bias, sensitivity, sensitive-axis
direction) and the gyro through the NPSAT1 model (:func:`bench.model.gyro.gyro_output`: b_cons,
misalignment matrix, g-sensitivity, angle random walk). No Earth rate is added (imucal ignores it).

The truth is of the size imucal's real example session shows (docs/calibration.md), not a datasheet's:
this is a test of the arithmetic and of the section handling against a known answer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from bench.model.accel import NasaSensorParams, nasa_sensor_output, sensitive_axes
from bench.model.gyro import GyroModelParams, gyro_output
from bench.model.inputs import SensorInputs

FS_HZ = 102.4
"""imucal's example session's sample rate."""
FACES = ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a")


@dataclass
class Truth:
    accel: NasaSensorParams  # g
    gyro: GyroModelParams  # deg/s
    accel_noise_g: float

    @property
    def t_a(self) -> np.ndarray:
        return self.accel.sensitivity[:, None] * sensitive_axes(self.accel.azimuth_rad, self.accel.coning_rad)

    @property
    def t_g(self) -> np.ndarray:
        return np.eye(3) + self.gyro.m_matrix()


TRUTH = Truth(
    accel=NasaSensorParams.from_degrees([0.055, -0.063, 0.041], [0.9967, 1.0024, 1.0234], [30.0, -60.0, 120.0],
                                        [0.9, 0.5, 0.75]),
    gyro=GyroModelParams(b_cons_dps=[-0.60, -0.37, 0.059],
                         misalignment_pct=[[2.79, -0.05, -0.64], [-0.02, -1.76, -0.28], [0.97, 0.76, -0.17]],
                         g_sensitivity_dps_per_g=[[0.0038, -0.0045, 0.0], [0.0042, 0.0048, 0.0061], [0.001, -0.0009, 0.0023]],
                         arw_deg_rth=[0.3, 0.3, 0.3]),
    accel_noise_g=0.0015,
)


def _face_attitude(face: str) -> Rotation:
    """Body-to-world rotation that points the face's axis up (world z up)."""
    axis = np.zeros(3)
    axis["xyz".index(face[0])] = 1.0 if face[2] == "p" else -1.0
    rot, _ = Rotation.align_vectors([[0.0, 0.0, 1.0]], [axis])
    return rot


@dataclass
class Session:
    time_s: np.ndarray
    accel_g: np.ndarray
    gyro_dps: np.ndarray
    sections: dict[str, tuple[int, int]]  # name -> (start row, stop row), imucal's iloc convention
    true_force_g: np.ndarray
    true_rate_dps: np.ndarray


def make_session(seed: int = 1, truth: Truth = TRUTH, still_s: float = 6.0, move_s: float = 1.5,
                 turn_dps: float = 120.0, face_tilt_deg: float = 0.2) -> Session:
    """The session (see the module docstring); ``sections`` mark each face's still stretch (less 0.5 s
    at each end) and each turn from the last still sample before it to the first after it. Each face
    is placed tilted by a random small angle (σ ``face_tilt_deg`` about each horizontal axis: a hand
    on a table that is not quite flat; imucal's example shows 0.13-0.18°)."""
    dt = 1.0 / FS_HZ
    rng = np.random.default_rng(seed)
    tilts = {face: Rotation.from_rotvec(np.radians(np.append(rng.normal(0.0, face_tilt_deg, 2), 0.0)))
             for face in FACES}
    keys: list[tuple[float, Rotation]] = []  # attitude keyframes
    marks: dict[str, tuple[float, float]] = {}
    t = 0.0

    def hold(att: Rotation, dur: float) -> None:
        nonlocal t
        keys.append((t, att))
        t += dur
        keys.append((t, att))

    def move(to: Rotation, dur: float) -> None:
        nonlocal t
        t += dur
        keys.append((t, to))

    for face in FACES:
        att = tilts[face] * _face_attitude(face)
        if keys:
            move(att, move_s)
        start = t
        hold(att, still_s)
        marks[face] = (start + 0.5, t - 0.5)
    for axis in "xyz":
        att = _face_attitude(f"{axis}_p")
        move(att, move_s)
        hold(att, 2.0)
        start = t
        for q in range(4):  # a clockwise turn (the axis' gyro reads negative, imucal's x_rot) in quarter turns
            att = Rotation.from_rotvec([0.0, 0.0, -math.pi / 2]) * att
            move(att, 90.0 / turn_dps)
            if q < 3:
                hold(att, 0.3)
        marks[f"{axis}_rot"] = (start - 0.2, t + 0.2)
        hold(att, 2.0)
    times = np.array([k[0] for k in keys])
    rots = Rotation.concatenate([k[1] for k in keys])
    # keyframes at equal times (a hold's two ends) are merged; moves get a smooth (cosine) speed profile
    uniq, idx = np.unique(times, return_index=True)
    slerp = Slerp(uniq, rots[idx])
    n = int(times[-1] * FS_HZ)
    ts = np.arange(n) * dt
    seg = np.searchsorted(uniq, ts, side="right") - 1
    seg = np.clip(seg, 0, uniq.size - 2)
    frac = (ts - uniq[seg]) / (uniq[seg + 1] - uniq[seg])
    smooth = uniq[seg] + (0.5 - 0.5 * np.cos(math.pi * frac)) * (uniq[seg + 1] - uniq[seg])
    att = slerp(smooth)
    force = att.inv().apply([0.0, 0.0, 1.0])  # specific force of a unit at rest: 1 g up, in the body frame
    # body rate from consecutive attitudes (exact for a constant rate over one sample)
    step = (att[:-1].inv() * att[1:]).as_rotvec() / dt
    rate = np.degrees(np.vstack([step, step[-1:]]))
    accel = nasa_sensor_output(truth.accel, force) + rng.normal(0.0, truth.accel_noise_g, force.shape)
    gyro = gyro_output(truth.gyro, SensorInputs(ts, rate, np.full(n, 25.0), specific_force_g=force), rng)
    sections = {name: (int(np.searchsorted(ts, a)), int(np.searchsorted(ts, b))) for name, (a, b) in marks.items()}
    return Session(ts, accel, gyro, sections, force, rate)
