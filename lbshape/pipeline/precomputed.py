"""What a scene's precompute produced (:class:`Precomputed`) and its stored form.

The cache holds one artifact per scene and key (:mod:`lbshape.io.cache`): named arrays
and a small JSON ``meta``. This module is the one place that knows that format, in
both directions: :func:`artifact` turns the stages' results into (arrays, meta), and
:meth:`Precomputed.from_arrays` reads them back; :func:`required_arrays` is what a
cached artifact of a scene must hold. Bump :data:`PIPELINE_VERSION` whenever what is
stored, or what it means, changes.

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
from lbshape.scene.schema import Scene
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
#: whose own r reaches the responses' cap still gets a few of them.
PIPELINE_VERSION = 21
#: FrameTensors fields stored as ``frame_<field>`` arrays (free bodies)
FRAME_FIELDS = ("mass", "center", "Y0", "G", "C", "H", "S", "translation")
#: arrays every artifact holds, and those of scenes with examples
_REQUIRED = ("points", "tets", "fixed", "U", "omega2", "cub_elements", "cub_weights")
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


class LBCubatures(NamedTuple):
    """The per-example cubatures of the LB displacement subspace (the ``lb`` route)."""

    elements: np.ndarray  #: (k, s) int64, one row per example, padded with element -1
    weights: np.ndarray  #: (k, s), padded with weight 0
    errors: np.ndarray  #: (2,) the largest training and held-out errors over the examples


class GlobalExamples(NamedTuple):
    """What the example stages of a scene with global examples store."""

    spectrum: LBSpectrum  #: the object's LB spectrum (m pairs)
    example_coefficients: np.ndarray  #: (k, m, 3)
    projection: np.ndarray  #: (r, 3m) ``T = Uᵀ M L``
    projection_clamped: np.ndarray  #: (r, 3m) the same for the clamped basis L_F
    alignment_residuals: np.ndarray  #: (k,)
    alignment_methods: np.ndarray  #: (k,) int: index into ``basis_choice.METHODS``
    target_table: TargetTable | None  #: the exact target tabulated, or None
    target_clamped: bool  #: the table and LB cubatures use the clamped basis
    lb_cubatures: LBCubatures


class LocalExamples(NamedTuple):
    """What the stages of a scene with local examples (regions) store."""

    space: LocalShapeSpace
    spectrum: LBSpectrum  #: the whole object's LB spectrum (pictures, measurements)


@dataclass(frozen=True)
class Precomputed:
    """Everything the runtime of a scene needs (n-sized arrays only for output).

    Attributes:
        scene: scene name.
        key: cache key.
        mesh: object rest mesh.
        material: the scene's material.
        fixed_vertices: (f,) fixed vertex indices (empty for a free object).
        U: (3n, r) nonlinear basis, ``Uᵀ M U = I`` (M the elastic mass).
        omega2: (k,) squared angular frequencies of the linear modes used (rad²/s²).
        cubature_elements: (s,) element indices; ``cubature_weights`` (s,).
        cubature_errors: training and held-out relative force errors.
        force_model: the reduced elastic force of the engines: ``"polynomial"`` (exact,
            :attr:`force_coefficients`) or ``"cubature"``.
        force_coefficients: the :class:`ForceCoefficients` of the polynomial force
            model, or None.
        eigenvalues: (m,) object's LB eigenvalues (1/m²) or None without examples.
        eigenvectors: (n, m) object's LB eigenvectors (M₃-orthonormal) or None.
        example_coefficients: (k, m, 3) example LB displacement coefficients or None.
        projection: (r, 3m) ``T = Uᵀ M L``: LB displacement coefficients c to reduced
            coordinates ``q = T c`` (:func:`~lbshape.shapespace.projections.reduced_projection`),
            or None.
        projection_clamped: (r, 3m) the same for the clamped basis ``L_F`` (faded to
            zero at the fixed vertices), or None.
        target_table: the :class:`~lbshape.shapespace.target_table.TargetTable` of the
            exact target in the :attr:`target_boundary` LB basis, or None (no examples,
            more than 3, or refused by its check).
        target_boundary: ``"clamped"`` when the target routes use the LB basis faded to
            zero at the fixed vertices (only with
            :data:`~lbshape.pipeline.precompute.CLAMPED_TARGETS` and when it keeps the
            examples' elements healthy,
            :func:`~lbshape.shapespace.example_shapes.clamp_is_safe`), else ``"free"``;
            the table and the per-example LB cubature use it.
        alignment_residuals: (k,) basis alignment residuals or None.
        alignment_method_codes: (k,) int index into
            :data:`~lbshape.shapespace.basis_choice.METHODS` of each example's
            alignment method (:attr:`alignment_methods`), or None.
        lb_cubature_elements, lb_cubature_weights: cubature of the LB displacement
            subspace (basis :meth:`lb_basis`), or None: (s,) shared by the examples or
            (k, s) one row per example (padded with element -1, weight 0);
            ``lb_cubature_errors`` (largest over the examples).
        example_names: (k,) labels.
        local: the local-example shape space (scenes with regions), or None.
        frame: reduced rigid-frame tensors of a free body, or None (fixed object).
        stage_seconds: wall time per stage (s) of the run that built the artifact.
        stage_peak_mb: largest resident memory (MB) of the process during each stage of
            that run; under MPI the sum of every rank's peak (the job's memory).
        stage_ranks: the number of MPI ranks each stage of that run was distributed
            over (1: rank 0 alone, or a serial run).
        from_cache: True when loaded from the cache.
    """

    scene: str
    key: str
    mesh: TetMesh
    material: Material
    fixed_vertices: np.ndarray
    U: np.ndarray
    omega2: np.ndarray
    cubature_elements: np.ndarray
    cubature_weights: np.ndarray
    cubature_errors: dict
    eigenvalues: np.ndarray | None = None
    eigenvectors: np.ndarray | None = None
    example_coefficients: np.ndarray | None = None
    projection: np.ndarray | None = None
    alignment_residuals: np.ndarray | None = None
    alignment_method_codes: np.ndarray | None = None
    lb_cubature_elements: np.ndarray | None = None
    lb_cubature_weights: np.ndarray | None = None
    lb_cubature_errors: dict = field(default_factory=dict)
    projection_clamped: np.ndarray | None = None
    target_table: TargetTable | None = None
    target_boundary: str = "free"
    example_names: tuple[str, ...] = ()
    local: LocalShapeSpace | None = None
    frame: FrameTensors | None = None
    stage_seconds: dict = field(default_factory=dict)
    stage_peak_mb: dict = field(default_factory=dict)
    stage_ranks: dict = field(default_factory=dict)
    from_cache: bool = False
    force_model: str = "cubature"
    force_coefficients: ForceCoefficients | None = None

    @property
    def r(self) -> int:
        return int(self.U.shape[1])

    @property
    def alignment_methods(self) -> list[str]:
        """(k,) each example's basis alignment method (``overlay`` or ``intrinsic``)."""
        codes = [] if self.alignment_method_codes is None else self.alignment_method_codes
        return [METHODS[int(c)] for c in codes]

    @property
    def has_examples(self) -> bool:
        """Global examples (the whole object's shape space)."""
        return self.example_coefficients is not None

    @property
    def has_local_examples(self) -> bool:
        """Local examples by region (:attr:`local`)."""
        return self.local is not None

    # --- shape-space maps in the elastic reduced coordinates (see the module docstring)
    @property
    def lb_to_reduced(self) -> np.ndarray:
        """(r, 3m) ``T``: maps LB displacement coefficients c to reduced coordinates q."""
        return self.projection

    @property
    def descriptor_matrix(self) -> np.ndarray:
        """(3m, r) ``D``: λ-weighted LB coefficients of ``U q`` are ``D q``."""
        return descriptor_matrix(self.eigenvalues, self.projection, self.material.density)

    @property
    def example_descriptors(self) -> np.ndarray:
        """(k, 3m) λ-weighted example displacement coefficients."""
        return example_descriptors(self.eigenvalues, self.example_coefficients)

    def example_rest_points(self, index: int, *, clamped: bool = False) -> np.ndarray:
        """(n, 3) example ``index`` reconstructed on the object's mesh (its rest shape);
        ``clamped``: with the clamped basis (no displacement at the fixed vertices)."""
        return self.mesh.points + self.target_eigenvectors(clamped) @ \
            self.example_coefficients[index]

    def example_energy_elements(self, *, clamped: bool = False) -> np.ndarray:
        """(e,) int64 the elements the example energies sum over
        (:func:`~lbshape.shapespace.example_shapes.energy_elements` of the rest shapes
        of :meth:`example_rest_points`)."""
        k = self.example_coefficients.shape[0]
        return energy_elements(self.mesh.points, self.mesh.tets, [
            self.example_rest_points(i, clamped=clamped) for i in range(k)])

    def target_eigenvectors(self, clamped: bool = False) -> np.ndarray:
        """(n, m) Φ, or Φ_F faded to zero at the fixed vertices when ``clamped``."""
        if not clamped or self.fixed_vertices.size == 0:
            return self.eigenvectors
        return clamped_eigenvectors(self.eigenvectors, self.fixed_vertices, self.mesh.points)

    def lb_basis(self, *, clamped: bool = False) -> np.ndarray:
        """(3n, 3m) dense ``L = Φ ⊗ I₃`` (node-major rows, column 3i+k); ``clamped``: L_F."""
        return block_basis(self.target_eigenvectors(clamped))

    def lb_to_reduced_for(self, *, clamped: bool) -> np.ndarray:
        """(r, 3m) the map of LB coefficients to reduced coordinates for L or L_F."""
        if clamped and self.projection_clamped is not None:
            return self.projection_clamped
        return self.lb_to_reduced

    # --- the stored form
    @classmethod
    def from_arrays(cls, scene: Scene, key: str, arrays: dict, meta: dict, *,
                    from_cache: bool = True) -> Precomputed:
        """The precompute stored as (arrays, meta) by :func:`artifact`."""
        mesh = TetMesh(np.asarray(arrays["points"]), np.asarray(arrays["tets"]),
                       *_groups_from_arrays(arrays))
        has_examples = "example_coefficients" in arrays
        return cls(
            scene=scene.name, key=key, mesh=mesh, material=scene.material,
            fixed_vertices=np.asarray(arrays["fixed"], dtype=np.int64),
            U=np.asarray(arrays["U"]), omega2=np.asarray(arrays["omega2"]),
            cubature_elements=np.asarray(arrays["cub_elements"], dtype=np.int64),
            cubature_weights=np.asarray(arrays["cub_weights"]),
            cubature_errors=meta.get("cubature_errors", {}),
            eigenvalues=arrays.get("eigenvalues"),
            eigenvectors=arrays.get("eigenvectors"),
            example_coefficients=arrays.get("example_coefficients") if has_examples else None,
            projection=arrays.get("projection") if has_examples else None,
            alignment_residuals=arrays.get("alignment_residuals") if has_examples else None,
            alignment_method_codes=arrays.get("alignment_methods") if has_examples else None,
            lb_cubature_elements=(np.asarray(arrays["lb_cub_elements"], dtype=np.int64)
                                  if has_examples else None),
            lb_cubature_weights=arrays.get("lb_cub_weights") if has_examples else None,
            lb_cubature_errors=({"train": float(arrays["lb_cub_errors"][0]),
                                 "holdout": float(arrays["lb_cub_errors"][1])}
                                if has_examples else {}),
            projection_clamped=arrays.get("projection_clamped") if has_examples else None,
            target_table=TargetTable.from_arrays(arrays) if has_examples else None,
            target_boundary=("clamped" if has_examples and int(np.asarray(
                arrays.get("target_clamped", [0]))[0]) else "free"),
            example_names=tuple(meta.get("example_names", ())),
            local=(LocalShapeSpace.from_arrays(meta["local_regions"], arrays,
                                               meta.get("local_representation_errors", {}))
                   if "local_regions" in meta else None),
            frame=(FrameTensors(**{name: (float(arrays[f"frame_{name}"]) if name == "mass"
                                          else np.asarray(arrays[f"frame_{name}"]))
                                   for name in FRAME_FIELDS})
                   if "frame_G" in arrays else None),
            stage_seconds=dict(meta.get("stage_seconds", {})),
            stage_peak_mb=dict(meta.get("stage_peak_mb", {})),
            stage_ranks=dict(meta.get("stage_ranks", {})),
            from_cache=from_cache,
            force_model="polynomial" if "poly_K" in arrays else "cubature",
            force_coefficients=(ForceCoefficients(np.asarray(arrays["poly_K"]),
                                                  np.asarray(arrays["poly_cubic"]),
                                                  np.asarray(arrays["poly_quartic"]))
                                if "poly_K" in arrays else None),
        )


