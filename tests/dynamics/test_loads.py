"""External load patterns: resultants and moments against their definitions."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from lbshape.dynamics.loads import (
    TimeProfile,
    gravity_pattern,
    region_force_pattern,
    region_torque_pattern,
)
from lbshape.errors import LbshapeError
from lbshape.geometry.primitives import structured_box


def _mass(mesh, density=1000.0):
    """Consistent P1 vector mass (node-major), built independently here."""
    vol = np.abs(mesh.signed_volumes())
    local = (np.ones((4, 4)) + np.eye(4)) / 20.0
    rows = np.repeat(mesh.tets, 4, axis=1).ravel()
    cols = np.tile(mesh.tets, (1, 4)).ravel()
    scalar = sp.csr_matrix(
        ((density * vol[:, None, None] * local).ravel(), (rows, cols)),
        shape=(mesh.n_vertices,) * 2,
    )
    return sp.kron(scalar, sp.eye(3)).tocsr()


MESH = structured_box((0.2, 0.2, 1.0), (2, 2, 6))
MASS = _mass(MESH)


def test_gravity_resultant_is_weight():
    f = gravity_pattern(MASS, [0, 0, -9.81]).reshape(-1, 3)
    total_mass = 1000.0 * MESH.volume()
    np.testing.assert_allclose(f.sum(axis=0), [0, 0, -9.81 * total_mass], rtol=1e-12)


def test_region_force_resultant_and_support():
    bottom = np.flatnonzero(MESH.points[:, 2] < 1e-9)
    f = region_force_pattern(MASS, bottom, [1.0, -2.0, 3.0]).reshape(-1, 3)
    np.testing.assert_allclose(f.sum(axis=0), [1.0, -2.0, 3.0], rtol=1e-12)
    assert np.count_nonzero(np.abs(f).sum(axis=1)) == bottom.size


def test_region_torque_moment_and_zero_resultant():
    bottom = np.flatnonzero(MESH.points[:, 2] < 1e-9)
    tau = np.array([0.0, 0.0, 2.5])
    f = region_torque_pattern(MASS, MESH.points, bottom, tau).reshape(-1, 3)
    centre = MESH.points[bottom].mean(axis=0)
    moment = np.cross(MESH.points - centre, f).sum(axis=0)
    np.testing.assert_allclose(moment, tau, atol=1e-12)
    np.testing.assert_allclose(f.sum(axis=0), 0.0, atol=1e-12)
    with pytest.raises(LbshapeError, match="extent"):
        region_torque_pattern(MASS, MESH.points, bottom[:1], tau)


def test_profiles():
    ramp = TimeProfile("ramp", start=0.1, duration=0.2)
    assert [ramp(t) for t in (0.0, 0.1, 0.2, 0.3, 1.0)] == pytest.approx([0, 0, 0.5, 1, 1])
    pulse = TimeProfile("pulse", start=0.0, duration=0.1)
    assert (pulse(0.05), pulse(0.1)) == (1.0, 0.0)
    assert TimeProfile()(0.0) == 1.0
    with pytest.raises(LbshapeError, match="duration"):
        TimeProfile("ramp")
    with pytest.raises(LbshapeError, match="one of"):
        TimeProfile("sawtooth")
