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
:func:`lbshape.dynamics.rigid_frame.best_rigid_frame`), ``u_body = Rᵀ(x − c) − X̄``.
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
  (:func:`lbshape.shapespace.local_examples.region_descriptor`), among the rest and
  the region's own examples.

The twist of a bar's end (:func:`end_twist_degrees`) is the number a reader of
the paper's Figure 3 looks for; it is reported next to the influence by the
pictures and the demo.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lbshape.dynamics.rigid_frame import best_rigid_frame
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.pipeline.precomputed import Precomputed
from lbshape.scene.schema import Scene
from lbshape.shapespace.interpolation import simplex_weights
from lbshape.shapespace.local_space import region_descriptor, region_example_distance

#: M-norm differences below ROUNDOFF × sqrt(mass) × bounding-box diagonal count as none
ROUNDOFF = 1e-12
#: the stats keys this module adds to a run's ``stats.json``
STATS_KEYS: tuple[str, ...] = (
    "example_influence", "example_influence_max", "example_residual", "example_residual_none",
    "influence_frame", "example_influence_world", "example_influence_world_max",
    "visible_change", "closest_example", "example_distances",
)
#: the label of the rest shape among the candidates of ``closest_example``
REST = "rest"
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


def mass_norms(u: np.ndarray, mass) -> np.ndarray:
    """(k,) ``sqrt(u(t)ᵀ M u(t))`` of displacements u (k, n, 3) or (k, 3n) (m), M (3n, 3n) kg."""
    flat = np.asarray(u, dtype=float).reshape(len(u), -1)
    if flat.shape[1] != mass.shape[0]:
        raise LbshapeError(f"displacements have {flat.shape[1]} components per sample, the "
                           f"mass matrix {mass.shape[0]} rows")
    squares = np.einsum("ti,ti->t", flat, np.asarray((mass @ flat.T).T))
    return np.sqrt(np.maximum(squares, 0.0))


def _ratio(numerator: float, denominator: float, atol: float) -> float | None:
    if numerator <= atol:
        return 0.0
    return numerator / denominator if denominator > atol else None


def trajectory_influence(u_ex: np.ndarray, u_none: np.ndarray, mass, *, atol: float = 0.0
                         ) -> tuple[float | None, float | None]:
    """``(final, maximum)`` influence of two trajectories sampled at the same times.

    Args:
        u_ex: (k, n, 3) displacements with examples (m).
        u_none: (k, n, 3) displacements without examples (m).
        mass: (3n, 3n) consistent mass (kg).
        atol: M-norms (m·kg^½) up to ``atol`` count as none: a difference that small
            is influence 0, a reference that small (and a larger difference) None.
    """
    u_ex, u_none = np.asarray(u_ex, dtype=float), np.asarray(u_none, dtype=float)
    if u_ex.shape != u_none.shape or u_ex.shape[0] == 0:
        raise LbshapeError(f"trajectories must have the same non-empty shape, got {u_ex.shape} "
                           f"and {u_none.shape}")
    difference = mass_norms(u_ex - u_none, mass)
    reference = mass_norms(u_none, mass)
    return (_ratio(float(difference[-1]), float(reference[-1]), atol),
            _ratio(float(difference.max()), float(reference.max()), atol))


