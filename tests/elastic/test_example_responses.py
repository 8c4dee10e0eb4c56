"""The example responses appended to the basis of a fixed object with examples: they
solve the spring-shifted systems, U keeps them M-orthonormal (its first r columns
unchanged, a direction it already holds adds nothing), the static shape an example
pull gives then lies in span U (it does not without them), and the reduced teddy with
global examples follows the full reference (41 % off it before)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import golden

from lbshape.analysis.free_body import free_body_error
from lbshape.analysis.norms import trajectory_error
from lbshape.elastic.basis import append_directions, nonlinear_basis
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.materials import Material
from lbshape.elastic.modal_derivatives import modal_derivatives
from lbshape.elastic.modes import linear_modes
from lbshape.geometry.primitives import structured_box
from lbshape.pipeline.precompute import (
    MAX_APPENDED_BASIS,
    MAX_APPENDED_FREE_BODY,
    MIN_APPENDED_FREE_BODY,
    precompute,
    stage_names,
)
from lbshape.pipeline.responses import example_response_stiffness, example_responses
from lbshape.pipeline.simulate import reduced_simulation, run_full_space
from lbshape.scene import load_scene
from lbshape.scene.variants import without_examples

MATERIAL = Material(young=2.0e5, poisson=0.3, density=1100.0)
K_EX = 400.0  # 1/s², above the bar's lowest ω² (≈ 90)


@pytest.fixture(scope="module")
def clamped():
    """A bar clamped at z = 0, its plain basis (r = 8) and a smooth target field that
    does not vanish at the clamp (as the LB reconstruction of an example does not)."""
    mesh = structured_box((0.1, 0.1, 0.6), (2, 2, 10))
    fixed = np.flatnonzero(mesh.points[:, 2] < 1e-12)
    modes = linear_modes(mesh, MATERIAL, 4, fixed_vertices=fixed)
    derivatives = modal_derivatives(mesh, MATERIAL, modes)
    M = mass_matrix(mesh, MATERIAL.density)
    basis = nonlinear_basis(modes, derivatives, M, 8)
    x, y, z = mesh.points.T
    angle = 0.4 * z / 0.6  # a twist about the bar's axis plus a sideways bend
    target = np.column_stack([x * np.cos(angle) - y * np.sin(angle) - x + 0.05 * z ** 2,
                              x * np.sin(angle) + y * np.cos(angle) - y,
                              0.01 * np.ones_like(z)]).ravel()
    return mesh, fixed, modes, M, basis, target[:, None]


def outside_share(u: np.ndarray, U: np.ndarray, M) -> float:
    rest = u - U @ (U.T @ (M @ u))
    return float(np.sqrt(rest @ (M @ rest) / (u @ (M @ u))))


def test_responses_solve_the_spring_shifted_systems(clamped):
    mesh, fixed, modes, M, _, V = clamped
    K = modes.stiffness
    X = example_responses(K, M, K_EX, V, M, fixed, depth=2)
    assert X.shape == (3 * mesh.n_vertices, 2)
    rows = (3 * fixed[:, None] + np.arange(3)).ravel()
    free = np.setdiff1d(np.arange(3 * mesh.n_vertices), rows)
    shifted = K + K_EX * M
    for column, load in ((X[:, 0], M @ V[:, 0]), (X[:, 1], M @ X[:, 0])):
        residual = (shifted @ column - load)[free]
        assert np.abs(residual).max() < 1e-9 * np.abs(load).max()
        assert np.all(column[rows] == 0.0)


def test_an_example_pulls_static_shape_lies_in_span_u_only_with_the_responses(clamped):
    mesh, fixed, modes, M, basis, V = clamped
    K = modes.stiffness
    X = example_responses(K, M, K_EX, V, M, fixed, depth=1)
    # the static shape under the example force k_ex M (v − u) alone: (K + k_ex M) u = k_ex M v
    u = K_EX * X[:, 0]
    enriched = append_directions(basis, X, M, K)
    assert outside_share(u, basis.U, M) > 0.2, "the test needs a pull the plain basis misses"
    assert outside_share(u, enriched.U, M) < 1e-8
    assert enriched.r == basis.r + 1 == enriched.U.shape[1]
    assert enriched.n_example_responses == 1


def test_appended_basis_stays_orthonormal_and_keeps_its_columns(clamped):
    mesh, fixed, modes, M, basis, V = clamped
    K = modes.stiffness
    X = example_responses(K, M, K_EX, V, M, fixed, depth=3)
    enriched = append_directions(basis, X, M, K)
    r = enriched.r
    assert basis.r < r <= basis.r + 3
    np.testing.assert_allclose(enriched.U.T @ (M @ enriched.U), np.eye(r), atol=1e-10)
    # the plain columns are kept (the Löwdin pass moves them by round-off only)
    np.testing.assert_allclose(enriched.U[:, :basis.r], basis.U, atol=1e-9 * np.abs(basis.U).max())
    np.testing.assert_allclose(enriched.omega2, np.einsum("ij,ij->j", enriched.U, K @ enriched.U))
    capped = append_directions(basis, X, M, K, max_columns=1)
    assert capped.r == basis.r + 1
    np.testing.assert_allclose(capped.U[:, basis.r:], enriched.U[:, basis.r:basis.r + 1],
                               atol=1e-9 * np.abs(enriched.U).max())
    # directions U already holds (its own columns) add nothing
    same = append_directions(basis, basis.U[:, :3], M, K)
    assert same.r == basis.r and same.n_example_responses == 0
    assert append_directions(basis, X, M, K, max_columns=0).r == basis.r


def test_which_scenes_get_example_responses():
    assert "example-basis" in stage_names(load_scene("teddy-global"))
    local = stage_names(load_scene("teddy-local"))
    assert local.index("regions") < local.index("example-basis") < local.index("cubature") \
        < local.index("projections")
    for name in ("car", "bar-s-cuboid"):  # free bodies too, without the rigid part
        scene = load_scene(name)
        assert "example-basis" in stage_names(scene)
        assert example_response_stiffness(scene) == scene.examples.stiffness
    assert "example-basis" not in stage_names(without_examples(load_scene("demo")))


@pytest.mark.slow
def test_teddy_with_global_examples_follows_the_full_reference():
    """Before the example responses the reduced teddy was 41 % off full over 0.8 s and
    already 30.8 % over the first 0.15 s (the scene's former 8 N drag and k_ex = 1000).
    At today's scene (50 N, k_ex = 100, all four limbs posed) it is 1.5 % over those
    0.15 s with them and 5.8 % without them (measured; the limit fails without them)."""
    scene = load_scene("teddy-global")
    pre = precompute(scene)
    assert pre.r > scene.reduced.r and pre.r <= MAX_APPENDED_BASIS
    np.testing.assert_allclose(pre.U.T @ (mass_matrix(pre.mesh, scene.material.density)
                                          @ pre.U), np.eye(pre.r), atol=1e-8)
    steps = 150
    reduced = reduced_simulation(scene, pre).run(steps, stride=5)
    full = run_full_space(scene, pre, steps=steps, stride=5)
    M = mass_matrix(pre.mesh, scene.material.density)
    error = trajectory_error(reduced.displacements(pre.U), full.displacements(), M)
    assert error < golden("example_responses.teddy_global_error").limit, \
        f"reduced vs full {error:.3f}"


@pytest.mark.slow
def test_the_figure4_bar_holds_its_example_pull_in_free_flight():
    """The Figure 4 bar asks for r = 30, above the free bodies' cap on appended columns
    (24), and once got no example response: in free flight, before its first bounce
    (0.28 s), its body-frame deformation was 5.6 % off the full reference, 5.5 % of the
    full one lying outside U. With its responses (r = 32) it is 0.4 % off (measured over
    those 0.28 s; the limit fails without them)."""
    scene = load_scene("bar-s-cuboid")
    pre = precompute(scene)
    plain = pre.elastic.leading or pre.r  # the basis before its impact columns
    assert MAX_APPENDED_FREE_BODY < scene.reduced.r < plain
    assert plain - scene.reduced.r <= MIN_APPENDED_FREE_BODY
    steps = 280  # the first contact is at 0.287 s
    reduced = reduced_simulation(scene, pre).run(steps, stride=5)
    full = run_full_space(scene, pre, steps=steps, stride=5)
    mass = mass_matrix(pre.mesh, scene.material.density)
    split = free_body_error(reduced.displacements(pre.U), full.displacements(None),
                            pre.mesh.points, mass)
    assert split.deformation < golden("example_responses.figure4_bar_deformation").limit, split
    assert split.rotation_deg < 0.05 and split.com_path < 1e-3, split
