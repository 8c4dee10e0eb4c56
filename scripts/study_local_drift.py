"""Why the reduced local-example run drifts from full on teddy-local at auto's k_ex.

Usage: ``python scripts/study_local_drift.py [--beta 0.01] [--steps 500]``. Prints, as
``max_t ‖·‖_M / max_t ‖u_full‖_M`` (the benchmark's measure):

* the reduced engine against full, and the reduced engine driven by the full run's own
  pull (``Uᵀ pull_full`` in place of its own target): what the pull's feedback adds;
* a linear model (the full method's M, ``αM + βK₀``, ``K₀ + k_ex S``, Newmark, the pull of
  :class:`~lbshape.shapespace.local_full_force.FullSpaceLocalForce` at the step's start
  state) on the full DOFs against its Galerkin reductions: on U, and on U with the
  responses ``(K₀ + k_ex S)⁻¹ M_R Q_R`` of each region's anchor-fit load appended (and the
  responses to the fit's read-out ``F_Rᵀ``), M-orthonormalised;
* the reduced engine (the exact reduced force, every element) on those enlarged bases.
"""

from __future__ import annotations

import os

if __name__ == "__main__":  # single-threaded BLAS, set before numpy loads
    os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import dataclasses
import types

import numpy as np
import scipy.sparse.linalg as spla

from lbshape.elastic.element_kernels import mass_matrix
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.responses import anchor_responses
from lbshape.pipeline.simulate import full_simulation, reduced_simulation
from lbshape.scene import load_scene


def auto_scene(beta: float):
    scene = load_scene("teddy-local")
    return dataclasses.replace(
        scene, examples=dataclasses.replace(scene.examples, stiffness="auto"),
        damping=dataclasses.replace(scene.damping, beta=beta))


def engines(scene, pre, steps: int) -> tuple[float, float]:
    """(reduced vs full, reduced driven by the full run's pull vs full)."""
    U = pre.U
    mass = mass_matrix(pre.mesh, pre.material.density).tocsr()
    full, own, driven = (full_simulation(scene, pre), reduced_simulation(scene, pre),
                         reduced_simulation(scene, pre))
    held = {}
    driven.driver = types.SimpleNamespace(
        spring=driven.driver.spring,
        target=lambda x: types.SimpleNamespace(q_target=held["q"]))
    fd, k = full.free_dofs, full._k_ex
    worst = np.zeros(3)
    for _ in range(steps):
        full.step()
        held["q"] = U[fd].T @ full._b / k
        own.step()
        driven.step()
        u = full.full_displacement().reshape(-1)
        worst = np.maximum(worst, [np.sqrt(e @ (mass @ e)) for e in
                                   (U @ own.x - u, U @ driven.x - u, u)])
    return worst[0] / worst[2], worst[1] / worst[2]


def anchor_basis_responses(pre, full, K) -> tuple[np.ndarray, np.ndarray]:
    """(load, read-out) responses of ``K₀ + k_ex S`` on the free DOFs, 6 per region each
    (:func:`lbshape.pipeline.responses.anchor_responses`)."""
    load, readout = anchor_responses(K, full._local.mass, full._k_ex, pre.mesh,
                                     pre.material.density, pre.local.regions,
                                     pre.fixed_vertices, sets=2)
    return load[full.free_dofs], readout[full.free_dofs]


