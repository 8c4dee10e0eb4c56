"""Full-space reference simulation and the all-element example energy, against truth:
finite differences, exact projections, the linear static solution, the linear
eigenfrequency with Newmark's period elongation, the example equilibrium and the
reduced method in a complete mass-orthonormal basis."""

from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.linalg as sla
import scipy.sparse.linalg as spla
from conftest import central_difference_errors, observed_rates, rel

import lbshape.dynamics.full_examples as full_examples
from lbshape.dynamics.engine import NewtonSettings
from lbshape.dynamics.full import (
    FullSpaceExamples,
    FullSpaceSimulator,
)
from lbshape.dynamics.loads import TimedLoad, TimeProfile, gravity_pattern
from lbshape.dynamics.reduced import ReducedSimulation
from lbshape.dynamics.rigid_frame import best_rigid_frame
from lbshape.elastic.element_kernels import FullSpaceElasticity, mass_matrix
from lbshape.elastic.materials import MODELS, Material
from lbshape.elastic.modes import rigid_body_modes
from lbshape.elastic.reduced_forces import ReducedForceModel
from lbshape.errors import LbshapeError, SolverError
from lbshape.geometry.primitives import structured_box
from lbshape.pipeline.simulate import run_full_space
from lbshape.shapespace.euclidean_energy import EuclideanExampleEnergy
from lbshape.shapespace.example_driver import ExampleDriver
from lbshape.shapespace.interpolation import TargetSolver
from lbshape.spectral.spectrum import lb_spectrum

M_LB = 4  # LB eigenfunctions of the test shape spaces


def material(model: str = "stvk") -> Material:
    return Material(model, young=1.0e5, poisson=0.3, density=1000.0)


def block_basis(phi: np.ndarray) -> np.ndarray:
    """L = Φ ⊗ I₃ (3n, 3m), node-major rows, column 3i + comp."""
    return np.kron(phi, np.eye(3))


@pytest.fixture(scope="module")
def bar():
    """A 0.4 m × 0.1 m × 0.1 m bar (81 vertices), its LB pairs, fixed end x = 0."""
    mesh = structured_box((0.4, 0.1, 0.1), (8, 2, 2))
    spectrum = lb_spectrum(mesh, M_LB)
    fixed = np.flatnonzero(mesh.points[:, 0] < 1e-9)
    return SimpleNamespace(mesh=mesh, lam=spectrum.eigenvalues, phi=spectrum.eigenvectors,
                           fixed=fixed)


def example_coefficients(phi: np.ndarray, pattern, largest: float) -> np.ndarray:
    """(m, 3) coefficients of a smooth LB displacement scaled to ``largest`` metres."""
    c = np.asarray(pattern, dtype=float).reshape(phi.shape[1], 3)
    return c * largest / np.abs(phi @ c).max()


def linear_problem(sim: FullSpaceSimulator):
    """(K₀, M) on the free dofs of a simulator, from the full-space assemblies."""
    free = sim.free_dofs
    K0 = sim.elastic.tangent(np.zeros(3 * sim.n_vertices))
    return K0[free][:, free].tocsc(), sim.mass[free][:, free].tocsc()


# ---------------------------------------------------------------- example energy
@pytest.mark.parametrize("model", MODELS)
def test_example_energy_is_the_projected_full_space_energy(bar, model):
    """E, g, H equal FullSpaceElasticity(rest = X_k) projected with B, to round-off."""
    mesh, phi = bar.mesh, bar.phi
    c_k = example_coefficients(phi, np.arange(1.0, 3 * M_LB + 1), 0.03)
    rest = mesh.points + phi @ c_k
    L = block_basis(phi)
    energy = EuclideanExampleEnergy(rest, mesh.tets, material(model), L)
    full = FullSpaceElasticity(mesh.with_points(rest), material(model))
    rng = np.random.default_rng(11)
    y = rng.normal(size=3 * M_LB)
    y *= 0.02 / np.abs(L @ y).max()
    g, H = energy.force_and_tangent(y)
    assert energy.n_elements == mesh.n_tets
    e_full = full.energy(L @ y)
    assert abs(energy.energy(y) - e_full) <= 1e-12 * e_full, (energy.energy(y), e_full)
    assert rel(g, L.T @ full.force(L @ y)) < 1e-11, rel(g, L.T @ full.force(L @ y))
    H_full = L.T @ (full.tangent(L @ y) @ L)
    assert rel(H, H_full) < 1e-11, rel(H, H_full)
    assert energy.energy(np.zeros(3 * M_LB)) == 0.0


