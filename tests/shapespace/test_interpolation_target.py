"""The nonlinear target (paper eqs. 4 and 6) on its three routes: modal, lb, euclidean.

Fixture: a 0.2 × 0.2 × 1 m StVK bar (structured, 208 vertices, 648 tets) fixed at
its top, its own twists about the z axis as examples (same mesh, so the LB
coefficients are exact projections, no alignment). The mesh is mapped onto itself
by the mirror ``(x, y, z) -> (y, x, z)``, which turns a twist by +θ into one by −θ:
the symmetry test relies on it. The elastic basis, its cubature, the LB spectrum
and the LB-subspace cubature come from the pipeline's stage functions.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from conftest import golden
from scipy.spatial import cKDTree

from lbshape.elastic.basis import default_linear_modes, nonlinear_basis
from lbshape.elastic.cubature import train_cubature
from lbshape.elastic.cubature_poses import inverse_frequency_scales
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.materials import Material
from lbshape.elastic.modal_derivatives import modal_derivatives
from lbshape.elastic.modes import linear_modes
from lbshape.geometry.poses import twist
from lbshape.geometry.primitives import structured_box
from lbshape.pipeline.precomputed import (
    ElasticSpace,
    GlobalExamples,
    LBCubatures,
    Precomputed,
    ShapeBasis,
)
from lbshape.pipeline.routes import ROUTES, example_driver, target_solver
from lbshape.shapespace.example_targets import tabulate_examples
from lbshape.shapespace.projections import lb_coefficients, reduced_projection
from lbshape.spectral.spectrum import lb_spectrum

MATERIAL = Material("stvk", young=1e6, poisson=0.3, density=1000.0)
#: LB modes: z-modes 1-5, the two cross-section modes and their products with z-mode
#: 1 (a clear gap follows: 282 -> 323 1/m²), so the mirror maps span Φ to itself
M_MODES = 9
R_BASIS = 30
S_ELEMENTS = 60
#: LB cubature training amplitude (fraction of the bar length): the twists below
#: move vertices by up to ~0.2 m relative to each other
LB_MAGNITUDE = 0.2


@pytest.fixture(scope="module")
def base() -> tuple[Precomputed, object]:
    """Object-side precompute of the bar and its LB mass matrix (n, n).

    Examples are filled in by :func:`_with_twists`; both cubatures have s = 60.
    """
    mesh = structured_box((0.2, 0.2, 1.0), (3, 3, 12), (-0.1, -0.1, 0.0))
    fixed = np.flatnonzero(mesh.points[:, 2] > 0.999)
    modes = linear_modes(mesh, MATERIAL, default_linear_modes(R_BASIS), fixed_vertices=fixed)
    basis = nonlinear_basis(modes, modal_derivatives(mesh, MATERIAL, modes),
                            mass_matrix(mesh, MATERIAL.density), R_BASIS)
    cubature = train_cubature(mesh, MATERIAL, basis.U, rng=np.random.default_rng(11),
                              scales=inverse_frequency_scales(basis.omega2),
                              max_elements=S_ELEMENTS, tol=0.0)
    spectrum = lb_spectrum(mesh, M_MODES + 1)
    gap = spectrum.eigenvalues[M_MODES] / spectrum.eigenvalues[M_MODES - 1]
    assert gap > 1.1, f"no spectral gap after mode {M_MODES}: {spectrum.eigenvalues}"
    phi = spectrum.eigenvectors[:, :M_MODES]
    eigenvalues = spectrum.eigenvalues[:M_MODES]
    shape = ShapeBasis(eigenvalues, phi, ("rest",), mesh, fixed)
    lb = train_cubature(mesh, MATERIAL, shape.lb_basis(), rng=np.random.default_rng(12),
                        scales=inverse_frequency_scales(np.repeat(eigenvalues, 3)),
                        max_elements=S_ELEMENTS, tol=0.0, magnitude=LB_MAGNITUDE)
    pre = Precomputed(
        scene="twisted-bar", key="", mesh=mesh, material=MATERIAL, fixed_vertices=fixed,
        elastic=ElasticSpace(
            U=basis.U, omega2=np.asarray(modes.omega2), cubature_elements=cubature.elements,
            cubature_weights=cubature.weights,
            cubature_errors={"train": cubature.train_error, "holdout": cubature.holdout_error}),
        shape=shape,
        examples=GlobalExamples(
            shape=shape, density=MATERIAL.density,
            example_coefficients=np.zeros((1, M_MODES, 3)),
            projection=reduced_projection(basis.U, phi, spectrum.mass, MATERIAL.density),
            alignment_residuals=np.zeros(1),
            lb_cubatures=LBCubatures(lb.elements, lb.weights,
                                     np.array([lb.train_error, lb.holdout_error]))),
    )
    return pre, spectrum.mass


#: the routes that solve the target by Newton at run time (``lb-table`` interpolates)
SOLVED_ROUTES = [route for route in ROUTES if route != "lb-table"]
_TABLES: dict = {}


def _with_twists(base, angles) -> Precomputed:
    """``base`` with one example per twist angle (rad; top end kept in place), and the
    target table of the precompute's ``target-table`` stage (free LB basis)."""
    pre, lb_mass = base
    points = pre.mesh.points
    coefficients = np.array([
        lb_coefficients(twist(points, angle=a, axis="z", anchor="max") - points,
                        pre.shape.eigenvectors, lb_mass)
        for a in angles
    ])
    key = (id(pre), tuple(angles))
    if key not in _TABLES:
        _TABLES[key] = tabulate_examples(points, pre.mesh.tets, pre.material,
                                         pre.shape.eigenvectors, coefficients,
                                         mass=lb_mass).table
    shape = dataclasses.replace(
        pre.shape, example_names=tuple(f"twist {a:+.2f}" for a in angles))
    return dataclasses.replace(pre, shape=shape, examples=dataclasses.replace(
        pre.examples, shape=shape, example_coefficients=coefficients,
        alignment_residuals=np.zeros(len(angles)), target_table=_TABLES[key]))


