"""A free body's error split into centre-of-mass path, rotation and body-frame deformation.

Known answers: a "full" trajectory built as a rigid motion (centre c(t), rotation R(t))
of the rest shape plus a known body-frame deformation D(t) that the mass-weighted best
rigid fit leaves alone (no mean, no linear part in the mass inner product, or a
stretch along the principal axes), and "reduced" trajectories that differ from it by a
known rotation, a known centre shift or a deformation scaled by 1.1.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lbshape.analysis.free_body import (
    KEYS,
    FreeBodyError,
    free_body_error,
    rotation_angle_deg,
)
from lbshape.analysis.norms import trajectory_error
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.geometry.primitives import structured_box

K = 7  # samples
TIMES = np.linspace(0.0, 0.3, K)
VELOCITY = np.array([0.8, -0.2, 0.5])  # m/s: the centre travels |v| · 0.3 s


@pytest.fixture(scope="module")
def body():
    """(rest (n, 3), mass (3n, 3n), centred rest X̄ (n, 3), deformation shape D (n, 3))."""
    mesh = structured_box((0.6, 0.2, 0.1), (6, 3, 2), origin=(0.3, -0.1, 0.2))
    mass = mass_matrix(mesh, 1000.0)
    scalar = mass[0::3, 0::3].toarray()
    rest = mesh.points
    weights = scalar.sum(axis=1) / scalar.sum()
    centred = rest - weights @ rest
    # a stretch along the principal axes: S commutes with J = X̄ᵀ M₁ X̄, so the fit's
    # (I + S) J stays symmetric positive definite and its polar factor is I
    J = centred.T @ scalar @ centred
    stretch = centred @ (0.05 * J / np.trace(J))
    # a bend (z grows with x²) with its affine part removed in the M₁ inner product
    affine = np.column_stack([np.ones(len(rest)), centred])
    bend = np.zeros_like(rest)
    bend[:, 2] = 0.4 * centred[:, 0] ** 2
    bend -= affine @ np.linalg.solve(affine.T @ scalar @ affine, affine.T @ scalar @ bend)
    return rest, mass, centred, stretch + bend


def _trajectory(body, *, rotation_offset=None, shift=None, scale=1.0):
    """(K, 3n) world displacements ``c(t) + R(t)(X̄ + D(t)) − X`` of the moving body."""
    rest, _, centred, shape = body
    center0 = rest[0] - centred[0]  # the rest shape's centre of mass
    frames = []
    for i, t in enumerate(TIMES):
        R = Rotation.from_rotvec(np.array([0.3, -1.1, 0.7]) * t).as_matrix()
        if rotation_offset is not None:
            R = rotation_offset[i] @ R
        c = center0 + VELOCITY * t + (0.0 if shift is None else shift[i])
        deformation = scale * np.sin(8.0 * t) * shape
        frames.append(c + (centred + deformation) @ R.T - rest)
    return np.array(frames).reshape(K, -1)


def test_rotation_angle_of_known_rotations():
    for angle in (1e-7, 0.3, 2.0, np.pi - 1e-6):
        R = Rotation.from_rotvec(angle * np.array([2.0, -1.0, 0.5]) / np.sqrt(5.25)).as_matrix()
        np.testing.assert_allclose(rotation_angle_deg(R), np.degrees(angle), rtol=1e-9)
    assert rotation_angle_deg(np.eye(3)) == 0.0


def test_identical_runs_have_zero_error(body):
    rest, mass, _, _ = body
    u = _trajectory(body)
    error = free_body_error(u, u.copy(), rest, mass)
    assert error == FreeBodyError(0.0, 0.0, 0.0), error
    assert tuple(error.stats()) == KEYS


def test_a_rotation_offset_is_its_angle_and_no_deformation_error(body):
    """Off by a rotation that grows to 7 degrees: the angle is 7, the centre and the
    deformation agree, while the whole-field error is large."""
    rest, mass, _, _ = body
    degrees = 7.0 * TIMES / TIMES[-1]
    offsets = [Rotation.from_rotvec(np.radians(a) * np.array([0.0, 0.6, 0.8])).as_matrix()
               for a in degrees]
    full = _trajectory(body)
    reduced = _trajectory(body, rotation_offset=offsets)
    error = free_body_error(reduced, full, rest, mass)
    np.testing.assert_allclose(error.rotation_deg, 7.0, rtol=1e-9)
    assert error.com_path is not None and error.com_path < 1e-12, error
    assert error.deformation is not None and error.deformation < 1e-9, error
    assert trajectory_error(reduced, full, mass) > 0.05  # the rigid motion dominates it


def test_a_centre_shift_is_its_length_over_the_path(body):
    """Shifted by 4 mm at the worst sample; the centre travels |v| · 0.3 s."""
    rest, mass, _, _ = body
    direction = np.array([1.0, 2.0, -2.0]) / 3.0
    shift = 0.004 * np.sin(np.pi * TIMES / TIMES[-1] / 2.0)[:, None] * direction
    error = free_body_error(_trajectory(body, shift=shift), _trajectory(body), rest, mass)
    np.testing.assert_allclose(error.com_path, 0.004 / (np.linalg.norm(VELOCITY) * 0.3),
                               rtol=1e-9)
    assert error.rotation_deg < 1e-9 and error.deformation < 1e-9, error


def test_a_deformation_scaled_by_1_1_is_a_10_percent_deformation_error(body):
    rest, mass, _, _ = body
    error = free_body_error(_trajectory(body, scale=1.1), _trajectory(body), rest, mass)
    np.testing.assert_allclose(error.deformation, 0.1, rtol=1e-9)
    assert error.com_path < 1e-12 and error.rotation_deg < 1e-9, error


def test_rotation_and_deformation_errors_together(body):
    """Both at once: each number sees only its own part (shapes (K, n, 3) accepted)."""
    rest, mass, _, _ = body
    offset = Rotation.from_rotvec([0.0, 0.0, np.radians(3.0)]).as_matrix()
    reduced = _trajectory(body, rotation_offset=[offset] * K, scale=0.8)
    error = free_body_error(reduced.reshape(K, -1, 3), _trajectory(body).reshape(K, -1, 3),
                            rest, mass)
    np.testing.assert_allclose(error.rotation_deg, 3.0, rtol=1e-9)
    np.testing.assert_allclose(error.deformation, 0.2, rtol=1e-9)


def test_undefined_ratios_are_none_and_bad_input_raises(body):
    rest, mass, _, _ = body
    still = np.zeros((K, 3 * len(rest)))
    moving = _trajectory(body)
    error = free_body_error(moving, still, rest, mass)
    assert error.com_path is None and error.deformation is None, error
    assert free_body_error(still, still, rest, mass) == FreeBodyError(0.0, 0.0, 0.0)
    with pytest.raises(LbshapeError, match="same non-empty"):
        free_body_error(moving, moving[:2], rest, mass)
    with pytest.raises(LbshapeError, match="do not match"):
        free_body_error(moving[:, :-3], moving[:, :-3], rest, mass)