@pytest.mark.parametrize("model", MODELS)
def test_example_energy_derivatives_match_finite_differences(bar, model):
    mesh, phi = bar.mesh, bar.phi
    rest = mesh.points + phi @ example_coefficients(phi, np.ones(3 * M_LB), 0.02)
    energy = EuclideanExampleEnergy(rest, mesh.tets, material(model), block_basis(phi))
    rng = np.random.default_rng(12)
    y = rng.normal(size=3 * M_LB) * 1e-3
    d = rng.normal(size=3 * M_LB)
    d *= np.linalg.norm(y) / np.linalg.norm(d)
    g, H = energy.force_and_tangent(y)
    steps = np.array([0.04, 0.02, 0.01])
    grad_errors = central_difference_errors(energy.energy, lambda _: g, y, d, steps)
    hess_errors = central_difference_errors(energy.force, lambda _: H, y, d, steps)
    for name, errors in (("gradient", grad_errors), ("Hessian", hess_errors)):
        rates = observed_rates(errors, steps)
        assert np.all(rates > 1.8), f"{name}: FD rates {rates}, errors {errors}"
        assert errors[-1] < 1e-4, f"{name}: FD error {errors[-1]:.2e} at h = {steps[-1]}"
    assert rel(H, H.T) < 1e-13


# ------------------------------------------------------------------------ statics
def gravity_run(bar, acceleration: float):
    mesh, mat = bar.mesh, material()
    g = gravity_pattern(mass_matrix(mesh, mat.density), np.array([0.0, 0.0, -acceleration]))
    probe = FullSpaceSimulator(mesh, mat, dt=1.0, fixed_vertices=bar.fixed)
    K, M = linear_problem(probe)
    omega1 = float(np.sqrt(sla.eigh(K.toarray(), M.toarray(), eigvals_only=True)[0]))
    # backward Euler with ζ ≥ 1 in every mode (α = ω₁, β = 1/ω₁): settles in ~10 T₁
    sim = FullSpaceSimulator(mesh, mat, dt=0.5 * np.pi / omega1, fixed_vertices=bar.fixed,
                             integrator="backward-euler", alpha=omega1, beta=1.0 / omega1,
                             loads=[TimedLoad(g, TimeProfile())])
    result = sim.run(60, stride=20)
    static = spla.spsolve(K, g[sim.free_dofs])
    settled = result.displacements()[-1].reshape(-1)[sim.free_dofs]
    before = result.displacements()[-2].reshape(-1)[sim.free_dofs]
    return rel(settled, static), rel(before, settled)


def test_cantilever_settles_to_the_linear_static_solution(bar):
    err_small, drift_small = gravity_run(bar, 0.005)
    err_large, _ = gravity_run(bar, 0.01)
    # settled (the last 20 steps changed nothing) ...
    assert drift_small < 1e-6, f"still moving: relative change {drift_small:.2e}"
    # ... within the geometric nonlinearity of the load, which is linear in the load
    assert err_small < 5e-4, f"relative error vs K u = f: {err_small:.3e}"
    ratio = err_large / err_small
    assert 1.9 < ratio < 2.1, f"error ratio for twice the load {ratio:.3f} (errors "\
        f"{err_small:.3e}, {err_large:.3e}); expected ~2 (nonlinearity)"


# ----------------------------------------------------------------------- dynamics
def test_first_mode_period_matches_eigenfrequency_with_newmark_stretch(bar):
    mesh, mat = bar.mesh, material()
    probe = FullSpaceSimulator(mesh, mat, dt=1.0, fixed_vertices=bar.fixed)
    K, M = linear_problem(probe)
    w2, V = sla.eigh(K.toarray(), M.toarray(), subset_by_index=(0, 0))
    omega, mode = float(np.sqrt(w2[0])), V[:, 0]
    u0 = np.zeros(3 * mesh.n_vertices)
    u0[probe.free_dofs] = mode * 1e-6 / np.abs(mode).max()  # 1 µm tip: linear regime
    dt = (2 * np.pi / omega) / 16
    sim = FullSpaceSimulator(mesh, mat, dt=dt, fixed_vertices=bar.fixed,
                             initial_displacement=u0.reshape(-1, 3),
                             newton=NewtonSettings(1e-12, 20))
    result = sim.run(48)  # three periods
    x = result.displacements().reshape(len(result.times), -1)[:, probe.free_dofs]
    q = x @ (M @ mode)  # modal coordinate: sampled A cos(ω̃ t) for Newmark
    # q_{n+1} + q_{n-1} = 2 cos(ω̃ Δt) q_n, least squares over the run
    cos_wdt = float(q[1:-1] @ (q[2:] + q[:-2]) / (2 * q[1:-1] @ q[1:-1]))
    observed = (2 * np.pi / np.arccos(cos_wdt) * dt) / (2 * np.pi / omega)
    wdt = omega * dt
    expected = wdt / (2 * np.arctan(wdt / 2))  # Newmark (β=¼, γ=½) period stretch
    assert abs(observed / expected - 1) < 1e-5, (
        f"T_num/T = {observed:.7f}, Newmark stretch {expected:.7f} (ωΔt = {wdt:.3f})"
    )
    assert expected - 1 > 1e-2  # the stretch is resolved: a missing one would fail
    residual = np.abs(q[2:] + q[:-2] - 2 * cos_wdt * q[1:-1]).max() / np.abs(q).max()
    assert residual < 1e-6, f"modal coordinate is not a single sinusoid ({residual:.2e})"


