"""Implicit steppers against analytic properties of Newmark and backward Euler."""

from __future__ import annotations

import re

import numpy as np
import pytest
import scipy.sparse as sp
from conftest import observed_rates
from scipy.integrate import solve_ivp

from lbshape.dynamics.integrators import (
    BackwardEulerStepper,
    NewmarkStepper,
    make_stepper,
)
from lbshape.dynamics.sanity import ENERGY_FACTOR
from lbshape.dynamics.schemes import INTEGRATORS
from lbshape.errors import LbshapeError, SolverError


def linear_modes(omega):
    """Reduced linear system: f = diag(ω²) x, M = I."""
    K = np.diag(np.asarray(omega, dtype=float) ** 2)
    return np.eye(K.shape[0]), (lambda x: (K @ x, K)), (lambda x: 0.5 * x @ K @ x)


def cubic_springs(K, c):
    """f = K x + c x³ (elementwise cubic), tangent K + diag(3 c x²)."""
    def force_and_tangent(x):
        extra = 3.0 * c * x**2
        if sp.issparse(K):
            return K @ x + c * x**3, (K + sp.diags(extra)).tocsr()
        return K @ x + c * x**3, K + np.diag(extra)
    return force_and_tangent


def zero_crossing_period(t, x):
    """Period from the zero crossings (linear interpolation, least-squares slope)."""
    i = np.flatnonzero(np.sign(x[:-1]) * np.sign(x[1:]) < 0)
    crossings = t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i])
    slope = np.polyfit(np.arange(crossings.size), crossings, 1)[0]
    return 2.0 * slope


def test_undamped_linear_newmark_conserves_energy_and_needs_one_newton_iteration():
    rng = np.random.default_rng(7)
    omega = np.array([1.0, 3.0, 7.0, 15.0, 40.0])
    mass, fk, potential = linear_modes(omega)
    stepper = NewmarkStepper(mass, fk, dt=0.01, x0=rng.normal(size=5), v0=rng.normal(size=5),
                             potential=potential, rtol=1e-12)
    e0 = stepper.total_energy()
    infos = stepper.run(5000)
    energies = np.array([info.energy for info in infos])
    drift = np.max(np.abs(energies - e0)) / e0
    assert drift < 1e-12, f"relative energy drift {drift:.2e} over 5000 steps"
    iterations = {info.iterations for info in infos}
    assert iterations == {1}, f"linear system took {iterations} Newton iterations"


def test_newmark_period_elongation_matches_formula():
    dt = 0.01
    wdt = np.array([0.5, 1.0, 1.5])
    mass, fk, _ = linear_modes(wdt / dt)
    stepper = NewmarkStepper(mass, fk, dt=dt, x0=np.ones(3))
    steps = 4000
    xs = [stepper.x.copy()]
    for _ in range(steps):
        stepper.step()
        xs.append(stepper.x.copy())
    xs = np.array(xs)
    t = dt * np.arange(steps + 1)
    for k, w in enumerate(wdt):
        observed = zero_crossing_period(t, xs[:, k]) / (2 * np.pi * dt / w)
        expected = w / (2.0 * np.arctan(w / 2.0))
        assert abs(observed / expected - 1) < 1e-6, (
            f"ωΔt={w}: T_num/T observed {observed:.6f}, expected {expected:.6f}"
        )


def test_backward_euler_dissipates_at_the_analytic_rate():
    dt = 0.01
    omega = np.array([2.0, 20.0, 100.0])
    mass, fk, potential = linear_modes(omega)
    stepper = BackwardEulerStepper(mass, fk, dt=dt, x0=np.ones(3), v0=np.ones(3),
                                   potential=potential)

    def mode_energy():
        return 0.5 * stepper.v**2 + 0.5 * omega**2 * stepper.x**2

    e0 = mode_energy()
    n = 200
    totals = [info.energy for info in stepper.run(n)]
    assert np.all(np.diff(totals) < 0), "backward Euler energy must decrease every step"
    ratio = mode_energy() / e0
    expected = (1.0 + (omega * dt) ** 2) ** (-n)
    np.testing.assert_allclose(ratio, expected, rtol=1e-9,
                               err_msg=f"per-mode energy ratio {ratio} vs {expected}")


def test_newton_converges_quadratically_on_cubic_springs():
    K = np.diag([4.0, 9.0])
    fk = cubic_springs(K, c=np.array([400.0, 900.0]))
    stepper = NewmarkStepper(np.eye(2), fk, dt=0.05, v0=np.array([3.0, -2.0]), rtol=1e-13)
    rates = []
    for info in stepper.run(5):
        r = np.array(info.residuals)
        r = r[r > 1e-12]  # above round-off
        assert info.iterations >= 3, f"expected a genuinely nonlinear solve, got {info.residuals}"
        rates += list(np.log(r[2:] / r[1:-1]) / np.log(r[1:-1] / r[:-2]))
    rates = np.array(rates)
    assert rates.size >= 3 and rates.min() > 1.7, f"observed Newton orders {rates}"


@pytest.mark.parametrize(("integrator", "order", "coarsest"),
                         [("newmark", 2.0, 100), ("backward-euler", 1.0, 800)])
