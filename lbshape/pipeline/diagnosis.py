"""What the stop message of a scene's run says about its loads (:mod:`lbshape.dynamics.sanity`).

:func:`load_reach` gives the engines a function, called only once a run stopped, that
measures each of the scene's loads against the object: its linear static displacement
``K₀⁻¹ f`` (K₀ the elastic tangent at rest; a fixed object: the full sparse solve on the
free degrees of freedom; a free body: in the reduced basis, which holds no rigid motion)
and the largest element strain of it. A load whose strain reaches 100 % at the failing
step is named as the likely cause (:class:`~lbshape.dynamics.sanity.LoadReach`).
:func:`run_warnings` gives a run's warnings before it starts: a step coarse against the
basis's highest mode, and a load that reaches 100 % strain at its peak (a StVK object
runs on under it, its answer meaningless; a Neo-Hookean one stops when it inverts).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from lbshape.dynamics.sanity import LoadReach, coarse_step, largest_strain, total_force
from lbshape.elastic.element_kernels import ElementKernel, FullSpaceElasticity, mass_matrix
from lbshape.pipeline.precomputed import Precomputed
from lbshape.pipeline.responses import mesh_load_patterns
from lbshape.scene.schema import Scene

log = logging.getLogger(__name__)


def basis_omega_max(pre: Precomputed) -> float | None:
    """The highest vibration frequency the basis holds (rad/s): its largest linear mode's
    (the coarse-step warning and the failure advice, :mod:`lbshape.dynamics.sanity`)."""
    omega2 = np.asarray(pre.elastic.omega2, dtype=float)
    return float(math.sqrt(omega2.max())) if omega2.size and omega2.max() > 0 else None


def run_warnings(scene: Scene, pre: Precomputed) -> list[str]:
    """The warnings of a run of ``scene`` (``stats.json`` ``warnings``): a coarse step
    (the engine logs it) and a load far beyond what the object carries at its peak
    (logged here); n-sized (one sparse solve with loads), once per run."""
    warnings = [w for w in (coarse_step(basis_omega_max(pre), scene.simulation.dt),) if w]
    reach = load_reach(scene, pre)
    reach = reach() if reach is not None else None
    beyond = reach.beyond([1.0] * len(reach.newtons)) if reach is not None else None
    if beyond is not None:
        warnings.append(f"at its peak {beyond}")
        log.warning("%s", warnings[-1])
    return warnings


def load_reach(scene: Scene, pre: Precomputed) -> Callable[[], LoadReach | None] | None:
    """``() -> LoadReach | None`` of the scene's loads, in the engines' order (``None``
    without loads); n-sized work (one sparse solve), done only when it is called."""
    if not scene.loads:
        return None

    def reach() -> LoadReach | None:
        mesh, material = pre.mesh, pre.material
        patterns = np.array([load.pattern for load in mesh_load_patterns(
            scene, mesh, mass_matrix(mesh, material.density))]).T  # (3n, L)
        stiffness = FullSpaceElasticity(mesh, material).tangent(np.zeros(3 * mesh.n_vertices))
        try:
            static = _static(stiffness, patterns, pre)
        except (RuntimeError, np.linalg.LinAlgError):  # a singular rest tangent
            return None
        kernel = ElementKernel(mesh.points, mesh.tets, material)
        strains = [largest_strain(kernel, column.reshape(-1, 3)[mesh.tets])
                   for column in static.T]
        return LoadReach(tuple(total_force(p) for p in patterns.T), tuple(strains))

    return reach


def _static(stiffness: sp.csr_matrix, patterns: np.ndarray, pre: Precomputed) -> np.ndarray:
    """(3n, L) linear static displacements of the load patterns (3n, L) in m."""
    if pre.fixed_vertices.size:
        fixed = (3 * pre.fixed_vertices[:, None] + np.arange(3)).ravel()
        free = np.setdiff1d(np.arange(stiffness.shape[0]), fixed)
        static = np.zeros_like(patterns)
        solve = spla.splu(sp.csc_matrix(stiffness[free][:, free])).solve
        static[free] = solve(np.ascontiguousarray(patterns[free]))
        return static
    U = np.asarray(pre.U)
    return U @ np.linalg.solve(U.T @ (stiffness @ U), U.T @ patterns)