# ----------------------------------------------------------------- example force
def test_strong_example_force_pulls_a_free_body_to_the_example_shape(bar):
    """A free body is pulled to the example's shape in its own rigid frame (rigid content
    of the target removed), not anchored to the world: its centre of mass stays put."""
    mesh, mat, phi = bar.mesh, material(), bar.phi
    c1 = example_coefficients(phi, [0, 0, 1, 0, 0.5, 0, 0.3, 0, 0, 0, 0, 0.2], 0.01)
    k_ex = 1e7
    sim = FullSpaceSimulator(mesh, mat, dt=1 / np.sqrt(k_ex), integrator="backward-euler",
                             alpha=2 * np.sqrt(k_ex),
                             examples=FullSpaceExamples(bar.lam, phi, c1[None], k_ex))
    result = sim.run(60, stride=20)
    u = result.displacements()[-1]
    rigid = rigid_body_modes(mesh.points, sim.mass)
    target = (phi @ c1).ravel()
    target = (target - rigid @ (rigid.T @ (sim.mass @ target))).reshape(-1, 3)
    M1 = sim.mass[0::3, 0::3]
    center, _, body = best_rigid_frame(M1, mesh.points, mesh.points + u)
    err = rel(body, target)
    assert err < 1e-2, f"relative distance to the example shape {err:.3e}"
    rest_center = np.asarray(M1.sum(axis=1)).ravel() @ mesh.points / np.asarray(M1.sum())
    assert np.linalg.norm(center - rest_center) < 1e-9
    np.testing.assert_allclose(sim.target_coefficients, c1.ravel(), rtol=0, atol=1e-12 *
                               np.abs(c1).max())
    assert result.stable and result.steps == 60
    # the interpolation is a part of each step (structure, not speed)
    assert result.t_interp_ms.shape == result.t_total_ms.shape == (60,)
    assert np.all(result.t_total_ms >= result.t_interp_ms) and np.all(result.t_interp_ms >= 0)


def test_zero_example_stiffness_builds_and_calls_no_example_machinery(bar, monkeypatch):
    mesh, mat = bar.mesh, material()
    g = gravity_pattern(mass_matrix(mesh, mat.density), np.array([0.0, 0.0, -9.81]))
    loads = [TimedLoad(g, TimeProfile("ramp", 0.0, 0.05))]
    plain = FullSpaceSimulator(mesh, mat, dt=0.01, fixed_vertices=bar.fixed, loads=loads)
    reference = plain.run(12, stride=3)

    def forbidden(*args, **kwargs):
        raise AssertionError("example machinery used with k_ex = 0")

    for name in ("SimplexWeights", "EuclideanExampleEnergy", "TargetSolver",
                 "ReusedHessianTargetSolver"):
        monkeypatch.setattr(full_examples, name, forbidden)
    c1 = example_coefficients(bar.phi, np.ones(3 * M_LB), 0.01)
    examples = FullSpaceExamples(bar.lam, bar.phi, c1[None], 0.0)
    sim = FullSpaceSimulator(mesh, mat, dt=0.01, fixed_vertices=bar.fixed, loads=loads,
                             examples=examples)
    assert not sim.uses_examples
    result = sim.run(12, stride=3)
    np.testing.assert_array_equal(result.displacements(), reference.displacements())
    np.testing.assert_array_equal(result.times, reference.times)
    assert result.max_displacement > 0


