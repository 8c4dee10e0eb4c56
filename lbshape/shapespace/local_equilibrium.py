"""How far local examples take their regions: the linear static equilibrium of the pull.

A local example pulls its region R towards a target that follows the rigid fit of the
region's anchor ring (:mod:`lbshape.shapespace.local_space`). With the weights held, the
pull of :class:`~lbshape.shapespace.local_full_force.FullSpaceLocalForce` is affine in
the displacement u (3n,) m, ``pull(u) = pull(0) + G u`` (``G``: its
:meth:`~lbshape.shapespace.local_full_force.FullSpaceLocalForce.anchor_coupling`), so
the object's linear static equilibrium under the loads f (3n,) N and the example force
``k_ex (pull(u) − S u)`` solves

    (K + k_ex (S − G)) u = k_ex pull_w(0) + f,

K (3n, 3n) N/m the stiffness at rest, S = Σ_R M^(R) kg the spring. The weights w (eq. 5)
depend on u, so :func:`static_equilibrium` iterates: weights from the last u, solve, until
u stops moving.

:func:`region_closeness` reads each region of that equilibrium as the closest-example
measure does (:func:`lbshape.shapespace.local_space.region_descriptor`, distances of the
descriptor over the largest example's): the distance to its nearest example over the
distance to rest, below 1 when the region is nearer an example than the rest shape. The
dynamic runs end close to this equilibrium (teddy-local at k_ex = 958 / 2000 1/s²: right
leg 0.153 / 0.229 and 0.194 / 0.189 (rest / nearest example) statically against
0.165 / 0.222 and 0.206 / 0.179 at 0.5 s of the full-space run; ``docs/decisions.md``,
"Local examples: k_ex raised to the regions' static equilibrium").
"""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from lbshape.geometry.mesh import TetMesh
from lbshape.shapespace.local_full_force import FullSpaceLocalForce
from lbshape.shapespace.local_space import RegionSpace, region_descriptor

__all__ = ["CLOSEST_RATIO", "MAX_RAISE", "equilibrium_stiffness", "region_closeness",
           "static_equilibrium"]

#: a region counts as reached when its static equilibrium's distance to its nearest
#: example is at most this share of its distance to rest (calibrated once on teddy-local:
#: at the resulting k_ex its reduced run ends the right leg at 0.94, the full run at 0.78)
CLOSEST_RATIO = 0.85
#: k_ex grows by this factor per trial, then is bisected between the last two
GROWTH = 2.0 ** 0.25
#: ... up to this many times the rule's value (8 trials), then the largest is taken: the
#: reduced run follows a stronger pull less well (teddy-local needs 2.6×; a soft bar whose
#: far half carries a 40 N tip load asked 64×, where the reduced run went 25-31 % off)
MAX_RAISE = 4.0
MAX_TRIALS = round(np.log(MAX_RAISE) / np.log(GROWTH))
#: bisection steps between the last failing and the first passing trial (≈ 0.3 %)
BISECTIONS = 6
#: fixed-point passes of the weights (they settle in 2-4 on the built-in scenes)
MAX_PASSES = 30
#: the passes stop when u moves less than this share of its Euclidean norm
PASS_TOLERANCE = 1e-6

log = logging.getLogger(__name__)


def static_equilibrium(force: FullSpaceLocalForce, stiffness, free: np.ndarray,
                       k_ex: float, load: np.ndarray | None = None) -> np.ndarray:
    """(3n,) m: the linear static equilibrium of the loads and the local example pull
    (module docstring).

    Args:
        force: the full-space local example force of the object.
        stiffness: (3n, 3n) K at rest, N/m, without supports.
        free: (3n,) bool, the DOFs not clamped.
        k_ex: the example stiffness, 1/s², > 0.
        load: (3n,) N, the loads at full strength (None: no loads).
    """
    coupling = force.anchor_coupling()
    operator = (sp.csr_matrix(stiffness) + k_ex * (force.mass - coupling)).tocsr()
    solve = spla.splu(operator[free][:, free].tocsc()).solve
    n3 = operator.shape[0]
    load = np.zeros(n3) if load is None else np.asarray(load, dtype=float)
    u = np.zeros(n3)
    for _ in range(MAX_PASSES):
        rhs = k_ex * (force.pull(u) - coupling @ u) + load
        moved = np.zeros(n3)
        moved[free] = solve(rhs[free])
        change = float(np.linalg.norm(moved - u))
        u = moved
        if change <= PASS_TOLERANCE * max(float(np.linalg.norm(u)), 1e-300):
            return u
    log.warning("local examples' static equilibrium at k_ex = %.4g 1/s²: the weights did "
                "not settle in %d passes; the last is used", k_ex, MAX_PASSES)
    return u


def equilibrium_stiffness(force: FullSpaceLocalForce, stiffness, free: np.ndarray,
                          start: float, load: np.ndarray | None, mesh: TetMesh,
                          density: float) -> tuple[float, dict[str, float]]:
    """The smallest k_ex ≥ ``start`` (1/s²) whose :func:`static_equilibrium` has every
    region within :data:`CLOSEST_RATIO` of an example (:func:`region_closeness`), and
    those ratios: k_ex grows geometrically from ``start`` until every region passes, then
    is bisected (in log k) between the last two trials; at :data:`MAX_RAISE` times
    ``start`` it stops and returns that with its ratios (some above the ratio). Arguments
    as :func:`static_equilibrium` and :func:`region_closeness`."""
    def ratios(k):
        u = static_equilibrium(force, stiffness, free, k, load)
        return region_closeness(mesh, force.regions, u, density)

    low, high, seen, trials = None, float(start), ratios(start), 0
    while max(seen.values()) > CLOSEST_RATIO:
        if trials == MAX_TRIALS:
            return high, seen
        low, high, trials = high, high * GROWTH, trials + 1
        seen = ratios(high)
    if low is None:
        return high, seen
    for _ in range(BISECTIONS):
        middle = float(np.sqrt(low * high))
        trial = ratios(middle)
        if max(trial.values()) <= CLOSEST_RATIO:
            high, seen = middle, trial
        else:
            low = middle
    return high, seen


def region_closeness(mesh: TetMesh, regions, u: np.ndarray, density: float
                     ) -> dict[str, float]:
    """Per region: the distance of its descriptor to the nearest of its examples over
    the distance to rest (below 1: nearer an example), for the displacement u (3n,) or
    (n, 3) m; ``density`` ρ kg/m³ (the example descriptors')."""
    return {region.name: _closeness(mesh, region, u, density) for region in regions}


def _closeness(mesh: TetMesh, region: RegionSpace, u: np.ndarray, density: float) -> float:
    d = region_descriptor(mesh, region, np.asarray(u, dtype=float).reshape(-1, 3))
    examples = region.example_descriptors(density)
    nearest = float(np.linalg.norm(examples - d, axis=1).min())
    rest = float(np.linalg.norm(d))
    return nearest / rest if rest > 0.0 else float("inf")