def test_damped_forced_nonlinear_convergence_order(integrator, order, coarsest):
    """Against a tight ODE reference with D = αM + βK(0): observed order 2 / 1."""
    M = np.array([[2.0, 0.5], [0.5, 1.0]])
    K = np.array([[40.0, -10.0], [-10.0, 25.0]])
    c = np.array([30.0, 10.0])
    alpha, beta = 0.4, 0.01
    D = alpha * M + beta * K
    load = np.array([1.0, -2.0])

    def external(t):
        return load * np.sin(3.0 * t)

    x0, v0, T = np.array([0.3, -0.1]), np.array([0.0, 0.5]), 2.0

    def rhs(t, y):
        x, v = y[:2], y[2:]
        return np.concatenate([v, np.linalg.solve(M, external(t) - D @ v - K @ x - c * x**3)])

    ref = solve_ivp(rhs, (0, T), np.concatenate([x0, v0]), method="DOP853",
                    rtol=1e-12, atol=1e-14, dense_output=True)
    errors, divisions = [], (coarsest, 2 * coarsest, 4 * coarsest)
    for n in divisions:
        stepper = make_stepper(integrator, M, cubic_springs(K, c), dt=T / n, x0=x0, v0=v0,
                               external=external, alpha=alpha, beta=beta, rtol=1e-12)
        err = 0.0
        for _ in range(n):
            info = stepper.step()
            err = max(err, np.linalg.norm(stepper.x - ref.sol(info.time)[:2]))
        errors.append(err)
    rates = observed_rates(errors, [T / n for n in divisions])
    print(f"{integrator}: errors {errors}, observed orders {rates}")
    assert np.all(np.abs(rates - order) < 0.1), f"errors {errors}, observed orders {rates}"


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_sparse_system_gives_the_dense_trajectory(integrator):
    rng = np.random.default_rng(3)
    n = 8
    A = rng.normal(size=(n, n))
    K = A @ A.T + n * np.eye(n)
    B = rng.normal(size=(n, n)) * 0.1
    M = B @ B.T + np.eye(n)
    c = rng.uniform(1.0, 5.0, size=n)
    load = rng.normal(size=n)
    options = dict(dt=0.02, x0=rng.normal(size=n) * 0.5, alpha=0.1, beta=0.02, rtol=1e-12,
                   external=lambda t: load * min(t, 1.0))
    dense = make_stepper(integrator, M, cubic_springs(K, c), **options)
    sparse = make_stepper(integrator, sp.csr_matrix(M), cubic_springs(sp.csr_matrix(K), c),
                          **options)
    assert sp.issparse(sparse.damping) and isinstance(dense.damping, np.ndarray)
    worst = 0.0
    for _ in range(200):
        dense.step()
        sparse.step()
        worst = max(worst, np.linalg.norm(dense.x - sparse.x) / np.linalg.norm(dense.x))
    assert worst < 1e-10, f"sparse vs dense relative difference {worst:.2e}"


def test_nan_force_raises_naming_the_step_and_keeps_last_good_state():
    mass, fk, _ = linear_modes([10.0])

    def poisoned(x):
        f, K = fk(x)
        return (f * np.nan, K) if x[0] < -0.5 else (f, K)

    dt = 0.01
    clean = NewmarkStepper(mass, fk, dt=dt, x0=[1.0])
    stepper = NewmarkStepper(mass, poisoned, dt=dt, x0=[1.0])
    with pytest.raises(SolverError, match=r"non-finite force .* at step (\d+)") as failure:
        for _ in range(100):
            stepper.step()
    bad = int(re.search(r"step (\d+)", str(failure.value)).group(1))
    assert bad == stepper.steps_taken + 1 and 1 < bad < 100, str(failure.value)
    assert f"t = {bad * dt:.6g} s" in str(failure.value)
    clean.run(bad - 1)
    assert stepper.time == pytest.approx(clean.time)
    np.testing.assert_array_equal(stepper.x, clean.x)
    np.testing.assert_array_equal(stepper.v, clean.v)


def test_energy_blow_up_of_a_circulatory_force_is_detected():
    """A follower (non-conservative) force makes the system flutter: exponential growth."""
    k, q = 4.0, 12.0
    Kc = np.array([[k, q], [-q, k]])
    stepper = NewmarkStepper(np.eye(2), lambda x: (Kc @ x, Kc), dt=0.01, x0=[0.01, 0.0],
                             potential=lambda x: 0.5 * k * x @ x, symmetric=False)
    e0 = stepper.total_energy()
    with pytest.raises(SolverError, match=r"energy blew up at step \d+ \(t = ") as failure:
        stepper.run(2000)
    last = stepper.total_energy()  # the last good state: grown, but within the budget
    assert np.isfinite(stepper.x).all() and 2 * e0 < last <= ENERGY_FACTOR * e0, (
        f"{failure.value}; last good energy {last:.3e} J, initial {e0:.3e} J"
    )
    bad = int(re.search(r"step (\d+)", str(failure.value)).group(1))
    assert stepper.steps_taken == bad - 1 and stepper.time == pytest.approx((bad - 1) * 0.01)


def test_newton_failure_and_bad_input():
    fk = cubic_springs(np.eye(1), c=np.array([1e4]))
    stepper = NewmarkStepper(np.eye(1), fk, dt=0.1, v0=[5.0], max_iterations=1, rtol=1e-12)
    with pytest.raises(SolverError, match=r"Newton did not converge at step 1 \(t = 0.1 s\)"):
        stepper.step()
    assert stepper.steps_taken == 0 and stepper.x[0] == 0.0
    with pytest.raises(LbshapeError, match="dt must be > 0"):
        NewmarkStepper(np.eye(1), fk, dt=0.0)
    with pytest.raises(LbshapeError, match="integrator must be one of"):
        make_stepper("leapfrog", np.eye(1), fk, dt=0.1)