def test_full_space_is_the_reduced_method_in_a_complete_mass_orthonormal_basis():
    """U = all free dofs, UᵀMU = I, all elements: the reduced runtime (euclidean
    route) and the full-space simulator integrate the same equations."""
    mesh = structured_box((0.3, 0.1, 0.1), (3, 1, 1))
    mat = material()
    spectrum = lb_spectrum(mesh, M_LB)
    lam, phi = spectrum.eigenvalues, spectrum.eigenvectors
    fixed = np.flatnonzero(mesh.points[:, 0] < 1e-9)
    coefficients = np.stack([
        example_coefficients(phi, [0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0], 0.02),
        example_coefficients(phi, [0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0], 0.02),
    ])
    k_ex, dt, alpha, beta = 400.0, 0.004, 2.0, 1e-4
    M = mass_matrix(mesh, mat.density)
    g = gravity_pattern(M, np.array([0.0, -3.0, -9.81]))
    profile = TimeProfile("ramp", 0.0, 0.04)
    sim = FullSpaceSimulator(mesh, mat, dt=dt, fixed_vertices=fixed, alpha=alpha, beta=beta,
                             loads=[TimedLoad(g, profile)], newton=NewtonSettings(1e-12, 20),
                             examples=FullSpaceExamples(lam, phi, coefficients, k_ex))
    weights = []
    full = sim.run(40, on_step=lambda i, t, u: weights.append(sim.weights.copy()))
    weights = np.array(weights)

    free = sim.free_dofs
    chol = np.linalg.cholesky(M[free][:, free].toarray())
    U = np.zeros((3 * mesh.n_vertices, free.size))
    U[free] = np.linalg.inv(chol).T  # UᵀMU = I
    L = block_basis(phi)
    volume_mass = M / mat.density
    D = np.repeat(lam, 3)[:, None] * (L.T @ (volume_mass @ U))
    T = U.T @ (M @ L)
    k = coefficients.shape[0]
    flat = coefficients.reshape(k, -1)
    models = [EuclideanExampleEnergy(mesh.points + phi @ c, mesh.tets, mat, L)
              for c in coefficients]
    driver = ExampleDriver(D, flat * np.repeat(lam, 3), TargetSolver(models, flat),
                           to_reduced=T)
    elastic = ReducedForceModel(mesh.points, mesh.tets, mat, U, np.arange(mesh.n_tets),
                                np.ones(mesh.n_tets))
    reduced = ReducedSimulation(elastic, r=free.size, dt=dt, alpha=alpha, beta=beta,
                                loads=[TimedLoad(U.T @ g, profile)], driver=driver, k_ex=k_ex)
    reduced.newton = NewtonSettings(1e-12, 20)
    # its energy monitor counts the target's pull as potential energy appearing at
    # step 1 from rest; the full-space one counts it as external work
    reduced.stepper.energy_factor = None
    record = reduced.run(40)
    assert record.stable, record.message
    u_reduced = (np.asarray(record.states) @ U.T).reshape(full.displacements().shape)
    assert np.abs(full.displacements()).max() > 1e-3  # a real motion, example-driven
    err = rel(full.displacements(), u_reduced)
    assert err < 1e-7, f"full-space vs complete-basis reduced trajectory: {err:.2e}"
    # both examples blend, with weights that change along the run
    assert weights.min() > 0.1 and np.ptp(weights[:, 0]) > 0.2, weights[::8]


# --------------------------------------------------------------------- failures
def test_absurd_load_stops_the_run_naming_the_step_and_keeps_the_partial_run(bar):
    mesh, mat = bar.mesh, material()
    dt = 0.01
    g = gravity_pattern(mass_matrix(mesh, mat.density), np.array([0.0, 0.0, -1e4]))
    sim = FullSpaceSimulator(mesh, mat, dt=dt, fixed_vertices=bar.fixed,
                             loads=[TimedLoad(g, TimeProfile("ramp", 0.0, 0.1))])
    partial = sim.run(30)
    found = re.search(r"at step (\d+) \(t = ([0-9.e+-]+) s\)", partial.message)
    assert found, f"message names no step and time: {partial.message}"
    step, t = int(found.group(1)), float(found.group(2))
    assert not partial.stable
    with pytest.raises(SolverError, match=f"at step {step} "):  # step() raises, state kept
        sim.step()
    assert step >= 2, f"expected a failure after some good steps, got step {step}"
    assert partial.steps == step - 1 and len(partial.displacements()) == step
    assert t == pytest.approx(step * dt, rel=1e-6)
    # what was kept is the run up to the last good step
    again = FullSpaceSimulator(mesh, mat, dt=dt, fixed_vertices=bar.fixed,
                               loads=[TimedLoad(g, TimeProfile("ramp", 0.0, 0.1))])
    np.testing.assert_array_equal(again.run(step - 1).displacements(), partial.displacements())