def body_deformations(scalar_mass, rest: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(k, n, 3) deformations of displacements u (k, n, 3) (m): each sample's displacement
    after its mass-weighted best rigid fit (``Rᵀ(X + u − c) − X̄``, body frame, m).

    Args:
        scalar_mass: (n, n) scalar mass M₁ (kg).
        rest: (n, 3) rest positions X (m).
        u: (k, n, 3) world displacements (m).
    """
    rest = np.asarray(rest, dtype=float)
    u = np.asarray(u, dtype=float).reshape(len(u), -1, 3)
    if u.shape[1:] != rest.shape:
        raise LbshapeError(f"displacements of shape {u.shape[1:]} for {rest.shape} rest points")
    return np.stack([best_rigid_frame(scalar_mass, rest, rest + sample)[2] for sample in u])


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
    (:func:`lbshape.shapespace.local_examples.region_example_distance`)."""
    return max(region_example_distance(pre.mesh, region, u, density=pre.material.density)[0]
               for region in pre.local.regions)


def visible_change(points: np.ndarray, shape_ex: np.ndarray, shape_none: np.ndarray) -> float:
    """Largest vertex distance between two shapes over the rest bounding-box diagonal.

    Args:
        points: (n, 3) rest positions X (m).
        shape_ex, shape_none: (n, 3) displacements (m) of the same vertices (a free
            body's deformations, :func:`body_deformations`).
    """
    points = np.asarray(points, dtype=float)
    diagonal = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    distance = np.linalg.norm(np.asarray(shape_ex) - np.asarray(shape_none), axis=1)
    return float(distance.max()) / diagonal


def nearest_shape(d: np.ndarray, examples: np.ndarray,
                  labels: Sequence[int] | None = None) -> tuple[object, dict]:
    """Which of the rest shape (descriptor 0) and the examples a descriptor is closest to.

    Args:
        d: (3m,) a shape's descriptor.
        examples: (k, 3m) the example descriptors e_k.
        labels: (k,) the examples' indices in the scene (default 0…k−1).

    Returns:
        ``(closest, distances)``: ``"rest"`` or the closest example's label, and
        ``{"rest": ‖d‖/s, "<label>": ‖d − e_k‖/s}`` with s = ``max_k ‖e_k‖``.
    """
    examples = np.atleast_2d(np.asarray(examples, dtype=float))
    labels = list(range(len(examples))) if labels is None else [int(k) for k in labels]
    scale = float(np.linalg.norm(examples, axis=1).max()) or 1.0
    distances = {REST: float(np.linalg.norm(d)) / scale}
    for label, e in zip(labels, examples, strict=True):
        distances[str(label)] = float(np.linalg.norm(d - e)) / scale
    closest = min(distances, key=distances.get)
    return (closest if closest == REST else int(closest)), distances


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


def without_examples(scene: Scene) -> Scene:
    """The same scene with the example force switched off (``k_ex = 0``, same precompute)."""
    if scene.examples is None:
        return scene
    return dataclasses.replace(scene, examples=dataclasses.replace(scene.examples, stiffness=0.0))


def with_stiffness(scene: Scene, stiffness: float) -> Scene:
    """The same scene with example stiffness ``k_ex`` = ``stiffness`` (1/s²)."""
    if scene.examples is None:
        raise LbshapeError(f"scene {scene.name} has no examples")
    if not (math.isfinite(stiffness) and stiffness >= 0.0):
        raise LbshapeError(f"example stiffness must be finite and >= 0, got {stiffness}")
    return dataclasses.replace(scene, examples=dataclasses.replace(scene.examples,
                                                                   stiffness=float(stiffness)))


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


def end_twist_degrees(points: np.ndarray, u: np.ndarray, *, axis: int = 2,
                      end: str = "min", tolerance: float = 1e-3) -> float:
    """Mean rotation (degrees, right-handed about ``+axis``) of a bar's end section.

    Args:
        points: (n, 3) rest positions (m).
        u: (n, 3) displacement (m).
        axis: the bar's axis (0, 1, 2).
        end: ``"min"`` or ``"max"``: which end section (vertices within
            ``tolerance`` of the extreme axial coordinate).
        tolerance: thickness of the end section (m).

    Each vertex of the section beyond 30 % of its largest radius contributes the
    angle between its arm from the section's centroid at rest and deformed.
    """
    points, u = np.asarray(points, dtype=float), np.asarray(u, dtype=float).reshape(-1, 3)
    z = points[:, axis]
    extreme = z.min() if end == "min" else z.max()
    section = np.flatnonzero(np.abs(z - extreme) <= tolerance)
    if section.size < 2:
        raise LbshapeError("the bar's end section has fewer than two vertices")
    i, j = (axis + 1) % 3, (axis + 2) % 3
    rest = points[section] - points[section].mean(axis=0)
    moved = points[section] + u[section]
    moved = moved - moved.mean(axis=0)
    a, b = rest[:, [i, j]], moved[:, [i, j]]
    angles = np.arctan2(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], np.einsum("ij,ij->i", a, b))
    radius = np.linalg.norm(a, axis=1)
    keep = radius > 0.3 * radius.max()
    return float(np.degrees(np.mean(angles[keep])))
