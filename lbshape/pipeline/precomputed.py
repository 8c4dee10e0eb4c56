"""What a scene's precompute produced (:class:`Precomputed`) and its stored form.

The cache holds one artifact per scene and key (:mod:`lbshape.io.cache`): named arrays
and a small JSON ``meta``. This module is the one place that knows that format, in
both directions: :func:`artifact` turns the stages' results into (arrays, meta), and
:meth:`Precomputed.from_arrays` reads them back; :func:`required_arrays` is what a
cached artifact of a scene must hold. Bump :data:`PIPELINE_VERSION` whenever what is
stored, or what it means, changes.

**Parts.** A :class:`Precomputed` is composed of records, each present as a whole or
None: :class:`ElasticSpace` (every scene: U, ω², the reduced force model),
:class:`ShapeBasis` (scenes with examples, global or local: the object's LB eigenpairs
and the examples' names), :class:`GlobalExamples` (global examples: coefficients, maps
to reduced coordinates, target table, LB cubatures; also what the example stages hand
to :func:`artifact`), the local-example shape space
(:class:`~lbshape.shapespace.local_space.LocalShapeSpace`), a free body's
:class:`~lbshape.dynamics.fictitious.FrameTensors`, and :class:`StageReport` (how the
artifact was built). ``pre.U``, ``pre.r``, ``pre.has_examples`` and
``pre.has_local_examples`` are kept on the record itself.

**Shape-space maps** (:mod:`lbshape.shapespace.projections`): ``projection`` is stored
in the reduced coordinates of the dynamics, ``T = Uᵀ M L`` (U orthonormal in the
elastic mass ``M = ρ M₃``): the examples' reduced coordinates are ``T c`` with no
density factor, and the descriptor matrix and example descriptors come from the same
functions as the shape space's own (:func:`~lbshape.shapespace.projections.descriptor_matrix`,
:func:`~lbshape.shapespace.projections.example_descriptors`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from lbshape.dynamics.fictitious import FrameTensors
from lbshape.elastic.cubature import Cubature
from lbshape.elastic.materials import Material
from lbshape.elastic.polynomial_forces import PolynomialForceModel
from lbshape.geometry.mesh import TetMesh
from lbshape.io.cache import PACKED, pack_arrays, unpack_arrays
from lbshape.pipeline.impact_columns import ImpactBasis, leading_columns
from lbshape.scene.schema import Scene
from lbshape.shapespace.auto_stiffness import AutoStiffness
from lbshape.shapespace.basis_choice import METHODS
from lbshape.shapespace.clamped_basis import clamped_eigenvectors
from lbshape.shapespace.example_shapes import energy_elements
from lbshape.shapespace.local_space import LocalShapeSpace
from lbshape.shapespace.projections import block_basis, descriptor_matrix, example_descriptors
from lbshape.shapespace.target_table import TargetTable
from lbshape.spectral.spectrum import LBSpectrum

#: bumped whenever the artifact's content or meaning changes (part of the cache key).
#: 15: ``projection`` and ``projection_clamped`` hold ``T = Uᵀ M L`` (the reduced
#: coordinates of the dynamics) instead of ``(√ρ U)ᵀ M₃ L``. 18: U of a fixed object
#: with examples ends with the example responses it misses (``example-basis`` stage).
#: 20: a free body's U too (its responses without their rigid part). 21: a free body
#: whose own r reaches the responses' cap still gets a few of them. 22: a fixed object's
#: ``estimate`` stage holds the LDLᵀ factor of the estimate's effective stiffness, packed.
#: 23: local examples with a strong pull hold the anchored read-out responses; the exact
#: force's build budget doubled. 24: a free body's impact columns (``impact-basis``) with
#: their coupling and their own polynomial energy. 25: the impact throws carry the
#: global examples' pull. 26: the impact throws at 1.2 times the speed the body reaches
#: a plane.
PIPELINE_VERSION = 26
#: FrameTensors fields stored as ``frame_<field>`` arrays (free bodies)
FRAME_FIELDS = ("mass", "center", "Y0", "G", "C", "H", "S", "translation")
#: arrays every artifact holds, and those of scenes with examples
_REQUIRED = ("points", "tets", "fixed", "U", "omega2", "cub_elements", "cub_weights")
#: the estimate stage's arrays are stored packed (:func:`~lbshape.io.cache.pack_arrays`) as
#: ``est_floats``, ``est_integers``, ``est_layout``; ``est_present`` (fixed objects) is 1
#: when they are there
ESTIMATE_PREFIX, ESTIMATE_FLAG = "est_", "est_present"
_REQUIRED_FRAME = tuple(f"frame_{name}" for name in FRAME_FIELDS)
_REQUIRED_EXAMPLES = ("eigenvalues", "eigenvectors", "example_coefficients", "projection",
                      "alignment_residuals", "lb_cub_elements", "lb_cub_weights",
                      "lb_cub_errors")


class ForceCoefficients(NamedTuple):
    """The polynomial force model's coefficients
    (:class:`~lbshape.elastic.polynomial_forces.PolynomialForceModel`)."""

    K: np.ndarray  #: (r, r)
    pair_cubic: np.ndarray  #: (P, r) C̃
    pair_quartic: np.ndarray  #: (P, P) D̃


@dataclass(frozen=True)
class ElasticSpace:
    """The reduced elastic dynamics of every scene: the basis, its frequencies and the
    reduced force model.

    Attributes:
        U: (3n, r) nonlinear basis, ``Uᵀ M U = I`` (M the elastic mass, kg), in √kg⁻¹
            (q in √kg·m).
        omega2: (k,) squared angular frequencies of the linear modes used (rad²/s²).
        cubature_elements: (s,) int64 element indices of the force cubature.
        cubature_weights: (s,) their non-negative weights (dimensionless).
        cubature_errors: the cubature's relative force errors: ``train``, ``holdout``,
            ``tolerance`` and ``reached_tolerance``.
        force_model: the reduced elastic force of the engines: ``"polynomial"`` (exact,
            :attr:`force_coefficients`) or ``"cubature"``.
        force_coefficients: the :class:`ForceCoefficients` of the polynomial force
            model, or None.
        impact_coupling: (r, r) ``Uᵀ K₀ U`` (1/s²) of a basis ending with impact
            columns (:mod:`lbshape.pipeline.impact_columns`), else None.
        leading: the columns before the impact columns (those of the force model
            above), or None without them.
        impact_forces: the impact columns' own polynomial energy (the
            :class:`ForceCoefficients` on them), or None (their energy quadratic); per
            feature each array has a leading axis of the t sets.
        impact_directions: per feature (``reduced.impact_columns_per`` ``"feature"`` or
            ``"feature-pair"``): (t, 3) each set's direction, the rest-frame plane
            normals its features' throws hit, summed (one feature: its normal), the
            sets of (r − leading) / t columns in that order; None: one set.
    """

    U: np.ndarray
    omega2: np.ndarray
    cubature_elements: np.ndarray
    cubature_weights: np.ndarray
    cubature_errors: dict
    force_model: str = "cubature"
    force_coefficients: ForceCoefficients | None = None
    impact_coupling: np.ndarray | None = None
    leading: int | None = None
    impact_forces: ForceCoefficients | None = None
    impact_directions: np.ndarray | None = None

    @property
    def r(self) -> int:
        """The number of reduced coordinates."""
        return int(self.U.shape[1])

    def impact_column_sets(self) -> list[np.ndarray]:
        """Each set of impact columns as its (k,) columns of U: per feature one a row of
        :attr:`impact_directions`, else the one set of them all (none without)."""
        if self.impact_coupling is None:
            return []
        sets = 1 if self.impact_directions is None else len(self.impact_directions)
        k = (self.r - self.leading) // sets
        return [self.leading + j * k + np.arange(k) for j in range(sets)]


@dataclass(frozen=True)
class ShapeBasis:
    """The object's LB basis, which both kinds of examples (global and local) share.
    Present whenever the scene has examples.

    Attributes:
        eigenvalues: (m,) the object's LB eigenvalues (1/m²), constant mode excluded.
        eigenvectors: (n, m) Φ, M₃-orthonormal (M₃ the volume mass, m³).
        example_names: (k,) the scene's example labels.
        mesh: the object's rest mesh (the same as :attr:`Precomputed.mesh`).
        fixed_vertices: (f,) the fixed vertices (the clamped basis is zero there).
    """

    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    example_names: tuple[str, ...]
    mesh: TetMesh
    fixed_vertices: np.ndarray

    @property
    def m(self) -> int:
        """The number of LB eigenpairs."""
        return int(self.eigenvalues.shape[0])

    def target_eigenvectors(self, clamped: bool = False) -> np.ndarray:
        """(n, m) Φ, or Φ_F faded to zero at the fixed vertices when ``clamped``."""
        if not clamped or self.fixed_vertices.size == 0:
            return self.eigenvectors
        return clamped_eigenvectors(self.eigenvectors, self.fixed_vertices, self.mesh.points)

    def lb_basis(self, *, clamped: bool = False) -> np.ndarray:
        """(3n, 3m) dense ``L = Φ ⊗ I₃`` (node-major rows, column 3i+k); ``clamped``: L_F."""
        return block_basis(self.target_eigenvectors(clamped))


class LBCubatures(NamedTuple):
    """The cubature of the LB displacement subspace (the ``lb`` route, basis
    :meth:`ShapeBasis.lb_basis`)."""

    #: (k, s) int64, one row per example, padded with element -1 (or (s,) shared)
    elements: np.ndarray
    weights: np.ndarray  #: (k, s) (or (s,)), padded with weight 0
    errors: np.ndarray  #: (2,) the largest training and held-out errors over the examples

    @property
    def named_errors(self) -> dict[str, float]:
        """:attr:`errors` as ``{"train": …, "holdout": …}``."""
        return {"train": float(self.errors[0]), "holdout": float(self.errors[1])}


@dataclass(frozen=True)
class GlobalExamples:
    """The shape space of a scene with global examples (the whole object's): what its
    example stages produce and the artifact stores, in the elastic reduced coordinates
    (see the module docstring).

    Attributes:
        shape: the LB basis the coefficients are in (:attr:`Precomputed.shape`).
        density: ρ (kg/m³) of the elastic mass ``M = ρ M₃`` U is orthonormal in.
        example_coefficients: (k, m, 3) the examples' LB displacement coefficients (m).
        projection: (r, 3m) ``T = Uᵀ M L``: LB displacement coefficients c to reduced
            coordinates ``q = T c``
            (:func:`~lbshape.shapespace.projections.reduced_projection`).
        alignment_residuals: (k,) basis alignment residuals.
        alignment_method_codes: (k,) int index into
            :data:`~lbshape.shapespace.basis_choice.METHODS` of each example's
            alignment method (:attr:`alignment_methods`).
        projection_clamped: (r, 3m) the same as :attr:`projection` for the clamped basis
            ``L_F`` (faded to zero at the fixed vertices), or None.
        target_table: the :class:`~lbshape.shapespace.target_table.TargetTable` of the
            exact target in the :attr:`target_boundary` LB basis, or None (more than 3
            examples, or refused by its check).
        target_clamped: the target routes use the LB basis faded to zero at the fixed
            vertices (only with :data:`~lbshape.pipeline.precompute.CLAMPED_TARGETS` and
            when it keeps the examples' elements healthy,
            :func:`~lbshape.shapespace.example_shapes.clamp_is_safe`); the table and the
            per-example LB cubatures use it.
        lb_cubatures: the per-example cubatures of the LB displacement subspace, or None.
    """

    shape: ShapeBasis
    density: float
    example_coefficients: np.ndarray
    projection: np.ndarray
    alignment_residuals: np.ndarray
    alignment_method_codes: np.ndarray | None = None
    projection_clamped: np.ndarray | None = None
    target_table: TargetTable | None = None
    target_clamped: bool = False
    lb_cubatures: LBCubatures | None = None

    @property
    def k(self) -> int:
        """The number of examples."""
        return int(self.example_coefficients.shape[0])

    @property
    def alignment_methods(self) -> list[str]:
        """(k,) each example's basis alignment method (``overlay`` or ``intrinsic``)."""
        codes = [] if self.alignment_method_codes is None else self.alignment_method_codes
        return [METHODS[int(c)] for c in codes]

    @property
    def target_boundary(self) -> str:
        """``"clamped"`` or ``"free"``: the LB basis of the target routes
        (:attr:`target_clamped`)."""
        return "clamped" if self.target_clamped else "free"

    @property
    def lb_to_reduced(self) -> np.ndarray:
        """(r, 3m) ``T``: maps LB displacement coefficients c to reduced coordinates q."""
        return self.projection

    def lb_to_reduced_for(self, *, clamped: bool) -> np.ndarray:
        """(r, 3m) the map of LB coefficients to reduced coordinates for L or L_F."""
        if clamped and self.projection_clamped is not None:
            return self.projection_clamped
        return self.lb_to_reduced

    @property
    def descriptor_matrix(self) -> np.ndarray:
        """(3m, r) ``D``: λ-weighted LB coefficients of ``U q`` are ``D q``."""
        return descriptor_matrix(self.shape.eigenvalues, self.projection, self.density)

    @property
    def example_descriptors(self) -> np.ndarray:
        """(k, 3m) λ-weighted example displacement coefficients."""
        return example_descriptors(self.shape.eigenvalues, self.example_coefficients)

    def rest_points(self, index: int, *, clamped: bool = False) -> np.ndarray:
        """(n, 3) example ``index`` reconstructed on the object's mesh (its rest shape, m);
        ``clamped``: with the clamped basis (no displacement at the fixed vertices)."""
        return self.shape.mesh.points + self.shape.target_eigenvectors(clamped) @ \
            self.example_coefficients[index]

    def energy_elements(self, *, clamped: bool = False) -> np.ndarray:
        """(e,) int64 the elements the example energies sum over
        (:func:`~lbshape.shapespace.example_shapes.energy_elements` of the rest shapes
        of :meth:`rest_points`)."""
        mesh = self.shape.mesh
        return energy_elements(mesh.points, mesh.tets, [
            self.rest_points(i, clamped=clamped) for i in range(self.k)])


class LocalExamples(NamedTuple):
    """What the stages of a scene with local examples (regions) produce."""

    space: LocalShapeSpace
    spectrum: LBSpectrum  #: the whole object's LB spectrum (pictures, measurements)


@dataclass(frozen=True)
class StageReport:
    """How the artifact was built (per stage name).

    Attributes:
        seconds: wall time per stage (s) of the run that built the artifact.
        peak_mb: largest resident memory (MB) of the process during each stage of that
            run; under MPI the sum of every rank's peak (the job's memory).
        ranks: the number of MPI ranks each stage of that run was distributed over
            (1: rank 0 alone, or a serial run).
        from_cache: True when loaded from the cache.
        cached: the stages this call took from the cache (all of them when the artifact
            itself came from it; else the stage entries that were stored).
    """

    seconds: dict = field(default_factory=dict)
    peak_mb: dict = field(default_factory=dict)
    ranks: dict = field(default_factory=dict)
    from_cache: bool = False
    cached: tuple = ()


@dataclass(frozen=True)
class Precomputed:
    """Everything the runtime of a scene needs (n-sized arrays only for output),
    composed of its parts, each present as a whole or None.

    Attributes:
        scene: scene name.
        key: cache key.
        mesh: object rest mesh.
        material: the scene's material.
        fixed_vertices: (f,) fixed vertex indices (empty for a free object).
        elastic: the basis U and the reduced force model (:class:`ElasticSpace`).
        shape: the object's LB basis (:class:`ShapeBasis`), or None without examples.
        examples: the global examples' shape space (:class:`GlobalExamples`), or None.
        local: the local-example shape space (scenes with regions), or None.
        frame: reduced rigid-frame tensors of a free body, or None (fixed object).
        stages: how the artifact was built (:class:`StageReport`).
        auto_stiffness: the k_ex the precompute set for ``stiffness = "auto"`` and why
            (:class:`~lbshape.shapespace.auto_stiffness.AutoStiffness`), or None (a
            number in the scene, or no examples).
        estimate: the error estimate's per-object operators (the ``estimate`` stage,
            :meth:`~lbshape.analysis.error_estimate.EstimateOperators.arrays`), or None.
    """

    scene: str
    key: str
    mesh: TetMesh
    material: Material
    fixed_vertices: np.ndarray
    elastic: ElasticSpace
    shape: ShapeBasis | None = None
    examples: GlobalExamples | None = None
    local: LocalShapeSpace | None = None
    frame: FrameTensors | None = None
    stages: StageReport = field(default_factory=StageReport)
    auto_stiffness: AutoStiffness | None = None
    estimate: dict | None = None

    @property
    def U(self) -> np.ndarray:
        """(3n, r) the elastic basis (:attr:`ElasticSpace.U`)."""
        return self.elastic.U

    @property
    def r(self) -> int:
        """The number of reduced coordinates."""
        return self.elastic.r

    @property
    def has_examples(self) -> bool:
        """Global examples (the whole object's shape space, :attr:`examples`)."""
        return self.examples is not None

    @property
    def has_local_examples(self) -> bool:
        """Local examples by region (:attr:`local`)."""
        return self.local is not None

    # --- the stored form
    @classmethod
    def from_arrays(cls, scene: Scene, key: str, arrays: dict, meta: dict, *,
                    from_cache: bool = True) -> Precomputed:
        """The precompute stored as (arrays, meta) by :func:`artifact`."""
        mesh = TetMesh(np.asarray(arrays["points"]), np.asarray(arrays["tets"]),
                       *_groups_from_arrays(arrays))
        fixed = np.asarray(arrays["fixed"], dtype=np.int64)
        polynomial = "poly_K" in arrays
        elastic = ElasticSpace(
            U=np.asarray(arrays["U"]), omega2=np.asarray(arrays["omega2"]),
            cubature_elements=np.asarray(arrays["cub_elements"], dtype=np.int64),
            cubature_weights=np.asarray(arrays["cub_weights"]),
            cubature_errors=meta.get("cubature_errors", {}),
            force_model="polynomial" if polynomial else "cubature",
            force_coefficients=(ForceCoefficients(np.asarray(arrays["poly_K"]),
                                                  np.asarray(arrays["poly_cubic"]),
                                                  np.asarray(arrays["poly_quartic"]))
                                if polynomial else None),
            impact_coupling=(np.asarray(arrays["impact_coupling"])
                             if "impact_coupling" in arrays else None),
            leading=(int(np.asarray(arrays["impact_leading"])[0])
                     if "impact_leading" in arrays else None),
            impact_forces=(ForceCoefficients(*(np.asarray(arrays[f"impact_poly_{name}"])
                                               for name in ("K", "cubic", "quartic")))
                           if "impact_poly_K" in arrays else None),
            impact_directions=(np.asarray(arrays["impact_directions"])
                               if "impact_directions" in arrays else None))
        shape = (ShapeBasis(arrays["eigenvalues"], arrays["eigenvectors"],
                            tuple(meta.get("example_names", ())), mesh, fixed)
                 if "eigenvalues" in arrays else None)
        return cls(
            scene=scene.name, key=key, mesh=mesh, material=scene.material,
            fixed_vertices=fixed, elastic=elastic, shape=shape,
            examples=(_examples_from_arrays(arrays, shape, scene.material.density)
                      if "example_coefficients" in arrays else None),
            local=(LocalShapeSpace.from_arrays(meta["local_regions"], arrays,
                                               meta.get("local_representation_errors", {}))
                   if "local_regions" in meta else None),
            frame=(FrameTensors(**{name: (float(arrays[f"frame_{name}"]) if name == "mass"
                                          else np.asarray(arrays[f"frame_{name}"]))
                                   for name in FRAME_FIELDS})
                   if "frame_G" in arrays else None),
            stages=StageReport(seconds=dict(meta.get("stage_seconds", {})),
                               peak_mb=dict(meta.get("stage_peak_mb", {})),
                               ranks=dict(meta.get("stage_ranks", {})),
                               from_cache=from_cache,
                               cached=tuple(meta.get("stage_seconds", {}) if from_cache
                                            else meta.get("stage_cached", ()))),
            auto_stiffness=(AutoStiffness.from_dict(meta["example_stiffness"])
                            if meta.get("example_stiffness") else None),
            estimate=(unpack_arrays({name: arrays[ESTIMATE_PREFIX + name] for name in PACKED})
                      if int(np.asarray(arrays.get(ESTIMATE_FLAG, [0]))[0]) else None),
        )


def _examples_from_arrays(arrays: dict, shape: ShapeBasis, density: float) -> GlobalExamples:
    """Inverse of :func:`_example_arrays`."""
    return GlobalExamples(
        shape=shape, density=float(density),
        example_coefficients=arrays["example_coefficients"],
        projection=arrays["projection"],
        alignment_residuals=arrays["alignment_residuals"],
        alignment_method_codes=arrays.get("alignment_methods"),
        projection_clamped=arrays.get("projection_clamped"),
        target_table=TargetTable.from_arrays(arrays),
        target_clamped=bool(int(np.asarray(arrays.get("target_clamped", [0]))[0])),
        lb_cubatures=LBCubatures(np.asarray(arrays["lb_cub_elements"], dtype=np.int64),
                                 arrays["lb_cub_weights"], np.asarray(arrays["lb_cub_errors"])),
    )


def artifact(scene: Scene, *, mesh: TetMesh, fixed: np.ndarray, U: np.ndarray,
             omega2: np.ndarray, cubature: Cubature, polynomial: PolynomialForceModel | None,
             examples: GlobalExamples | None, local: LocalExamples | None,
             frame: FrameTensors | None, example_names: list[str],
             stage_ranks: dict[str, int],
             auto_stiffness: AutoStiffness | None = None,
             estimate: dict | None = None,
             impact: ImpactBasis | None = None) -> tuple[dict, dict]:
    """The stages' results as the artifact's (arrays, meta) (read by
    :meth:`Precomputed.from_arrays`); ``impact``: the ``impact-basis`` stage's result."""
    arrays = {
        **_group_arrays(mesh),
        "points": mesh.points, "tets": mesh.tets, "fixed": fixed, "U": U,
        "omega2": omega2, "cub_elements": cubature.elements,
        "cub_weights": cubature.weights,
        **({} if polynomial is None else {
            "poly_K": polynomial.K, "poly_cubic": polynomial.pair_cubic,
            "poly_quartic": polynomial.pair_quartic}),
    }
    if impact is not None:
        arrays.update({"impact_coupling": impact.coupling,
                       "impact_leading": np.array([leading_columns(impact.basis)])})
        if impact.directions is not None:
            arrays["impact_directions"] = impact.directions
        if impact.columns is not None:  # per feature: stacked, a leading axis of the sets
            arrays.update({f"impact_poly_{name}": getattr(impact.columns, attribute)
                           if impact.directions is None else
                           np.stack([getattr(m, attribute) for m in impact.columns])
                           for name, attribute in (("K", "K"), ("cubic", "pair_cubic"),
                                                   ("quartic", "pair_quartic"))})
    meta = {"scene": scene.name, "cubature_errors": {
        "train": cubature.train_error, "holdout": cubature.holdout_error,
        "tolerance": cubature.tol, "reached_tolerance": bool(cubature.reached_tol)},
        "stage_ranks": stage_ranks}
    if auto_stiffness is not None:
        meta["example_stiffness"] = auto_stiffness.to_dict()
    if local is not None:
        arrays.update(local.space.arrays())
        arrays.update({"eigenvalues": local.spectrum.eigenvalues,
                       "eigenvectors": local.spectrum.eigenvectors})
        meta["example_names"] = list(example_names)
        meta["local_regions"] = [reg.name for reg in scene.regions]
        meta["local_representation_errors"] = local.space.representation_errors
    elif examples is not None:
        arrays.update(_example_arrays(examples))
        meta["example_names"] = list(example_names)
    if frame is not None:
        arrays.update({f"frame_{name}": np.asarray(getattr(frame, name))
                       for name in FRAME_FIELDS})
    else:  # a fixed object: the estimate stage's operators, or the flag saying none
        arrays[ESTIMATE_FLAG] = np.array([int(estimate is not None)])
        if estimate is not None:  # packed: many small members cost more to read than one
            arrays.update({ESTIMATE_PREFIX + k: v for k, v in pack_arrays(estimate).items()})
    return arrays, meta


def required_arrays(scene: Scene) -> tuple[str, ...]:
    """The arrays a cached artifact of ``scene`` must hold."""
    required = _REQUIRED + (_REQUIRED_EXAMPLES if scene.has_examples else ())
    if scene.has_local_examples:
        required = _REQUIRED + ("eigenvalues", "eigenvectors") \
            + LocalShapeSpace.required_arrays(len(scene.regions))
    if scene.is_free:
        required = required + _REQUIRED_FRAME
    else:
        required = required + (ESTIMATE_FLAG,)
    if scene.reduced.impact_columns:
        required = required + ("impact_coupling", "impact_leading")
    if scene.reduced.sets_per_feature:
        required = required + ("impact_directions",)
    return required


def _example_arrays(examples: GlobalExamples) -> dict[str, np.ndarray]:
    table = examples.target_table
    lb = examples.lb_cubatures
    return {
        "lb_cub_elements": lb.elements, "lb_cub_weights": lb.weights,
        "lb_cub_errors": lb.errors,
        **({} if table is None else table.to_arrays()),
        "projection_clamped": examples.projection_clamped,
        "target_clamped": np.array([int(examples.target_clamped)], dtype=np.int64),
        "eigenvalues": examples.shape.eigenvalues,
        "eigenvectors": examples.shape.eigenvectors,
        "example_coefficients": examples.example_coefficients,
        "projection": examples.projection,
        "alignment_residuals": examples.alignment_residuals,
        "alignment_methods": np.asarray(examples.alignment_method_codes, dtype=np.int64),
    }


def _group_arrays(mesh: TetMesh) -> dict[str, np.ndarray]:
    """The mesh's physical groups as artifact arrays (loads may name them at run time)."""
    out = {f"cgroup__{name}": np.asarray(v, dtype=np.int64) for name, v in mesh.cell_groups.items()}
    out.update({f"vgroup__{name}": np.asarray(v, dtype=np.int64)
                for name, v in mesh.vertex_groups.items()})
    return out


def _groups_from_arrays(arrays: dict) -> tuple[dict, dict]:
    """Inverse of :func:`_group_arrays`: (cell groups, vertex groups)."""
    cells = {k[len("cgroup__"):]: np.asarray(v, dtype=np.int64) for k, v in arrays.items()
             if k.startswith("cgroup__")}
    vertices = {k[len("vgroup__"):]: np.asarray(v, dtype=np.int64) for k, v in arrays.items()
                if k.startswith("vgroup__")}
    return cells, vertices