def test_scene_adapter_reports_a_divergence_as_unstable_with_the_partial_run(bar):
    mesh, mat = bar.mesh, material()
    c1 = example_coefficients(bar.phi, np.ones(3 * M_LB), 0.05)
    scene = SimpleNamespace(
        name="t", planes=(), regions=(), loads=(),
        examples=SimpleNamespace(stiffness=1e4, auto=False, ramp=0.0),
        simulation=SimpleNamespace(dt=0.01, integrator="newmark"),
        damping=SimpleNamespace(alpha=0.0, beta=0.0),
    )
    pre = SimpleNamespace(mesh=mesh, material=mat, fixed_vertices=bar.fixed, has_examples=True,
                          shape=SimpleNamespace(eigenvalues=bar.lam, eigenvectors=bar.phi),
                          examples=SimpleNamespace(example_coefficients=c1[None]),
                          elastic=SimpleNamespace(omega2=np.zeros(0)))
    record = run_full_space(scene, pre, steps=6, stride=2)
    times, frames, stable, message = (record.times, record.displacements(), record.stable,
                                      record.message)
    t_interp, t_total = record.mean_ms(warmup=1)
    direct = FullSpaceSimulator(mesh, mat, dt=0.01, fixed_vertices=bar.fixed,
                                examples=FullSpaceExamples(bar.lam, bar.phi, c1[None], 1e4))
    expected = direct.run(6, stride=2)
    assert stable and message == ""
    np.testing.assert_array_equal(frames, expected.displacements())
    np.testing.assert_allclose(times, [0.0, 0.02, 0.04, 0.06])
    assert 0 <= t_interp <= t_total  # the interpolation is a part of the step
    # an absurd load: Newton fails, the adapter keeps the run
    scene.loads = (SimpleNamespace(type="gravity", vector=(0.0, 0.0, -1e4), selection=None,
                                   profile=TimeProfile("ramp", 0.0, 0.1)),)
    scene.examples = None
    record = run_full_space(scene, pre, steps=30, stride=1)
    frames, stable, message = record.displacements(), record.stable, record.message
    found = re.search(r"step (\d+) \(t = ", message)
    assert not stable and found, message
    assert len(frames) == int(found.group(1)), (len(frames), message)


def test_bad_inputs_raise_lbshape_error(bar):
    mesh, mat = bar.mesh, material()
    n = mesh.n_vertices
    with pytest.raises(LbshapeError, match="out of range"):
        FullSpaceSimulator(mesh, mat, dt=0.01, fixed_vertices=[n])
    with pytest.raises(LbshapeError, match="every vertex is fixed"):
        FullSpaceSimulator(mesh, mat, dt=0.01, fixed_vertices=np.arange(n))
    with pytest.raises(LbshapeError, match="pattern must have shape"):
        FullSpaceSimulator(mesh, mat, dt=0.01,
                           loads=[TimedLoad(np.zeros(n), TimeProfile())])
    with pytest.raises(LbshapeError, match="dt must be > 0"):
        FullSpaceSimulator(mesh, mat, dt=0.0)
    with pytest.raises(LbshapeError, match="k_ex"):
        FullSpaceSimulator(mesh, mat, dt=0.01, examples=FullSpaceExamples(
            bar.lam, bar.phi, np.zeros((1, M_LB, 3)), -1.0))
    with pytest.raises(LbshapeError, match="example coefficients"):
        FullSpaceSimulator(mesh, mat, dt=0.01, examples=FullSpaceExamples(
            bar.lam, bar.phi, np.zeros((1, M_LB + 1, 3)), 1.0))
    u0 = np.zeros((n, 3))
    u0[bar.fixed[0]] = 1e-3
    with pytest.raises(LbshapeError, match="zero on the fixed vertices"):
        FullSpaceSimulator(mesh, mat, dt=0.01, fixed_vertices=bar.fixed, initial_displacement=u0)
    with pytest.raises(LbshapeError, match="integrator"):
        FullSpaceSimulator(mesh, mat, dt=0.01, integrator="euler")
    with pytest.raises(LbshapeError, match="basis U must have shape"):
        EuclideanExampleEnergy(mesh.points, mesh.tets, mat, np.zeros((3 * n - 1, 2)))
