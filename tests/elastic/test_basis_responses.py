"""Static-response vectors in the basis: they solve their systems (with the modal
derivatives' factorisation of K), U keeps them exactly
after the linear modes, a load's linear static solution then lies in span U (it does not
without them), and a scene's responses are what its loads ask for. The example
responses appended after the basis: ``tests/elastic/test_example_responses.py``."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from lbshape.elastic.basis import RESPONSE_MIN_OUTSIDE, nonlinear_basis
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.materials import Material
from lbshape.elastic.modal_derivatives import modal_derivatives
from lbshape.elastic.modes import linear_modes
from lbshape.errors import LbshapeError
from lbshape.geometry.primitives import structured_box
from lbshape.pipeline.meshes import build_mesh, selected_vertices
from lbshape.pipeline.responses import mesh_load_patterns, response_loads
from lbshape.scene import load_scene

MATERIAL = Material(young=2.0e5, poisson=0.3, density=1100.0)
K_MODES = 4


@pytest.fixture(scope="module")
def clamped():
    mesh = structured_box((0.1, 0.1, 0.6), (2, 2, 10))
    fixed = np.flatnonzero(mesh.points[:, 2] < 1e-12)
    modes = linear_modes(mesh, MATERIAL, K_MODES, fixed_vertices=fixed)
    return mesh, fixed, modes, modal_derivatives(mesh, MATERIAL, modes,
                                                 static_loads=tip_loads(mesh))


def tip_loads(mesh) -> np.ndarray:
    """(3n, 2): a sideways pull on one tip corner and a twisting couple on the tip."""
    n = mesh.n_vertices
    tip = np.flatnonzero(mesh.points[:, 2] > mesh.points[:, 2].max() - 1e-12)
    F = np.zeros((n, 3, 2))
    F[tip[0], 0, 0] = 1.0
    centre = mesh.points[tip].mean(axis=0)
    for v in tip:
        F[v, :, 1] = np.cross([0.0, 0.0, 1.0], mesh.points[v] - centre)
    return F.reshape(3 * n, 2)


def m_angles(A, B, M) -> np.ndarray:
    L = np.linalg.cholesky(M.toarray())
    return scipy.linalg.subspace_angles(L.T @ A, L.T @ B)


def test_static_responses_solve_their_systems(clamped):
    mesh, fixed, modes, derivatives = clamped
    K = modes.stiffness
    F = tip_loads(mesh)
    X = derivatives.static_responses
    assert X.shape == F.shape and derivatives.vectors.shape[1] == derivatives.pairs.shape[0]
    free = np.setdiff1d(np.arange(3 * mesh.n_vertices), (3 * fixed[:, None] + np.arange(3)))
    residual = (K @ X - F)[free]
    assert np.abs(residual).max() < 1e-9 * np.abs(F).max()
    assert np.abs(X.reshape(-1, 3, 2)[fixed]).max() == 0.0
    # the same derivatives as without loads: one factorisation serves both
    alone = modal_derivatives(mesh, MATERIAL, modes)
    assert np.abs(alone.vectors - derivatives.vectors).max() < 1e-10 * np.abs(alone.vectors).max()
    assert alone.static_responses.shape == (3 * mesh.n_vertices, 0)
    free_modes = linear_modes(mesh, MATERIAL, 7)
    with pytest.raises(LbshapeError, match="need a clamped body"):
        modal_derivatives(mesh, MATERIAL, free_modes, pairs=[[6, 6]], static_loads=F)
    with pytest.raises(LbshapeError, match="static_loads must be a finite"):
        modal_derivatives(mesh, MATERIAL, modes, static_loads=F[:-1])


def test_responses_the_plain_basis_misses_are_kept_exactly_after_the_linear_modes(clamped):
    mesh, fixed, modes, derivatives = clamped
    M = modes.mass
    X = derivatives.static_responses
    r = 10
    plain = nonlinear_basis(modes, derivatives, M, r).U
    share = [float(np.sqrt(v @ (M @ v) / (x @ (M @ x))))
             for x in X.T for v in [x - plain @ (plain.T @ (M @ x))]]
    # the sideways pull is (nearly) a bending mode; the tip twist is no low mode
    assert share[0] < RESPONSE_MIN_OUTSIDE < share[1]
    basis = nonlinear_basis(modes, derivatives, M, r, responses=X)
    assert basis.n_responses == 1 and basis.U.shape[1] == r
    assert np.abs(basis.U.T @ (M @ basis.U) - np.eye(r)).max() < 1e-10
    head = basis.U[:, : K_MODES + 1]
    assert m_angles(head, np.hstack([modes.vectors, X[:, 1:]]), M).max() < 1e-8
    assert m_angles(basis.U[:, :K_MODES], modes.vectors, M).max() < 1e-8
    # responses the plain basis holds leave it unchanged; r ≤ k keeps the lowest modes
    again = nonlinear_basis(modes, derivatives, M, r, responses=np.hstack([X[:, :1],
                                                                        plain[:, -2:]]))
    assert again.n_responses == 0 and np.abs(again.U - plain).max() < 1e-12
    small = nonlinear_basis(modes, derivatives, M, 3, responses=X)
    assert small.n_responses == 0 and np.abs(small.U - modes.vectors[:, :3]).max() < 1e-12
    with pytest.raises(LbshapeError, match="responses must be a finite"):
        nonlinear_basis(modes, derivatives, M, r, responses=X[:-1])
    with pytest.raises(LbshapeError, match="keep_linear=True"):
        nonlinear_basis(modes, derivatives, M, r, responses=X, keep_linear=False)


def test_a_load_static_solution_lies_in_span_u_only_with_responses(clamped):
    mesh, fixed, modes, derivatives = clamped
    M = modes.mass
    X = derivatives.static_responses
    u = X[:, 1]  # the linear static solution of the tip twist

    def outside(U):
        rest = u - U @ (U.T @ (M @ u))
        return float(np.sqrt(rest @ (M @ rest) / (u @ (M @ u))))

    plain = nonlinear_basis(modes, derivatives, M, 8).U
    enriched = nonlinear_basis(modes, derivatives, M, 8, responses=X).U
    assert outside(enriched) < 1e-8
    assert outside(plain) > 0.5, "the test needs a load the plain basis misses"


@pytest.mark.parametrize("name", [pytest.param("teddy-local", marks=pytest.mark.slow), "demo"])
def test_scene_responses_answer_its_loads(name):
    scene = load_scene(name)
    mesh = build_mesh(scene.object)
    fixed = selected_vertices(scene.fixed, mesh)
    M = mass_matrix(mesh, scene.material.density)
    modes = linear_modes(mesh, scene.material, 1, fixed_vertices=fixed)
    K = modes.stiffness
    X = modal_derivatives(mesh, scene.material, modes,
                          static_loads=response_loads(scene, mesh, M, fixed)).static_responses
    loads = np.column_stack([load.pattern for load in mesh_load_patterns(scene, mesh, M)])
    assert X.shape == (3 * mesh.n_vertices, len(scene.loads)) == loads.shape
    free = np.ones(3 * mesh.n_vertices, dtype=bool)
    free[(3 * fixed[:, None] + np.arange(3)).ravel()] = False
    residual = (K @ X - loads)[free]
    assert np.abs(residual).max() < 1e-8 * np.abs(loads).max()


def test_a_free_body_gets_no_responses():
    mesh = structured_box((0.3, 0.1, 0.1), (3, 1, 1))
    scene = load_scene("car")
    M = mass_matrix(mesh, scene.material.density)
    X = response_loads(scene, mesh, M, np.zeros(0, int))
    assert X.shape == (3 * mesh.n_vertices, 0)


def test_cache_key_follows_what_the_responses_depend_on():
    import dataclasses

    from lbshape.pipeline.precompute_key import scene_cache_key

    scene = load_scene("demo")
    key = scene_cache_key(scene)
    load = scene.loads[0]

    def with_vector(vector):
        return dataclasses.replace(scene, loads=(dataclasses.replace(load, vector=vector),))

    # a load's size sets the static equilibria the basis holds: part of the key
    assert scene_cache_key(with_vector(tuple(2.5 * np.asarray(load.vector)))) != key
    # the example responses are shifted by k_ex: its value is part of the key
    assert scene_cache_key(dataclasses.replace(
        scene, examples=dataclasses.replace(scene.examples, stiffness=1.0))) != key
    # so are a load's direction, its presence and whether the examples pull
    assert scene_cache_key(with_vector((100.0, 0.0, 0.0))) != key
    assert scene_cache_key(dataclasses.replace(scene, loads=())) != key
    assert scene_cache_key(dataclasses.replace(
        scene, examples=dataclasses.replace(scene.examples, stiffness=0.0))) != key