def linear_models(scene, pre, steps: int) -> dict[str, float]:
    """Galerkin reductions of the linear model against its full-DOF run."""
    full = full_simulation(scene, pre)
    local, fd, k, h = full._local, full.free_dofs, full._k_ex, scene.simulation.dt
    n3 = pre.U.shape[0]
    M = mass_matrix(pre.mesh, pre.material.density).tocsr()[fd][:, fd]
    K0 = full.elastic.tangent(np.zeros(n3))
    K = K0.tocsr()[fd][:, fd]
    D = scene.damping.alpha * M + scene.damping.beta * K
    A = (K + k * local.mass.tocsr()[fd][:, fd]).tocsc()
    load, readout = anchor_basis_responses(pre, full, K0)
    U = pre.U[fd]

    def appended(B):
        for _ in range(2):
            B = B - U @ (U.T @ (M @ B))
        return np.linalg.solve(np.linalg.cholesky(B.T @ (M @ B)), B.T).T

    bases = {"U": U, "U + anchor loads": np.hstack([U, appended(load)]),
             "U + anchor loads and read-outs": np.hstack([U, appended(np.hstack([load, readout]))])}

    def external(t, x):
        u = np.zeros(n3)
        u[fd] = x
        scales = np.array([profile(t) for profile in full._load_profiles])
        return scales @ full._load_patterns + k * local.pull(u)[fd]

    def newmark(Mx, Dx, Ax, force, size):
        J = 4 / h**2 * Mx + 2 / h * Dx + Ax
        if size is None:
            solve = spla.splu(J.tocsc()).solve
        else:
            inverse = np.linalg.inv(J)
            solve = inverse.__matmul__
        n = Mx.shape[0]
        x, v, a = np.zeros(n), np.zeros(n), np.zeros(n)
        for step in range(1, steps + 1):
            x1 = solve(force(step * h, x) + Mx @ (4 / h**2 * x + 4 / h * v + a)
                       + Dx @ (2 / h * x + v))
            a1 = 4 / h**2 * (x1 - x) - 4 / h * v - a
            v, a, x = v + h / 2 * (a + a1), a1, x1
            yield x

    norm = lambda e: np.sqrt(e @ (M @ e))  # noqa: E731
    runs = {name: newmark(B.T @ (M @ B), B.T @ (D @ B), B.T @ (A @ B),
                          lambda t, q, B=B: B.T @ external(t, B @ q), B.shape[1])
            for name, B in bases.items()}
    worst = dict.fromkeys([*bases, "basis miss (U)", "full"], 0.0)
    for x, *qs in zip(newmark(M, D, A, external, None), *runs.values(), strict=True):
        for (name, B), q in zip(bases.items(), qs, strict=True):
            worst[name] = max(worst[name], norm(B @ q - x))
        worst["basis miss (U)"] = max(worst["basis miss (U)"], norm(x - U @ (U.T @ (M @ x))))
        worst["full"] = max(worst["full"], norm(x))
    return {name: value / worst["full"] for name, value in worst.items() if name != "full"}


def enlarged_engines(scene, pre, steps: int) -> dict[str, float]:
    """The reduced engine (exact forces) on U with the anchor responses appended, vs full."""
    full = full_simulation(scene, pre)
    fd, n3 = full.free_dofs, pre.U.shape[0]
    mass = mass_matrix(pre.mesh, pre.material.density).tocsr()
    M = mass[fd][:, fd]
    load, readout = anchor_basis_responses(pre, full, full.elastic.tangent(np.zeros(n3)))
    U = pre.U[fd]
    engines_by_name = {}
    for name, B in (("U + anchor loads", load),
                    ("U + anchor loads and read-outs", np.hstack([load, readout]))):
        for _ in range(2):
            B = B - U @ (U.T @ (M @ B))
        B = np.linalg.solve(np.linalg.cholesky(B.T @ (M @ B)), B.T).T
        basis = np.zeros((n3, U.shape[1] + B.shape[1]))
        basis[fd] = np.hstack([U, B])
        enlarged = dataclasses.replace(
            pre, elastic=dataclasses.replace(pre.elastic, U=basis),
            local=pre.local.projected(pre.mesh, pre.material, basis))
        engines_by_name[name] = (basis, reduced_simulation(scene, enlarged, exact_forces=True))
    worst = dict.fromkeys([*engines_by_name, "full"], 0.0)
    for _ in range(steps):
        full.step()
        u = full.full_displacement().reshape(-1)
        for name, (basis, engine) in engines_by_name.items():
            engine.step()
            e = basis @ engine.x - u
            worst[name] = max(worst[name], float(np.sqrt(e @ (mass @ e))))
        worst["full"] = max(worst["full"], float(np.sqrt(u @ (mass @ u))))
    return {f"{name} (r = {engines_by_name[name][0].shape[1]})": value / worst["full"]
            for name, value in worst.items() if name != "full"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--beta", type=float, default=0.01)
    parser.add_argument("--steps", type=int, default=500)
    args = parser.parse_args()
    scene = auto_scene(args.beta)
    pre = precompute(scene)
    own, driven = engines(scene, pre, args.steps)
    print(f"teddy-local auto k_ex = {pre.auto_stiffness.k_ex:.4g}, beta = {args.beta} s, "
          f"{args.steps} steps, r = {pre.r}")
    print(f"engines: reduced vs full {own:.4f}; reduced driven by the full run's pull "
          f"{driven:.4f}")
    for name, value in linear_models(scene, pre, args.steps).items():
        print(f"linear model, own pull: {name}: {value:.4f}")
    for name, value in enlarged_engines(scene, pre, args.steps).items():
        print(f"reduced engine, exact forces, on {name}: {value:.4f}")


if __name__ == "__main__":
    main()