def _m_norm(pre: Precomputed, u: np.ndarray) -> float:
    """‖u‖_M in the volume mass (m^(5/2)); u (n, 3) or (3n,)."""
    u = np.asarray(u).ravel()
    return float(np.sqrt(u @ (mass_matrix(pre.mesh, 1.0) @ u)))


def _mirror(pre: Precomputed):
    """The map u -> S u of displacement fields (n, 3) under (x, y, z) -> (y, x, z)."""
    points = pre.mesh.points
    distance, image = cKDTree(points).query(points[:, [1, 0, 2]])
    assert distance.max() < 1e-12, "the bar mesh is not mirror symmetric"
    return lambda u: np.asarray(u).reshape(-1, 3)[image][:, [1, 0, 2]]


def _end_rotation(pre: Precomputed, u: np.ndarray) -> float:
    """Mean rotation (rad) about z of the free (bottom) face's vertices under u (n, 3)."""
    points = pre.mesh.points
    bottom = points[:, 2] < 1e-9
    before = points[bottom, :2]
    after = before + np.asarray(u).reshape(-1, 3)[bottom, :2]
    keep = np.linalg.norm(before, axis=1) > 1e-9
    before, after = before[keep], after[keep]
    cross = before[:, 0] * after[:, 1] - before[:, 1] * after[:, 0]
    return float(np.mean(np.arctan2(cross, np.einsum("ij,ij->i", before, after))))


# -- exactness at the examples ------------------------------------------------------------
@pytest.mark.parametrize("route", ROUTES)
def test_a_single_example_is_its_own_target(base, route):
    pre = _with_twists(base, [0.8])
    setup = target_solver(pre, route, tolerance=1e-10)
    z1 = setup.offsets[0]
    # from the rest shape, a large move (the whole twist) away from the answer
    result = setup.solver.solve(np.ones(1), start=np.zeros_like(z1))
    error = np.linalg.norm(result.z - z1) / np.linalg.norm(z1)
    assert error < 1e-8, f"{route}: target differs from the example by {error:.2e} ({result})"
    # and the runtime driver hands the same q* = T c_1 to the dynamics on every route
    driver = example_driver(pre, route=route)
    info = driver.target(np.zeros(pre.r))
    q1 = pre.examples.lb_to_reduced @ pre.examples.example_coefficients[0].ravel()
    np.testing.assert_allclose(info.weights, [1.0])
    np.testing.assert_allclose(info.q_target, q1, rtol=0, atol=1e-8 * np.linalg.norm(q1))


@pytest.mark.parametrize("route", ROUTES)
def test_vertex_weights_give_each_example(base, route):
    pre = _with_twists(base, [0.8, -0.4])
    setup = target_solver(pre, route, tolerance=1e-10)
    for index, weights in enumerate(([1.0, 0.0], [0.0, 1.0])):
        goal, other = setup.offsets[index], setup.offsets[1 - index]
        result = setup.solver.solve(np.array(weights), start=other)  # start at the other one
        error = np.linalg.norm(result.z - goal) / np.linalg.norm(goal)
        assert error < 1e-8, (
            f"{route}, weights {weights}: {error:.2e} from the example after "
            f"{result.iterations} Newton steps"
        )


