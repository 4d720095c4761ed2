"""Mount geometry shared by the simulated world, the sensor model and the analyses.

The unit sits on a platter (the stepper bench or the rate table) with one of its axes along the
platter normal. Frames: platter x points north at table angle 0 and z along the platter normal
(``docs/simulation.md``); the sensor frame is the unit's own (x, y, z).
"""

from __future__ import annotations

import numpy as np


def mount_matrix(up: str) -> np.ndarray:
    """Rotation from platter to sensor frame putting sensor axis ``up`` on the platter normal.

    +x: sensor (x, y, z) = platter (z, x, y); +y: (y, z, x); +z: identity (cyclic, right-handed);
    a negative axis adds a half turn about the next axis.
    """
    sign = -1.0 if up.startswith("-") else 1.0
    axis = up.lstrip("+-")
    if axis not in ("x", "y", "z"):
        raise ValueError(f"expected x, y, z, -x, -y or -z, got {up!r}")
    k = "xyz".index(axis)
    # platter z goes to sensor axis k; platter x, y to the next two (cyclic)
    m = np.zeros((3, 3))
    m[k, 2] = 1.0
    m[(k + 1) % 3, 0] = 1.0
    m[(k + 2) % 3, 1] = 1.0
    if sign < 0:
        flip = np.eye(3)
        flip[k, k] = -1.0
        flip[(k + 1) % 3, (k + 1) % 3] = -1.0
        m = flip @ m
    return m
