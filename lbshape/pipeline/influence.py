"""How much a scene's examples change its motion: the example influence and the eq. 5 residual.

Whenever a scene has examples (and ``k_ex > 0``), the same scene run **without**
examples (``k_ex = 0``, same method, same steps, same precompute; run by
:func:`lbshape.pipeline.simulate.example_influence`) is the reference for their
effect. With M the consistent elastic mass (kg) and
``u_ex(t)``, ``u_none(t)`` (n, 3) the sampled displacements (m):

* ``example_influence = ‖u_ex(T) − u_none(T)‖_M / ‖u_none(T)‖_M`` at the last
  sample T;
* ``example_influence_max = max_t ‖u_ex(t) − u_none(t)‖_M / max_t ‖u_none(t)‖_M``
  (normalised like the trajectory error of the benchmarks, so that the first
  steps, where ``u_none`` is still tiny, do not dominate);
* ``example_residual`` / ``example_residual_none``: the eq. 5 residual of the
  final shape with and without examples — the distance of its LB descriptor
  ``d = λ ⊙ (Φᵀ M₁ u)`` (3m,) to the convex hull of the example descriptors,
  ``min_{w ∈ simplex} ‖Σ_k w_k e_k − d‖``, divided by ``max_k ‖e_k‖`` (how far
  the examples themselves are from the rest shape), so 0 means "on the example
  manifold" and 1 "as far from it as the examples are from rest". With local
  examples: the largest of the regions' residuals, each on its own descriptors.
  A free body's final shape is its deformation (see **Frame**).

**Frame.** For a fixed object u is the world displacement (``influence_frame:
"world"``). A free body's world displacement is dominated by its rigid motion
(where it flies, how it spins), which the examples barely change while they plainly
change its shape, so there u is the **deformation** (``influence_frame: "body"``):
the displacement left after the mass-weighted best rigid fit of the deformed
positions onto the rest positions (Kabsch,
:func:`lbshape.analysis.free_body.body_deformations`), ``u_body = Rᵀ(x − c) − X̄``.
It needs nothing but positions, so it is the same measure for the reduced engine
and the full-space reference, and a rigid motion of either run does not change it.
The world-displacement figures are kept next to it (``example_influence_world``,
``example_influence_world_max``; equal to the main ones for a fixed object).

A measure is ``None`` when it is undefined: the reference never moves (division
by zero; for a free body: never deforms) while the example run does. Two
trajectories that agree to round-off (:data:`ROUNDOFF` of the object's size) have
influence 0, also when neither moves.

Examples equal to the rest shape are not "no examples": the example force
``k_ex (q* − q)`` with ``q* = 0`` is a spring towards rest, so under loads their
influence is ``k_ex / (ω² + k_ex)`` for a mode of angular frequency ω (a stiffer
object); without loads they leave the object at rest (influence 0).

**What a person sees.** The influence is relative to the no-example motion and can
be large while nothing visible changes (a run that barely moves). Two measures read
like the picture:

* ``visible_change = max_i ‖u_ex,i(T) − u_none,i(T)‖ / D``: the largest vertex
  distance between the final shapes with and without examples over the rest
  bounding-box diagonal D (a free body: deformations, best rigid fit removed);
* ``closest_example``: which shape the final shape ends closest to in shape space,
  the rest shape (``"rest"``) or an example (its index in the scene's ``[examples]``):
  the smallest ``‖d − e_k‖`` over the example descriptors e_k and ``‖d‖`` for rest
  (``example_distances`` lists them, relative to ``max_k ‖e_k‖``). With local
  examples, per region (``{region: …}``), on the region's descriptors
  (:func:`lbshape.shapespace.local_space.region_descriptor`), among the rest and
  the region's own examples.

The measures on arrays (mass norms, the influence ratios, visible change, nearest shape,
the body-frame deformation) are :mod:`lbshape.analysis`; this module applies them to a
scene's runs and precompute.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lbshape.analysis.free_body import body_deformations
from lbshape.analysis.influence import nearest_shape, trajectory_influence, visible_change
from lbshape.analysis.norms import ROUNDOFF
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.pipeline.precomputed import Precomputed
from lbshape.scene.schema import Scene
from lbshape.shapespace.interpolation import simplex_weights
from lbshape.shapespace.local_space import region_descriptor, region_example_distance

#: the stats keys this module adds to a run's ``stats.json``
STATS_KEYS: tuple[str, ...] = (
    "example_influence", "example_influence_max", "example_residual", "example_residual_none",
    "influence_frame", "example_influence_world", "example_influence_world_max",
    "visible_change", "closest_example", "example_distances",
)
#: what ``example_influence`` measures: world displacement (fixed) or deformation (free)
FRAMES: tuple[str, ...] = ("world", "body")


@dataclass(frozen=True)
class Influence:
    """The effect of a scene's examples on one method's run.

    Attributes:
        final: ``‖u_ex(T) − u_none(T)‖_M / ‖u_none(T)‖_M`` (None if undefined).
        maximum: ``max_t ‖u_ex − u_none‖_M / max_t ‖u_none‖_M`` (None if undefined).
        residual: eq. 5 residual of the final shape with examples (relative, see
            the module docstring; None without examples).
        residual_none: the same for the run without examples.
        frame: ``"world"`` (final and maximum measure world displacements) or
            ``"body"`` (they measure the deformation, best rigid fit removed).
        world_final: ``final`` of the world displacements (None if undefined; the
            same as ``final`` when ``frame == "world"``).
        world_maximum: ``maximum`` of the world displacements.
        visible_change: largest vertex distance between the final shapes (m) over the
            rest bounding-box diagonal (free bodies: deformations).
        closest_example: ``"rest"`` or the index of the example the final shape with
            examples is closest to in shape space; local examples: ``{region: …}``.
        example_distances: the descriptor distances behind ``closest_example``
            (``{"rest": …, "0": …}``, relative to the largest example; local examples:
            per region).
    """

    final: float | None
    maximum: float | None
    residual: float | None = None
    residual_none: float | None = None
    frame: str = "world"
    world_final: float | None = None
    world_maximum: float | None = None
    visible_change: float | None = None
    closest_example: object = None
    example_distances: dict | None = None

    def __post_init__(self):
        if self.frame not in FRAMES:
            raise LbshapeError(f"influence frame must be one of {FRAMES}, got {self.frame!r}")

    def stats(self) -> dict:
        """The :data:`STATS_KEYS` entries of ``stats.json``."""
        return dict(zip(STATS_KEYS, (self.final, self.maximum, self.residual,
                                     self.residual_none, self.frame, self.world_final,
                                     self.world_maximum, self.visible_change,
                                     self.closest_example, self.example_distances),
                        strict=True))


def is_free_body(pre: Precomputed) -> bool:
    """True for a free body (it has a rigid frame): its influence is measured in the body frame."""
    return pre.frame is not None


def descriptor(pre: Precomputed, u: np.ndarray) -> np.ndarray:
    """(3m,) LB descriptor ``λ ⊙ (Φᵀ M₁ u)`` of a displacement u (n, 3) in m (row-major, 3i + c)."""
    volume_mass = mass_matrix(pre.mesh, 1.0)[0::3, 0::3]  # M₁ (n, n), m³
    coefficients = np.asarray(pre.shape.eigenvectors.T
                              @ (volume_mass @ np.asarray(u).reshape(-1, 3)))
    return coefficients.reshape(-1) * np.repeat(pre.shape.eigenvalues, 3)


def manifold_residual(pre: Precomputed, u: np.ndarray) -> float:
    """Relative eq. 5 residual of displacement u (n, 3): distance of its descriptor to the
    convex hull of the example descriptors over ``max_k ‖e_k‖`` (see the module docstring)."""
    if not pre.has_examples:
        raise LbshapeError(f"scene {pre.scene!r} has no examples: no example manifold")
    examples = pre.examples.example_descriptors
    d = descriptor(pre, u)
    w = simplex_weights(examples, d)
    scale = float(np.linalg.norm(examples, axis=1).max())
    distance = float(np.linalg.norm(w @ examples - d))
    return distance / scale if scale > 0.0 else distance


def local_residual(pre: Precomputed, u: np.ndarray) -> float:
    """Local examples: the largest region's relative eq. 5 residual of u (n, 3), each on
    the region's own descriptors
    (:func:`lbshape.shapespace.local_space.region_example_distance`)."""
    return max(region_example_distance(pre.mesh, region, u, density=pre.material.density)[0]
               for region in pre.local.regions)


def closest_example(pre: Precomputed, u: np.ndarray, example_descriptors=None
                    ) -> tuple[object, dict]:
    """:func:`nearest_shape` of the shape u (n, 3) (a free body's deformation) among the
    rest and the scene's examples; local examples: per region (``{region: …}``).

    ``example_descriptors`` (k, 3m) replaces ``pre``'s, e.g. those of the whole
    scene's examples for a run with one of them (same object, same LB basis).
    """
    if pre.has_local_examples and example_descriptors is None:
        closest, distances = {}, {}
        for region in pre.local.regions:
            d = region_descriptor(pre.mesh, region, u)
            E = region.example_descriptors(pre.material.density)
            closest[region.name], distances[region.name] = nearest_shape(d, E, region.examples)
        return closest, distances
    examples = (pre.examples.example_descriptors if example_descriptors is None
                else example_descriptors)
    if examples is None:
        raise LbshapeError(f"scene {pre.scene!r} has no examples to be closest to")
    return nearest_shape(descriptor(pre, u), examples)


def has_example_force(scene: Scene, pre: Precomputed) -> bool:
    """True when the scene's examples act on its motion (examples and ``k_ex > 0``)."""
    active = pre.has_examples or pre.has_local_examples
    return bool(active and scene.examples is not None and scene.examples.acts)


def compare_runs(pre: Precomputed, with_ex, without, mass=None) -> Influence:
    """The :class:`Influence` of two finished runs (``SimulationOutput``) of one scene.

    A free body's (``pre.frame`` set) is measured on the deformation, a fixed
    object's on the world displacement (see the module docstring); both report the
    world figures too.
    """
    if with_ex.displacements.shape != without.displacements.shape or not np.allclose(
            with_ex.times, without.times):
        raise LbshapeError("the runs with and without examples are sampled differently "
                           "(a run stopped early?)")
    mass = mass_matrix(pre.mesh, pre.material.density) if mass is None else mass
    points = pre.mesh.points
    size = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    atol = ROUNDOFF * size * math.sqrt(float(mass.sum()) / 3.0)
    world = trajectory_influence(with_ex.displacements, without.displacements, mass, atol=atol)
    frame, (final, maximum) = "world", world
    shape_ex, shape_none = with_ex.displacements, without.displacements
    if is_free_body(pre):
        scalar_mass = mass[0::3, 0::3]
        frame = "body"
        shape_ex = body_deformations(scalar_mass, points, shape_ex)
        shape_none = body_deformations(scalar_mass, points, shape_none)
        final, maximum = trajectory_influence(shape_ex, shape_none, mass, atol=atol)
    residual = residual_none = closest = distances = None
    change = visible_change(points, shape_ex[-1], shape_none[-1])
    if pre.has_examples or pre.has_local_examples:
        closest, distances = closest_example(pre, shape_ex[-1])
    if pre.has_examples:  # residuals of the final shape (a free body's deformation)
        residual = manifold_residual(pre, shape_ex[-1])
        residual_none = manifold_residual(pre, shape_none[-1])
    elif pre.has_local_examples:
        residual = local_residual(pre, shape_ex[-1])
        residual_none = local_residual(pre, shape_none[-1])
    return Influence(final, maximum, residual, residual_none, frame, *world,
                     visible_change=change, closest_example=closest,
                     example_distances=distances)


