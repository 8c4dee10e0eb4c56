"""Nonlinear static equilibria of a held object under a load, by Newton's method with
load stepping.

The shapes an object settles into under its scene's loads at full strength,
``f_int(u) = λ f`` for a few load levels λ ∈ (0, 1]. Appended to the reduced basis
(:func:`lbshape.elastic.basis.append_directions`, the precompute's
``static-equilibria`` stage) they make the reduced model exact at those equilibria:
when ``u* ∈ span U`` and ``f_int(u*) = f``, ``q* = UᵀM u*`` is an equilibrium of the
reduced forces ``Uᵀ f_int(U q)``, so a reduced run that settles under the load settles
at the full model's shape. The linear static responses ``K⁻¹ f`` of the basis hold
the small-load shape only; under large loads (the cross's arms bent by 25 cm) the
equilibrium leaves their span by a few percent, which the dynamics amplify.

Each level is reached from the last in load increments; an increment whose Newton
iteration does not converge (``|f_int(u) − λ f| ≤ rtol |f|`` on the free dofs within
:data:`MAX_NEWTON_ITERATIONS`) is halved, down to :data:`MIN_LOAD_INCREMENT`, below
which the levels reached so far are returned (an equilibrium may not exist: a
St. Venant–Kirchhoff body can collapse under compression).

The equilibria are of the elastic forces and the loads alone: a scene's contact planes
and example pull are left out (the example pull has its own responses,
:func:`lbshape.pipeline.responses.example_responses`); they are directions for the basis,
not a solution the simulation uses.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from lbshape.elastic.element_kernels import FullSpaceElasticity
from lbshape.elastic.materials import Material
from lbshape.errors import LbshapeError, SolverError
from lbshape.fem.cholesky import serial_cholesky
from lbshape.geometry.mesh import TetMesh, free_dof_mask

log = logging.getLogger(__name__)

#: the load levels λ whose equilibria are returned, as fractions of the full load
STATIC_LOAD_LEVELS = (0.5, 1.0)
#: Newton iterations per load increment before the increment is halved
MAX_NEWTON_ITERATIONS = 25
#: relative residual ``|f_int(u) − λ f| / |f|`` (free dofs) of a converged equilibrium
NEWTON_RTOL = 1e-9
#: the smallest load increment tried before giving up on the next level
MIN_LOAD_INCREMENT = 1.0 / 64


def static_equilibria(mesh: TetMesh, material: Material, fixed_vertices: np.ndarray,
                      load: np.ndarray, *, levels: Sequence[float] = STATIC_LOAD_LEVELS,
                      rtol: float = NEWTON_RTOL) -> np.ndarray:
    """(3n, c) displacements in m of the equilibria ``f_int(u) = λ f`` at the levels
    λ reached (c ≤ len(levels); fewer when Newton failed at some level, logged).

    Args:
        mesh: the object's rest mesh (n vertices).
        material: its hyperelastic material.
        fixed_vertices: (f,) vertices held at zero displacement, f ≥ 1.
        load: (3n,) node-major external force f in N.
        levels: increasing load levels in (0, 1].
        rtol: converged when the free dofs' residual is below ``rtol |f|``.

    Raises:
        LbshapeError: no fixed vertex (a free body has no static equilibrium under a
            load), a load of the wrong shape or not finite, or levels outside (0, 1] or
            not increasing.
    """
    n3 = 3 * mesh.n_vertices
    load = np.asarray(load, dtype=float).reshape(-1)
    levels = [float(level) for level in levels]
    if np.size(fixed_vertices) == 0:
        raise LbshapeError("a static equilibrium needs fixed vertices")
    if load.shape != (n3,) or not np.isfinite(load).all():
        raise LbshapeError(f"the load must be {n3} finite forces, got shape {load.shape}")
    if not levels or any(not 0 < b <= 1 for b in levels) or sorted(set(levels)) != levels:
        raise LbshapeError(f"load levels must increase within (0, 1], got {levels}")
    free = free_dof_mask(n3 // 3, fixed_vertices)
    elasticity = FullSpaceElasticity(mesh, material)
    scale = float(np.linalg.norm(load[free]))
    u, reached, found = np.zeros(n3), 0.0, []
    if scale == 0.0:
        return np.zeros((n3, 0))
    for level in levels:
        increment = level - reached
        while reached < level:
            trial = min(level, reached + increment)
            solved = _newton(elasticity, free, trial * load, u, rtol * scale)
            if solved is not None:
                u, reached = solved, trial
                continue
            increment /= 2
            if increment < MIN_LOAD_INCREMENT:
                log.warning("static equilibria: no equilibrium found beyond %.3g of the "
                            "load (Newton failed with increments down to %.3g); %d of %d "
                            "levels kept", reached, MIN_LOAD_INCREMENT, len(found),
                            len(levels))
                return np.column_stack(found) if found else np.zeros((n3, 0))
        found.append(u.copy())
    return np.column_stack(found)


def _newton(elasticity: FullSpaceElasticity, free: np.ndarray, force: np.ndarray,
            start: np.ndarray, atol: float) -> np.ndarray | None:
    """u (3n,) with ``|f_int(u) − force|`` ≤ atol on the free dofs, from ``start``;
    None when Newton does not get there in :data:`MAX_NEWTON_ITERATIONS`."""
    u = start.copy()
    for _ in range(MAX_NEWTON_ITERATIONS):
        internal, tangent = elasticity.force_and_tangent(u)
        residual = (force - internal)[free]
        norm = float(np.linalg.norm(residual))
        if not np.isfinite(norm):
            return None
        if norm <= atol:
            return u
        step = _newton_step(tangent[free][:, free], residual)
        if step is None:
            return None
        u[free] += step
    return None


def _newton_step(tangent: sp.spmatrix, residual: np.ndarray) -> np.ndarray | None:
    """``tangent⁻¹ residual`` (free dofs): by sparse Cholesky (the tangent of a stable
    equilibrium is positive definite; 2.2 s for the 55k free dofs of an 18.6k-vertex
    bar, against 23 s by LU), by LU where it is not; None when it is singular."""
    try:
        with serial_cholesky(tangent, prefix="static_", what="the tangent stiffness") \
                as solve:
            return solve(residual)[:, 0]
    except SolverError:  # indefinite (a buckling StVK body): LU
        pass
    try:
        return spla.splu(sp.csc_matrix(tangent)).solve(residual)
    except RuntimeError:  # a singular tangent
        return None
