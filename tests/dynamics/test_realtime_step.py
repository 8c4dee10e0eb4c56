"""The real-time reduced step: compiled kernels against numpy, the allocation-free step
against the generic implicit stepper, the real-time Newton tolerance against converged
Newton."""

from __future__ import annotations

import dataclasses
import tracemalloc

import numpy as np
import pytest
from conftest import golden

from lbshape.dynamics.engine import NewtonSettings
from lbshape.dynamics.integrators import make_stepper
from lbshape.dynamics.loads import TimedLoad, TimeProfile
from lbshape.dynamics.reduced import REALTIME_RTOL, ReducedSimulation
from lbshape.elastic.energy_densities import density_model
from lbshape.elastic.jit_densities import density_parameters, stress_and_tangent
from lbshape.elastic.materials import Material
from lbshape.elastic.reduced_forces import ReducedForceModel
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import reduced_simulation
from lbshape.scene import load_scene

MATERIALS = [Material("stvk", young=1e6, poisson=0.3, density=1000.0),
             Material("neohookean", young=1e6, poisson=0.45, density=1000.0)]


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("LBSHAPE_CACHE", str(tmp_path_factory.mktemp("cache")))
        scene = load_scene("demo")
        return scene, precompute(scene)


@pytest.mark.parametrize("material", MATERIALS, ids=lambda m: m.model)
def test_compiled_stress_and_tangent_match_numpy(material):
    rng = np.random.default_rng(3)
    s = 40
    H = 0.3 * rng.standard_normal((3, 3, s))
    P, A = density_model(material).stress_and_derivative_t(H)
    P9, A_jit = np.zeros((9, s)), np.zeros((s, 9, 9))
    code, parameters = density_parameters(material)
    stress_and_tangent(code, parameters, np.ascontiguousarray(H.reshape(9, s)), P9, A_jit)
    scale = np.abs(A).max()
    np.testing.assert_allclose(P9, P.reshape(9, s), rtol=0, atol=1e-13 * scale)
    np.testing.assert_allclose(A_jit, A.reshape(81, s).T.reshape(s, 9, 9), rtol=0,
                               atol=1e-13 * scale)


@pytest.mark.parametrize("material", MATERIALS, ids=lambda m: m.model)
def test_force_and_tangent_into_matches_the_reference(demo, material):
    _, pre = demo
    model = ReducedForceModel(pre.mesh.points, pre.mesh.tets, material, pre.U,
                              pre.elastic.cubature_elements, pre.elastic.cubature_weights)
    q = 0.2 * np.random.default_rng(1).standard_normal(pre.r)
    f, K = model.force_and_tangent(q)
    f_into, K_into = np.zeros(pre.r), np.zeros((pre.r, pre.r))
    model.force_and_tangent_into(q, f_into, K_into)
    np.testing.assert_allclose(f_into, f, rtol=0, atol=1e-12 * np.abs(f).max())
    np.testing.assert_allclose(K_into, K, rtol=0, atol=1e-12 * np.abs(K).max())


@pytest.mark.parametrize("integrator", ["newmark", "backward-euler"])
def test_converged_step_matches_the_generic_implicit_stepper(demo, integrator):
    """No examples, gravity ramp and a torque: the same equations, two implementations."""
    scene, pre = demo
    model = ReducedForceModel(pre.mesh.points, pre.mesh.tets, pre.material, pre.U,
                              pre.elastic.cubature_elements, pre.elastic.cubature_weights)
    rng = np.random.default_rng(2)
    pattern = 50.0 * rng.standard_normal(pre.r)
    profile = TimeProfile("ramp", 0.0, 0.02)
    dt, alpha, beta = 1e-3, 0.5, 0.01
    fast = ReducedSimulation(model, r=pre.r, dt=dt, integrator=integrator, alpha=alpha,
                             beta=beta, loads=[TimedLoad(pattern, profile)],
                             newton_iterations=None,
                             newton=NewtonSettings(1e-12, 20))
    _, K0 = model.force_and_tangent(np.zeros(pre.r))
    reference = make_stepper(integrator, np.eye(pre.r), model.force_and_tangent, dt=dt,
                             external=lambda t: profile(t) * pattern, alpha=alpha, beta=beta,
                             damping_stiffness=K0, rtol=1e-12)
    for _ in range(60):
        fast.step()
        reference.step()
    scale = np.abs(reference.x).max()
    assert scale > 1e-4
    np.testing.assert_allclose(fast.x, reference.x, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(fast.v, reference.v, rtol=0, atol=1e-8 * np.abs(reference.v).max())


def test_the_real_time_tolerance_stays_on_the_converged_trajectory(demo):
    """The real-time step (Newton to REALTIME_RTOL, its first update linearised at the start
    of the step) against converged Newton at dt = 1 ms (golden value: 5e-7 relative, limit
    1e-4, 200x margin); it costs under 2 updates per step on average (measured 1.97)."""
    scene, pre = demo
    realtime = reduced_simulation(scene, pre).run(200)
    converged = reduced_simulation(scene, pre, newton=NewtonSettings(1e-12, 20)).run(200)
    q1, qc = realtime.states, converged.states
    difference = np.abs(q1 - qc).max() / np.abs(qc).max()
    assert realtime.stable and converged.stable
    limit = golden("realtime_step.realtime_vs_converged").limit
    assert difference < limit, f"real-time tolerance vs converged: {difference:.2e}"
    assert realtime.newton_iterations.mean() <= converged.newton_iterations.mean()


def test_every_accepted_step_meets_the_residual_tolerance(demo):
    """The residual is measured at the state each step accepts, never assumed."""
    scene, pre = demo
    sim = reduced_simulation(scene, pre)
    residuals = []
    for _ in range(100):
        sim.step()
        residuals.append(sim.last_residual)
    assert max(residuals) <= REALTIME_RTOL
    assert max(residuals) > 0.0  # measured, not skipped


def test_the_step_allocates_no_arrays(demo):
    """After warm-up, traced memory does not grow over 200 steps, and its transient peak
    (interpreter frames, argument tuples) stays below the size of one r × r matrix, so no
    r × r, s-sized or n-sized array is made per step (r raised to 30 to separate them)."""
    scene, _ = demo
    scene = dataclasses.replace(scene, reduced=dataclasses.replace(scene.reduced, r=30))
    pre = precompute(scene)
    sim = reduced_simulation(scene, pre)
    for _ in range(20):
        sim.step()
    tracemalloc.start()
    try:
        before, _ = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        for _ in range(200):
            sim.step()
        after, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert after - before < 8 * pre.r, (before, after)
    assert peak - before < 8 * pre.r * pre.r / 2, (before, peak)


def test_a_newton_failure_ends_the_run_with_the_step_named(demo):
    scene, pre = demo
    model = ReducedForceModel(pre.mesh.points, pre.mesh.tets, pre.material, pre.U,
                              pre.elastic.cubature_elements, pre.elastic.cubature_weights)
    huge = TimedLoad(1e9 * np.ones(pre.r), TimeProfile("constant", 0.0, 0.0))
    record = ReducedSimulation(model, r=pre.r, dt=1e-3, loads=[huge], newton_iterations=None,
                               newton=NewtonSettings(REALTIME_RTOL, 2)).run(50)
    assert not record.stable and record.steps < 50
    assert "Newton did not converge at step" in record.message, record.message
