"""World geometry: Earth rate, gravity and field through the table's tilt, rotation and the mount."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.model.geometry import mount_matrix
from bench.sim.world import World, WorldParams

OMEGA = 360.0 / 86164.0905  # deg/s, sidereal
LAT = 36.4


def settled(world: World, t: float = 1000.0):
    return world.environment(np.array([t]))


def test_level_unit_sees_earth_rate_north_and_up():
    env = World(WorldParams()).environment(np.array([0.0]))
    rate = np.atleast_2d(env.rate_dps)[0]
    assert rate == pytest.approx([OMEGA * math.cos(math.radians(LAT)), 0.0, OMEGA * math.sin(math.radians(LAT))], abs=1e-12)


def test_tilt_by_minus_latitude_cancels_earth_rate_on_the_table_axis():
    """NPSAT1 IV.E / Appendix L: the table tilted at -36.4 deg at Monterey."""
    w = World(WorldParams())
    w.table.tilt.command_position(0.0, -LAT, 5.0, 5.0)
    for angle in (0.0, 90.0, 200.0):
        w.table.rotation.command_position(w.table.tilt.settled_at() + 100 * angle, angle, 5.0, 5.0)
        t = w.table.rotation.settled_at() + 1.0
        env = settled(w, t)
        assert abs(env.rate_dps[0, 2]) < 1e-9 * OMEGA + 1e-15
        assert np.linalg.norm(env.rate_dps[0]) == pytest.approx(OMEGA, rel=1e-9)  # all of it in the platter plane
        assert np.linalg.norm(env.specific_force_g[0]) == pytest.approx(1.0)


def test_table_rate_appears_on_the_mounted_axis():
    w = World(WorldParams())
    w.set_mount("x")
    w.table.rotation.command_rate(0.0, 5.0, 10.0)
    env = settled(w, 100.0)
    assert env.rate_dps[0, 0] == pytest.approx(5.0 + OMEGA * math.sin(math.radians(LAT)), abs=1e-9)
    assert env.specific_force_g[0] == pytest.approx([1.0, 0.0, 0.0], abs=1e-12)  # x now points up


@pytest.mark.parametrize("up", ["x", "y", "z", "-x", "-y", "-z"])
def test_mounts_are_proper_rotations(up):
    m = mount_matrix(up)
    assert np.allclose(m @ m.T, np.eye(3)) and np.linalg.det(m) == pytest.approx(1.0)
    axis = "xyz".index(up[-1])
    assert (m @ [0, 0, 1.0])[axis] == (-1.0 if up.startswith("-") else 1.0)