# -- derivatives ---------------------------------------------------------------------------
@pytest.mark.parametrize("route", SOLVED_ROUTES)
def test_gradient_and_hessian_match_finite_differences(base, route):
    """Central differences of F (and of ∇F) converge to ∇F (∇²F) at second order."""
    pre = _with_twists(base, [0.8, -0.4])
    solver = target_solver(pre, route).solver
    rng = np.random.default_rng(4)
    weights = np.array([0.3, 0.7])
    scale = np.abs(solver.offsets).max()
    z = weights @ solver.offsets + 0.1 * scale * rng.standard_normal(solver.dimension)
    g, H = solver.gradient_and_hessian(z, weights)
    identity = np.eye(solver.dimension)
    g_errors, H_errors = [], []
    for h in (1e-3 * scale, 1e-4 * scale):
        g_fd = np.array([(solver.energy(z + h * e, weights) - solver.energy(z - h * e, weights))
                         / (2 * h) for e in identity])
        H_fd = np.column_stack([
            (solver.gradient_and_hessian(z + h * e, weights)[0]
             - solver.gradient_and_hessian(z - h * e, weights)[0]) / (2 * h) for e in identity])
        g_errors.append(np.linalg.norm(g_fd - g) / np.linalg.norm(g))
        H_errors.append(np.linalg.norm(H_fd - H) / np.linalg.norm(H))
    for name, errors in (("gradient", g_errors), ("Hessian", H_errors)):
        rate = math.log10(errors[0] / errors[1])
        assert errors[1] < 1e-6 and rate > 1.8, (
            f"{route}: {name} vs central differences: errors {errors} (h, h/10), "
            f"observed order {rate:.2f}"
        )
    np.testing.assert_allclose(H, H.T, rtol=0, atol=1e-12 * np.abs(H).max())


# -- properties of the interpolated target ------------------------------------------------
def _all_elements(pre: Precomputed) -> Precomputed:
    """``pre`` with both cubatures replaced by all elements at unit weight (exact energies)."""
    t = pre.mesh.n_tets
    return dataclasses.replace(
        pre, elastic=dataclasses.replace(pre.elastic, cubature_elements=np.arange(t),
                                         cubature_weights=np.ones(t)),
        examples=dataclasses.replace(pre.examples, lb_cubatures=LBCubatures(
            np.arange(t), np.ones(t), pre.examples.lb_cubatures.errors)))


#: |end rotation| / θ left at weights (½, ½) of twists by ±θ = ±0.8 rad by the routes
#: whose energies are cubatures (s = 60 of 648 elements; the other routes sum all
#: elements and are symmetric to round-off). What is left is the cubature's asymmetry, a
#: property of the drawn rule, not of the route. Measured (fixture seeds 11 and 12, the
#: same at OMP_NUM_THREADS 1 and 2): modal 0.128 rad = 0.16 θ; over 64 seeds of its
#: cubature median 0.015 rad, largest 0.138 rad; lb 0.019 rad = 0.024 θ (24 seeds:
#: median 0.022, largest 0.059 rad). Limits: modal 0.35 θ = 0.28 rad (2.2× margin; 2.0×
#: over the worst of 64 seeds), lb 0.05 θ = 0.04 rad (2.1× margin). A broken
#: interpolation still fails: one example alone turns the end by 0.72 (modal) and
#: 0.73 rad (lb), weights (0.65, 0.35) instead of (½, ½) by 0.30 and 0.24 rad.
CUBATURE_ROTATION = {route: golden(f"interpolation_target.cubature_rotation_{route}").limit
                     for route in ("modal", "lb")}


