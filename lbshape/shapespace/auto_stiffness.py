"""``stiffness = "auto"``: the example stiffness k_ex set from what the examples ask.

A scene's example force is ``k_ex (q* − q)`` in mass-normalised reduced coordinates
(``UᵀMU = I``). :func:`auto_example_stiffness` chooses k_ex (1/s²) from two things the
examples ask of the object, on arrays only (no scene, no precompute):

**The examples' own stiffness.** Let e be an example's displacement field on the object
(its LB coefficients reconstructed on the object's mesh, (3n,) m; a local example's on its
region's mesh) and ``‖e‖_M = √(eᵀMe)`` its size in the mass M. The ω² of the example
shape is the secant Rayleigh quotient of its elastic energy E (the StVK energy of the
material's Lamé parameters: defined for any shape, zero for rotations, so a twist's
rotation is not counted as strain as the linear ``eᵀKe`` would; for small e it is
``eᵀKe / eᵀMe``):

    ω_e² = 2 E(e) / ‖e‖_M²,

the elastic force per unit of mass-normalised displacement that holds the object in that
shape. Along the example, ``u = a e``, with the target at the example and no loads, the
example force ``k_ex (1 − a)`` balances the elastic ``a ω_e²`` (per unit of ‖e‖_M²):

    a ω_e² = k_ex (1 − a)     ⇒     a = k_ex / (k_ex + ω_e²).

The object then goes the share ``a`` of the way from rest to the example. It ends closer
to the example than to the rest shape (``closest_example``) when ``a > ½``, i.e.
``k_ex > ω_e²``; a chosen share a* needs

    k_ex ≥ SHAPE_FACTOR · ω_e²,        SHAPE_FACTOR = a* / (1 − a*).

**The loads.** A load's generalized force ``g = Uᵀ f`` (f (3n,) N, the scene's loads at
full strength, U the basis, ``UᵀMU = I``) pushes the object along directions the example
need not share. The pull towards an example at the rest shape is ``k_ex ‖e‖_M``; for the
examples to be more than a small correction to what the loads do, it is at least
LOAD_FACTOR times the loads' pull:

    k_ex ≥ LOAD_FACTOR · ‖g‖ / ‖e‖_M.

A local example pulls only its region (:mod:`lbshape.shapespace.local_space`): the
loads it stands out against are those applied on the region, ``g_R = Uᵀ f_R`` (f_R the
loads' rows of the region's vertices, zero elsewhere); a load on another region is
that region's examples' concern (per example, ``load_force`` takes one value each).

**The rule.** Each example needs ``k_e = max(SHAPE_FACTOR ω_e², LOAD_FACTOR ‖g‖ /
‖e‖_M)``; ``k_ex = min over the examples of k_e``: the example that asks least is reached
the share a* of the way against its own stiffness and pulls LOAD_FACTOR times the loads.
(The largest k_e — every example reachable — was tried first: it reached every example,
but an object's stiffest example, e.g. the cross's twisted arm, then set k_ex at 560 ω₁²,
and the reduced local examples drifted 17–28 % from the full reference; a pull that strong
is more than the reduced space holds.) Scaling the loads by s scales the load term by s; a
smaller example needs a stronger pull to stand out against the same loads; ω_e² depends on
the example's amplitude only through the energy's nonlinearity. The constants were
calibrated once on the built-in fixed scenes and a clamped object without loads
(``docs/decisions.md``, 2026-11-28), never per scene.

**Local examples: every region near an example.** ``a = k_ex / (k_ex + ω_e²)`` is the
share of the displacement; whether a region ends closer to an example than to rest is
judged on its LB descriptor, which weighs the fine detail the pull reaches last
(teddy-local's right leg, ω_e² = 479, stays nearer rest up to k_ex ≈ 1800). For local
examples the precompute therefore raises the rule's k_ex until the object's linear static
equilibrium under its loads and the pull has every region within
:data:`~lbshape.shapespace.local_equilibrium.CLOSEST_RATIO` of an example
(:func:`lbshape.shapespace.local_equilibrium.equilibrium_stiffness`; the rule's value
stands when it already does, as on the cross).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from lbshape.elastic.element_kernels import FullSpaceElasticity, mass_matrix
from lbshape.elastic.materials import Material
from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.shapespace.local_equilibrium import CLOSEST_RATIO, MAX_RAISE

__all__ = ["AUTO_RULE", "LOAD_FACTOR", "SHAPE_FACTOR", "TARGET_SHARE", "AutoStiffness",
           "auto_example_stiffness", "example_field_stiffness"]

#: the share a* of the way from rest to an example that k_ex reaches against the
#: example's own linear stiffness (no loads); SHAPE_FACTOR = a* / (1 − a*)
TARGET_SHARE = 2.0 / 3.0
#: an example e needs k_ex ≥ SHAPE_FACTOR · ω_e²
SHAPE_FACTOR = TARGET_SHARE / (1.0 - TARGET_SHARE)
#: ... and a pull towards it at rest, k_ex ‖e‖_M, of at least LOAD_FACTOR times the
#: loads' generalized force ‖Uᵀ f‖
LOAD_FACTOR = 2.0
#: an example whose ω² is below this share of E / (ρ D²) (D the bounding-box diagonal)
#: has no strain energy: the rest shape or a rigid motion of it
RIGID_TOLERANCE = 1e-9
#: what the rule's result depends on besides the scene (part of the precompute's cache
#: key: a new constant recomputes the precomputes of "auto" scenes)
AUTO_RULE = ("energy-rayleigh-min-2-region-loads", SHAPE_FACTOR, LOAD_FACTOR,
             "local-static-closest", CLOSEST_RATIO, MAX_RAISE)


@dataclass(frozen=True)
class AutoStiffness:
    """What :func:`auto_example_stiffness` chose, and why.

    Attributes:
        k_ex: the example stiffness, 1/s².
        omega1_sq: ω₁², the object's lowest non-rigid squared angular frequency, rad²/s².
        example_omega2: (k,) ω_e² of each example shape (its Rayleigh quotient), rad²/s².
        example_norms: (k,) ‖e‖_M of each example's displacement, m·√kg.
        load_force: ‖Uᵀ f‖ of the loads at full strength, N/√kg (0 without loads).
        example_loads: (k,) the loads' ‖Uᵀ f‖ each example stands out against (a local
            example: the loads on its region), N/√kg.
        governing: ``"shape"`` (an example's own stiffness set k_ex), ``"loads"``, or
            ``"regions"`` (local examples: raised until every region's static
            equilibrium is near an example, ``raised_from`` the rule's value).
        example: the index of the example that set k_ex (before any raise).
        raised_from: the rule's k_ex before the regions' raise, 1/s² (0: not raised).
        closeness: per region (local examples), the static equilibrium's distance to its
            nearest example over its distance to rest at k_ex
            (:func:`lbshape.shapespace.local_equilibrium.region_closeness`).
    """

    k_ex: float
    omega1_sq: float
    example_omega2: tuple[float, ...]
    example_norms: tuple[float, ...]
    load_force: float
    governing: str
    example: int
    example_loads: tuple[float, ...] = ()
    raised_from: float = 0.0
    closeness: tuple[tuple[str, float], ...] = ()

    def summary(self) -> str:
        """The one line precompute and simulate print."""
        ratio = self.k_ex / self.omega1_sq if self.omega1_sq > 0 else float("nan")
        if self.governing == "regions":
            name, near = max(self.closeness, key=lambda item: item[1])
            why = (f"raised from {self.raised_from:.4g} until every region's static "
                   f"equilibrium is nearer an example; {name} at {near:.2f} of its "
                   "distance to rest" if near <= CLOSEST_RATIO else
                   f"raised from {self.raised_from:.4g} to the limit, {MAX_RAISE:g}×; "
                   f"{name}'s static equilibrium stays at {near:.2f} of its distance to "
                   "rest from an example: give a number to pull harder")
        elif self.governing == "shape":
            why = (f"{SHAPE_FACTOR:g}×ω² of example {self.example}'s shape, "
                   f"ω² = {self.example_omega2[self.example]:.4g} 1/s²")
        else:
            why = (f"the pull to example {self.example} at rest {LOAD_FACTOR:g}× the "
                   "loads' generalized force")
        return f"example stiffness auto: k_ex = {self.k_ex:.4g} 1/s² ({ratio:.3g}×ω₁², {why})"

    def to_dict(self) -> dict:
        """JSON-compatible fields (the precompute's metadata)."""
        data = asdict(self)
        data["example_omega2"] = list(self.example_omega2)
        data["example_norms"] = list(self.example_norms)
        data["example_loads"] = list(self.example_loads)
        data["closeness"] = [list(item) for item in self.closeness]
        return data

    @classmethod
    def from_dict(cls, data: dict) -> AutoStiffness:
        return cls(k_ex=float(data["k_ex"]), omega1_sq=float(data["omega1_sq"]),
                   example_omega2=tuple(float(v) for v in data["example_omega2"]),
                   example_norms=tuple(float(v) for v in data["example_norms"]),
                   load_force=float(data["load_force"]), governing=str(data["governing"]),
                   example=int(data["example"]),
                   example_loads=tuple(float(v) for v in data.get("example_loads", ())),
                   raised_from=float(data.get("raised_from", 0.0)),
                   closeness=tuple((str(name), float(v))
                                   for name, v in data.get("closeness", ())))


def example_field_stiffness(mesh: TetMesh, material: Material,
                            field: np.ndarray) -> tuple[float, float]:
    """``(ω_e², ‖e‖_M)`` of one example's displacement field e ((n, 3) or (3n,) m) on
    ``mesh`` (the object, or the region of a local example): ``ω_e² = 2 E(e) / ‖e‖²_M``
    in rad²/s² and ``‖e‖_M = √(eᵀMe)`` in m·√kg (module docstring).

    Raises:
        LbshapeError: a field without strain energy (the rest shape, or a rigid motion).
    """
    e = np.asarray(field, dtype=float).reshape(-1)
    mass = mass_matrix(mesh, material.density)
    norm2 = float(e @ (mass @ e))
    energy = float(FullSpaceElasticity(mesh, dataclasses.replace(material, model="stvk"))
                   .energy(e))
    # the scale of ω² on this mesh: E / (ρ D²), D its bounding-box diagonal
    diagonal = float(np.linalg.norm(np.ptp(mesh.points, axis=0)))
    floor = RIGID_TOLERANCE * material.young / (material.density * diagonal ** 2)
    if not (norm2 > 0 and np.isfinite(energy) and 2.0 * energy > floor * norm2):
        raise LbshapeError("the example equals the object's rest shape or a rigid motion of "
                           "it (no strain energy): give 'stiffness' a number")
    return 2.0 * energy / norm2, float(np.sqrt(norm2))


def auto_example_stiffness(examples: Sequence[tuple[TetMesh, np.ndarray]],
                           material: Material, *, omega1_sq: float,
                           load_force: float | Sequence[float] = 0.0) -> AutoStiffness:
    """k_ex (1/s²) from the examples' displacement fields and the loads (module docstring).

    Args:
        examples: per example, ``(mesh, e)``: the mesh it deforms (the object, or a local
            example's region) and its displacement e on it, (n, 3) m.
        material: the object's material (the example shapes' energy is its StVK energy
            with the same Lamé parameters: defined for any shape, zero for rotations).
        omega1_sq: ω₁² of the object (rad²/s²), for the report.
        load_force: ‖Uᵀ f‖ of the loads at full strength, N/√kg (0: no loads); or (k,)
            one per example: the loads each example stands out against (a local example:
            those on its region); the record's ``load_force`` is then their largest.

    Raises:
        LbshapeError: no examples, or an example without strain energy (naming it).
    """
    if not examples:
        raise LbshapeError("example stiffness auto: no examples")
    measures = []
    for k, (mesh, field) in enumerate(examples):
        try:
            measures.append(example_field_stiffness(mesh, material, field))
        except LbshapeError as exc:
            raise LbshapeError(f"example stiffness auto: example {k}: {exc}") from None
    omega2, norms = (np.array(v) for v in zip(*measures, strict=True))
    loads = np.broadcast_to(np.asarray(load_force, dtype=float), norms.shape)
    shape_terms = SHAPE_FACTOR * omega2
    load_terms = LOAD_FACTOR * loads / norms
    terms = np.maximum(shape_terms, load_terms)  # what each example needs
    k = int(np.argmin(terms))  # the example that needs the least
    return AutoStiffness(
        k_ex=float(terms[k]), omega1_sq=float(omega1_sq),
        example_omega2=tuple(float(v) for v in omega2),
        example_norms=tuple(float(v) for v in norms), load_force=float(loads.max()),
        governing="shape" if shape_terms[k] >= load_terms[k] else "loads", example=k,
        example_loads=tuple(float(v) for v in loads))
