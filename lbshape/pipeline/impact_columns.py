"""Impact columns: a free body's basis given the shapes of its impacts (``impact-basis``).

The reduced free body restarted from the full reference's state just before an impact
misses the impact because its basis does not hold the local crush: appending the
principal components of the impact's own full-space deformations took the Figure 4 bar's
edge hit from 24 % to 0.1 % in restitution (``docs/decisions.md``, "Impact columns").
This stage makes such columns without knowing the scene's impacts:

1. **Throws** (:func:`throw`): the body, at rest shape and without spin, thrown at a
   plane along each of its hull directions (:func:`lbshape.geometry.hull_directions.
   hull_directions`: a plane flat on each side, on each crease between two sides and on
   each corner), at :data:`THROW_SPEED_MARGIN` × :func:`throw_speed` (the fastest speed
   the body reaches a plane at), with the scene's first plane's stiffness, no
   friction and no loads, but with the scene's global examples' pull (and its ramp),
   which shapes the body as it flies in the scene; the full-space reference
   (:class:`~lbshape.dynamics.full.FullSpaceSimulator`) runs from touching until
   :data:`THROW_CLEAR_STEPS` steps after its last contact (at most
   :data:`THROW_MAX_STEPS`). Thrown as the straight body without its pull, the Figure 4
   bar's face hit with its example stayed 16 % off in restitution; with the pull it is
   within 10 % (``docs/decisions.md``, "Impact throws with the example pull").
2. **Columns** (:func:`impact_basis`): each throw's body-frame deformations during contact
   (:func:`~lbshape.analysis.free_body.body_deformations`), their rigid motions and span U
   removed M-orthogonally, give its leading principal components (``ceil(k / throws)``
   each); :func:`~lbshape.elastic.basis.append_directions` appends the k principal
   directions of them all (``reduced.impact_columns`` = k). Per feature
   (``reduced.impact_columns_per``) each throw's own k are one set, or each pair of
   neighbouring directions' 2k (``"feature-pair"``), the sets one after another.
3. **Energy** (:class:`~lbshape.elastic.column_forces.ColumnForceModel`): the columns'
   own energy exact (the StVK polynomial on them, where ``reduced.forces`` resolves to
   polynomials for k columns; else quadratic), their coupling to the other coordinates
   linear; the stage returns the coupling ``Uᵀ K₀ U`` and the columns' polynomial with
   the basis.

Cost: one short full-space run per direction (26 on a cuboid; the 332-vertex bar's 26
throws take about 10 s).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from typing import NamedTuple

import numpy as np

from lbshape.analysis.free_body import body_deformations
from lbshape.analysis.free_body_eval import penetration
from lbshape.dynamics.contact import ContactPlane
from lbshape.dynamics.full import FullSpaceSimulator, rigid_velocity
from lbshape.dynamics.full_contact import FullSpaceContact
from lbshape.dynamics.full_examples import FullSpaceExamples
from lbshape.elastic.basis import NonlinearBasis, append_directions, principal_components
from lbshape.elastic.modes import rigid_body_modes
from lbshape.elastic.polynomial_forces import PolynomialForceModel, resolve_force_model
from lbshape.errors import LbshapeError, SolverError
from lbshape.geometry.hull_directions import hull_directions, neighbouring_pairs
from lbshape.geometry.mesh import TetMesh
from lbshape.scene.schema import Scene

log = logging.getLogger(__name__)

#: a throw runs at most this many steps
THROW_MAX_STEPS = 80
#: a throw ends this many steps after its last step in contact
THROW_CLEAR_STEPS = 4
#: the slowest throw (m/s): a body that starts at rest above a plane it never falls onto
MIN_THROW_SPEED = 0.5
#: the throws run this much faster than the fastest speed the body reaches a plane at
#: (:func:`throw_speed`): a column holds a crush as deep as its throw's, and the scene's
#: impacts can be faster than that estimate (a bounce turns spin into speed, the example
#: pull drives parts of the body). At the reach speed itself the Figure 4 bar's 3 m/s edge
#: hit (the bar reaches its floor at 2.9 m/s) missed 5 % in restitution (5.03 %); of
#: 1.1-1.4 this margin leaves the most room to both targets (``docs/decisions.md``)
THROW_SPEED_MARGIN = 1.2


class ImpactBasis(NamedTuple):
    """The ``impact-basis`` stage's result (stored in the artifact by
    :func:`lbshape.pipeline.precomputed.artifact`)."""

    basis: NonlinearBasis  #: U (3n, r) with ``n_impact_columns`` columns last
    coupling: np.ndarray  #: (r, r) ``Uᵀ K₀ U`` (1/s²)
    #: the columns' own exact energy E_V (the StVK polynomial on them), or None (quadratic);
    #: per feature (``sets``): one polynomial a set
    columns: PolynomialForceModel | list[PolynomialForceModel] | None
    #: per feature: (t, 3) the throw direction of each set (rest frame), the sets of
    #: ``reduced.impact_columns`` columns each in that order; None: one set of them all
    directions: np.ndarray | None = None


def throw_speed(scene: Scene, points: np.ndarray) -> float:
    """The fastest speed (m/s) the body reaches at one of its planes: its initial speed,
    its spin at its radius and the fall under the scene's gravity to the plane,
    ``√(|v₀|² + (|ω₀| R)² + 2 max(0, −g·n) d)`` (d the gap from the body's lowest point
    along the normal n), at least :data:`MIN_THROW_SPEED`."""
    points = np.asarray(points, dtype=float)
    radius = float(np.linalg.norm(points - points.mean(axis=0), axis=1).max())
    gravity = sum((np.asarray(load.vector, dtype=float) for load in scene.loads
                   if load.type == "gravity"), np.zeros(3))
    moving = (float(np.sum(np.square(scene.initial.velocity)))
              + (float(np.linalg.norm(scene.initial.angular_velocity)) * radius) ** 2)
    speed = 0.0
    for plane in scene.planes:
        normal = np.asarray(plane.normal, dtype=float) / np.linalg.norm(plane.normal)
        gap = max(float(((points - np.asarray(plane.point)) @ normal).min()), 0.0)
        fall = max(-float(gravity @ normal), 0.0)
        speed = max(speed, math.sqrt(moving + 2.0 * fall * gap))
    return max(speed, MIN_THROW_SPEED)


def throw(scene: Scene, mesh: TetMesh, direction: np.ndarray, speed: float,
          examples: FullSpaceExamples | None = None) -> np.ndarray:
    """(k, n, 3) world displacements (m) of the steps of one throw in contact: the body
    along −``direction`` at ``speed`` (m/s) onto a plane of that normal touching it, the
    scene's first plane's stiffness, no friction, no loads, the scene's dt, integrator
    and damping; ``examples``: the example pull acting (with the scene's ramp).

    Raises:
        LbshapeError: the full-space run stopped (named with the direction).
    """
    direction = np.asarray(direction, dtype=float)
    support = float((mesh.points @ direction).min())
    plane = ContactPlane(tuple(support * direction), tuple(direction),
                         float(scene.planes[0].stiffness), 0.0)
    sim = FullSpaceSimulator(
        mesh, scene.material, dt=scene.simulation.dt,
        integrator=scene.simulation.integrator, alpha=scene.damping.alpha,
        beta=scene.damping.beta, contact=FullSpaceContact([plane], mesh.points, mesh.tets),
        initial_velocity=rigid_velocity(mesh, scene.material.density, -speed * direction,
                                        (0.0, 0.0, 0.0)),
        examples=examples,
        example_ramp=0.0 if examples is None or scene.examples is None
        else float(scene.examples.ramp))
    frames, clear = [], 0
    try:
        for _ in range(THROW_MAX_STEPS):
            sim.step()
            u = sim.displacement()
            if penetration((mesh.points + u)[None], [plane])[0] > 0.0:
                frames.append(u)
                clear = 0
            elif frames:
                clear += 1
                if clear >= THROW_CLEAR_STEPS:
                    break
    except SolverError as exc:
        raise LbshapeError(f"impact columns: the throw along {np.round(direction, 3)} "
                           f"stopped: {exc}") from None
    return np.asarray(frames).reshape(-1, mesh.n_vertices, 3)


def impact_basis(scene: Scene, mesh: TetMesh, mass, stiffness, basis: NonlinearBasis,
                 examples: FullSpaceExamples | None = None) -> ImpactBasis:
    """The ``impact-basis`` stage: ``basis`` with ``scene.reduced.impact_columns`` impact
    columns appended (module docstring), the coupling ``Uᵀ K₀ U`` and the columns' own
    polynomial energy (None where it is not built).

    Args:
        scene: a free body with contact planes and ``reduced.impact_columns`` > 0.
        mesh: its rest mesh.
        mass, stiffness: (3n, 3n) M (kg) and the rest stiffness K₀ (N/m).
        basis: the basis so far (M-orthonormal).
        examples: the scene's global examples' pull for the throws (:func:`throw`), or None.
    """
    count = int(scene.reduced.impact_columns)
    per_feature = scene.reduced.sets_per_feature
    directions = hull_directions(mesh.points).all
    speed = THROW_SPEED_MARGIN * throw_speed(scene, mesh.points)
    rigid = rigid_body_modes(mesh.points, mass)
    U = basis.U

    def outside(X):
        for _ in range(2):
            X = X - rigid @ (rigid.T @ (mass @ X))
            X = X - U @ (U.T @ (mass @ X))
        return X

    scalar_mass = mass[0::3, 0::3]
    each = count if per_feature else math.ceil(count / len(directions))
    columns = []
    for index, direction in enumerate(directions):
        u = throw(scene, mesh, direction, speed, examples)
        if len(u):  # the leading principal components of its deformations outside U
            deformations = body_deformations(scalar_mass, mesh.points, u)
            components, _ = principal_components(
                outside(deformations.reshape(len(u), -1).T), mass)
            columns.append(components[:, :each])
        log.info("impact columns: throw %d of %d at %.3g m/s, %d steps in contact",
                 index + 1, len(directions), speed, len(u))
    if not columns:
        raise LbshapeError("impact columns: no throw reached its plane")
    if per_feature:
        return _feature_sets(scene, mesh, mass, stiffness, basis, directions, columns)
    grown = append_directions(basis, np.hstack(columns), mass, stiffness,
                              kind="impact_columns", max_columns=count, rtol=0.0,
                              min_outside=0.0)
    if grown.n_impact_columns < count:
        raise LbshapeError(f"reduced.impact_columns = {count}: the {len(directions)} throws "
                           f"give {grown.n_impact_columns} independent columns; set "
                           f"impact_columns <= {grown.n_impact_columns}")
    U = grown.U
    V = np.ascontiguousarray(U[:, leading_columns(grown):])
    exact = resolve_force_model(scene.reduced.forces, scene.material.model, mesh.n_tets,
                                V.shape[1]) == "polynomial"
    return ImpactBasis(grown, U.T @ (stiffness @ U), PolynomialForceModel(
        mesh.points, mesh.tets, scene.material, V) if exact else None)


def _feature_sets(scene: Scene, mesh: TetMesh, mass, stiffness, basis: NonlinearBasis,
                  directions: np.ndarray, columns: list[np.ndarray]) -> ImpactBasis:
    """Per feature: each throw's own ``reduced.impact_columns`` leading components as one
    set, M-orthonormal and M-orthogonal to U₀ (``basis``); per pair of features
    (``"feature-pair"``) the two sets of each pair of neighbouring directions
    (:func:`~lbshape.geometry.hull_directions.neighbouring_pairs`) made one, M-orthonormal.
    The sets follow one another after U₀ (not orthogonal to each other: only one acts at
    a time, :mod:`lbshape.dynamics.impact_switch`), each with its own polynomial energy
    and its direction, its features' directions summed."""
    count = int(scene.reduced.impact_columns)
    r0 = basis.r
    fewest = min(c.shape[1] for c in columns)
    if len(columns) < len(directions) or fewest < count:
        raise LbshapeError(f"reduced.impact_columns = {count} per feature: {len(columns)} of "
                           f"the {len(directions)} throws reached their plane, the fewest "
                           f"independent columns a throw gave is {fewest}; set "
                           f"impact_columns <= {fewest}")
    groups = (neighbouring_pairs(directions) if scene.reduced.impact_columns_per
              == "feature-pair" else np.arange(len(directions))[:, None])
    own = _orthonormal_sets(basis, columns, mass, stiffness, count)
    sets = own if groups.shape[1] == 1 else _orthonormal_sets(
        basis, [np.hstack([own[i] for i in group]) for group in groups], mass, stiffness,
        groups.shape[1] * count)
    U = np.hstack([basis.U, *sets])
    grown = dataclasses.replace(basis, U=U, r=int(U.shape[1]),
                                omega2=np.einsum("ij,ij->j", U, stiffness @ U),
                                n_impact_columns=int(U.shape[1]) - r0)
    exact = resolve_force_model(scene.reduced.forces, scene.material.model, mesh.n_tets,
                                sets[0].shape[1]) == "polynomial"
    return ImpactBasis(grown, U.T @ (stiffness @ U), [
        PolynomialForceModel(mesh.points, mesh.tets, scene.material, np.ascontiguousarray(v))
        for v in sets] if exact else None, np.asarray(directions, dtype=float)[groups].sum(1))


def _orthonormal_sets(basis: NonlinearBasis, blocks: list[np.ndarray], mass, stiffness,
                      size: int) -> list[np.ndarray]:
    """Each block's ``size`` leading directions outside the basis, M-orthonormal
    ((3n, size) each); a one-line error where a block holds fewer."""
    sets = [append_directions(basis, block, mass, stiffness, kind="impact_columns",
                              max_columns=size, rtol=0.0, min_outside=0.0).U[:, basis.r:]
            for block in blocks]
    if min(v.shape[1] for v in sets) < size:
        raise LbshapeError(f"reduced.impact_columns: a set of {size} columns per feature "
                           "is not independent of the basis; set impact_columns lower")
    return sets


def leading_columns(basis: NonlinearBasis) -> int:
    """The columns before the impact columns (those of the nonlinear force model)."""
    return int(basis.r - basis.n_impact_columns)
