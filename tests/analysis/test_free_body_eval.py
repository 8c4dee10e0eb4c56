"""The field's measures of a free body: the pre-contact window, the symmetric surface
distance, the impact measures and the projection of a full state.

Known answers: a square bar turned 90° about its long axis (the same surface, other
vertices where) is 0 apart, a bent one is not; a point's distance to a triangle agrees
with a dense sampling of the triangle; a trajectory that departs from its reference
only after the first contact has no error before it; a rigid cloud that reverses its
normal velocity at half the speed has restitution ½ and the momentum change m·1.5 v.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lbshape.analysis.free_body_eval import (
    first_contact,
    impact_measures,
    point_surface_distances,
    project_state,
    surface_distance,
    window_error,
)
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.geometry.primitives import structured_box

FLOOR = SimpleNamespace(point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0))


@pytest.fixture(scope="module")
def bar():
    """A square bar 0.2 × 0.2 × 1 m, long axis z, centred on the z axis."""
    mesh = structured_box((0.2, 0.2, 1.0), (2, 2, 6), origin=(-0.1, -0.1, 0.0))
    return mesh, mesh.boundary_faces(), float(np.linalg.norm([0.2, 0.2, 1.0]))


def test_a_square_bar_turned_90_degrees_about_its_long_axis_is_0_apart(bar):
    mesh, triangles, diagonal = bar
    turned = mesh.points @ Rotation.from_euler("z", 90, degrees=True).as_matrix().T
    moved = np.abs(turned - mesh.points).max()
    assert moved > 0.1  # the vertices did move: a vertex-to-vertex distance would see it
    distance = surface_distance(turned, mesh.points, triangles, diagonal)
    assert distance.chamfer < 1e-12 and distance.hausdorff < 1e-12


def test_a_bent_or_shifted_bar_is_apart_by_what_moved(bar):
    mesh, triangles, diagonal = bar
    bent = mesh.points.copy()
    bent[:, 0] += 0.1 * bent[:, 2] ** 2  # the far end 0.1 m sideways
    distance = surface_distance(bent, mesh.points, triangles, diagonal)
    assert distance.hausdorff == pytest.approx(0.1 / diagonal, rel=0.05)
    assert 0.005 < distance.chamfer < distance.hausdorff
    shifted = surface_distance(mesh.points + [0.0, 0.0, 0.05], mesh.points, triangles,
                               diagonal)
    assert shifted.hausdorff == pytest.approx(0.05 / diagonal, rel=1e-9)


def test_point_to_triangle_distance_matches_a_dense_sampling():
    rng = np.random.default_rng(3)
    triangle = rng.normal(size=(3, 3))
    points = 2.0 * rng.normal(size=(40, 3))
    s, t = np.meshgrid(np.linspace(0, 1, 301), np.linspace(0, 1, 301))
    keep = s + t <= 1.0
    samples = (triangle[0] + s[keep, None] * (triangle[1] - triangle[0])
               + t[keep, None] * (triangle[2] - triangle[0]))
    dense = np.linalg.norm(points[:, None] - samples[None], axis=-1).min(axis=1)
    exact = point_surface_distances(points, triangle, np.array([[0, 1, 2]]))
    assert np.all(exact <= dense + 1e-12)
    np.testing.assert_allclose(exact, dense, atol=0.02)


def _falling(rest: np.ndarray, steps: int, dt: float, bounce: int | None = None):
    """Positions (steps, n, 3) of a rigid cloud moving at −1 m/s in z from 0.05 m above the
    floor; from sample ``bounce`` on it moves up at 0.5 m/s."""
    lift = 0.05 - rest[:, 2].min()
    z = np.array([lift - dt * k for k in range(steps)])
    if bounce is not None:
        z[bounce:] = z[bounce - 1] + 0.5 * dt * np.arange(1, steps - bounce + 1)
    return rest[None] + z[:, None, None] * np.array([0.0, 0.0, 1.0])


def test_the_pre_contact_window_ends_at_the_first_penetration(bar):
    mesh, _, _ = bar
    mass = mass_matrix(mesh, 1000.0)
    dt = 0.01
    points = _falling(mesh.points, 12, dt)
    contact = first_contact(points, [FLOOR])
    assert contact == 6  # 0.05 m at 1 m/s: behind the floor from t = 0.06 s on
    u_full = points - mesh.points
    u = u_full.copy()
    u[contact:] += 0.01  # the run departs from the reference only in contact
    assert window_error(u, u_full, mass, contact) == 0.0
    assert window_error(u, u_full, mass, contact + 1) > 0.01
    assert window_error(u, u_full, mass, 0) is None
    assert first_contact(points[:contact], [FLOOR]) is None


def test_a_rigid_bounce_at_half_speed_has_restitution_one_half(bar):
    mesh, _, _ = bar
    mass = mass_matrix(mesh, 1000.0)
    total = float(mass.sum()) / 3.0
    dt = 0.01
    points = _falling(mesh.points, 14, dt, bounce=7)
    measures = impact_measures(points, mass, dt, np.array([0.0, 0.0, 1.0]), np.zeros(3),
                               [FLOOR], 2, 10)
    assert measures.restitution == pytest.approx(0.5, rel=1e-9)
    np.testing.assert_allclose(measures.delta_p, [0.0, 0.0, 1.5 * total], atol=1e-9 * total)
    np.testing.assert_allclose(measures.delta_L, 0.0, atol=1e-9 * total)
    assert measures.energy_lost == pytest.approx(0.75, rel=1e-9)
    assert measures.depth == pytest.approx(0.01, rel=1e-9)
    with pytest.raises(LbshapeError):
        impact_measures(points, mass, dt, np.array([0.0, 0.0, 1.0]), np.zeros(3), [FLOOR],
                        0, 10)


def test_a_rigid_spinning_state_projects_onto_its_frame_and_momenta(bar):
    mesh, _, _ = bar
    mass = mass_matrix(mesh, 1000.0)
    total = float(mass.sum()) / 3.0
    rest = mesh.points
    center = (mass[0::3, 0::3] @ rest).sum(axis=0) / total
    dt, velocity, spin = 1e-3, np.array([0.3, -0.2, 1.0]), np.array([0.0, 2.0, 0.5])
    frames = np.stack([center + k * dt * velocity
                       + (rest - center) @ Rotation.from_rotvec(k * dt * spin).as_matrix().T
                       for k in (2, 3, 4)])
    basis = np.zeros((rest.size, 1))
    basis[2::3, 0] = rest[:, 2] - center[2]  # a stretch along z
    state = project_state(frames, dt, rest, mass, basis)
    np.testing.assert_allclose(state.c, center + 3 * dt * velocity, atol=1e-12)
    np.testing.assert_allclose(state.R, Rotation.from_rotvec(3 * dt * spin).as_matrix(),
                               atol=1e-12)
    np.testing.assert_allclose(state.p, total * velocity, rtol=1e-9)
    np.testing.assert_allclose(state.q, 0.0, atol=1e-12)
    arm = frames[1] - state.c
    inertia = np.asarray(mass[0::3, 0::3] @ arm).T @ arm
    world_inertia = np.trace(inertia) * np.eye(3) - inertia
    expected = world_inertia @ spin
    np.testing.assert_allclose(state.L, expected, atol=1e-5 * np.linalg.norm(expected))


def test_a_body_resting_on_a_plane_to_round_off_is_not_in_contact(bar):
    mesh, _, _ = bar
    points = mesh.points - [0.0, 0.0, 1e-17]  # its lowest vertices 1e-17 m behind the floor
    assert first_contact(points[None], [FLOOR]) is None
    assert first_contact((points - [0.0, 0.0, 1e-6])[None], [FLOOR]) == 0