@pytest.mark.parametrize("route", ROUTES)
def test_opposite_twists_average_to_the_rest_shape(base, route):
    """Weights (½, ½) of a +θ and a −θ twist: the mirror maps each example onto the
    other, so with exact energies the target is mirror symmetric (no twist left)
    and near the rest shape (what remains is a symmetric shortening / contraction);
    with cubature energies the symmetry holds up to the cubature's error."""
    theta = 0.8
    pre = _with_twists(base, [theta, -theta])
    mirror = _mirror(pre)
    L = pre.shape.lb_basis()
    example, opposite = (L @ c.ravel() for c in pre.examples.example_coefficients)
    size = _m_norm(pre, example)
    mirrored = _m_norm(pre, mirror(example) - opposite.reshape(-1, 3)) / size
    assert mirrored < 1e-12, f"the mirror maps example 1 to example 2 only to {mirrored:.1e}"
    # exact energies (all elements): symmetric to round-off on every route
    exact = target_solver(_all_elements(pre), route, tolerance=1e-10)
    u = exact.displacement(exact.solver.solve(np.array([0.5, 0.5])).z)
    asymmetry = _m_norm(pre, u - mirror(u)) / size
    rotation = _end_rotation(pre, u)
    assert asymmetry < 1e-9 and abs(rotation) < 1e-9 * theta, (
        f"{route} (all elements): asymmetry {asymmetry:.2e}, end rotation {rotation:.2e} rad"
    )
    # the limit is half-way to an example (1.0)
    distance = _m_norm(pre, u) / size
    assert distance < golden("interpolation_target.distance_from_rest").limit, \
        f"{route} (all elements): target is {distance:.3f} ‖u_ex‖ from rest"
    if route not in CUBATURE_ROTATION:  # no cubature: the energies above are the scene's
        return
    # the scene's cubature energies: the twist still mostly cancels
    setup = target_solver(pre, route)
    u = setup.displacement(setup.solver.solve(np.array([0.5, 0.5])).z)
    rotation = _end_rotation(pre, u)
    assert abs(rotation) < CUBATURE_ROTATION[route] * theta, (
        f"{route}: end rotation {rotation:.4f} rad left from twists of ±{theta} rad"
    )


#: stated agreement with the Euclidean target, ‖u − u_euclid‖_M / ‖u_euclid‖_M, for
#: twists of 0.8 and 0.3 rad at weights (0.7, 0.3). Measured: lb 0.0051 (limit 0.02,
#: 3.9× margin); modal 0.187, the same with all elements: the gap is the search space,
#: span U vs span L — U reproduces each example only to 12.5 % in the M-norm — not the
#: cubature (limit 0.4, 2.1× margin; a target left at rest is 1.0 away).
AGREEMENT = {route: golden(f"interpolation_target.agreement_{route}").limit
             for route in ("lb", "modal")}


@pytest.mark.parametrize("route", ["lb", "modal"])
def test_reduced_targets_agree_with_the_euclidean_target(base, route):
    pre = _with_twists(base, [0.8, 0.3])
    weights = np.array([0.7, 0.3])
    euclidean = target_solver(pre, "euclidean", tolerance=1e-10)
    u_ref = euclidean.displacement(euclidean.solver.solve(weights).z)
    setup = target_solver(pre, route, tolerance=1e-10)
    u = setup.displacement(setup.solver.solve(weights).z)
    error = _m_norm(pre, u - u_ref) / _m_norm(pre, u_ref)
    assert error < AGREEMENT[route], (
        f"{route} target differs from the Euclidean one by {error:.4f} (M-norm, relative)"
    )
    if route == "modal":  # the gap is at least U's error on the examples themselves
        L = pre.shape.lb_basis()
        c = pre.examples.example_coefficients.reshape(2, -1)
        projection = max(_m_norm(pre, pre.U @ (pre.examples.lb_to_reduced @ ck) - L @ ck)
                         / _m_norm(pre, L @ ck) for ck in c)
        # compared with the gap of exact energies (all elements), a property of span U,
        # not of the cubature: measured 0.125 < 0.187
        exact = target_solver(_all_elements(pre), route, tolerance=1e-10)
        gap = _m_norm(pre, exact.displacement(exact.solver.solve(weights).z) - u_ref)
        gap /= _m_norm(pre, u_ref)
        assert 0.05 < projection < gap, (
            f"projection error of the examples on U {projection:.4f}, target error with "
            f"all elements {gap:.4f}"
        )


@pytest.mark.parametrize("route", SOLVED_ROUTES)
def test_warm_start_saves_iterations_on_a_nearby_call(base, route):
    pre = _with_twists(base, [0.8, 0.3])
    solver = target_solver(pre, route).solver
    solver.solve(np.array([0.6, 0.4]))
    nearby = np.array([0.62, 0.38])
    warm = solver.solve(nearby)  # starts from the previous target
    solver.reset()
    cold = solver.solve(nearby)  # starts from Σ w_k z_k
    assert warm.iterations < cold.iterations, (
        f"{route}: warm start {warm.iterations} Newton steps, cold {cold.iterations}"
    )
    gap = np.linalg.norm(warm.z - cold.z) / np.linalg.norm(cold.z)
    assert gap < 1e-8, f"{route}: warm and cold starts end {gap:.2e} apart"