def artifact(scene: Scene, *, mesh: TetMesh, fixed: np.ndarray, U: np.ndarray,
             omega2: np.ndarray, cubature: Cubature, polynomial: PolynomialForceModel | None,
             examples: GlobalExamples | None, local: LocalExamples | None,
             frame: FrameTensors | None, example_names: list[str],
             stage_ranks: dict[str, int]) -> tuple[dict, dict]:
    """The stages' results as the artifact's (arrays, meta) (read by
    :meth:`Precomputed.from_arrays`)."""
    arrays = {
        **_group_arrays(mesh),
        "points": mesh.points, "tets": mesh.tets, "fixed": fixed, "U": U,
        "omega2": omega2, "cub_elements": cubature.elements,
        "cub_weights": cubature.weights,
        **({} if polynomial is None else {
            "poly_K": polynomial.K, "poly_cubic": polynomial.pair_cubic,
            "poly_quartic": polynomial.pair_quartic}),
    }
    meta = {"scene": scene.name, "cubature_errors": {
        "train": cubature.train_error, "holdout": cubature.holdout_error,
        "tolerance": cubature.tol, "reached_tolerance": bool(cubature.reached_tol)},
        "stage_ranks": stage_ranks}
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
    return arrays, meta


def required_arrays(scene: Scene) -> tuple[str, ...]:
    """The arrays a cached artifact of ``scene`` must hold."""
    required = _REQUIRED + (_REQUIRED_EXAMPLES if scene.has_examples else ())
    if scene.has_local_examples:
        required = _REQUIRED + ("eigenvalues", "eigenvectors") \
            + LocalShapeSpace.required_arrays(len(scene.regions))
    if scene.is_free:
        required = required + _REQUIRED_FRAME
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
        "eigenvalues": examples.spectrum.eigenvalues,
        "eigenvectors": examples.spectrum.eigenvectors,
        "example_coefficients": examples.example_coefficients,
        "projection": examples.projection,
        "alignment_residuals": examples.alignment_residuals,
        "alignment_methods": np.asarray(examples.alignment_methods, dtype=np.int64),
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
