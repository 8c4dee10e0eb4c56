"""Local examples: regions of the object, each guided by its own examples (paper §5).

**Variant used: per-region eigenfunctions** (the paper's Figure 7 caption). Each
region R (a set of the object's tetrahedra) is a mesh of its own; its m smallest
non-zero LB eigenpairs ``(λ_R, Φ_R)`` (Φ_R: (n_R, m), orthonormal in the region's
volume mass ``M_R``) describe the region's displacement ``u_R`` (its vertices'
rows of u) by the coefficients ``c_R = Φ_Rᵀ M_R u_R`` (m, 3); the descriptor is
``λ_R ⊙ c_R`` as for the whole object. The paper's text instead projects the
region's displacement, set to zero outside the region, on the *whole object's*
eigenfunctions. Both are measured at precompute
(:attr:`LocalShapeSpace.representation_errors`): the relative M_R-error of
reconstructing a region's own pose from its m coefficients. On the cross (m = 10)
the whole-object basis has about two functions per arm and none that varies
across an arm's section, so it cannot hold an arm's twist and smears a field that
is zero outside the arm over its neighbours; the per-region basis spends all m
functions on the region. That is the reason for the choice (numbers in
``docs/architecture.md``).

**Examples of a region.** Example k guiding region R is the example mesh's part
selected by R (the same physical group, or the expression evaluated on the example
mesh in its own coordinates), with k's pose applied to *that part*: the pose's
bar is the region (its extent along the pose axis, its anchor end), so "twist the
left arm" is ``pose = "twist", axis = "x"`` on a region that is the left arm. A
posed mesh file is cut the same way on its *rest* mesh (its ``rest`` file, or the
object for a posed copy of the object), and the part's posed positions are the
file's positions of the same vertices (:func:`lbshape.pipeline.meshes.example_meshes`
gives every example's rest and posed meshes, whole or by region). The part is
brought into R's shape space with the global machinery
(:func:`lbshape.shapespace.projections.embed_example`: frame and basis alignment
against R's own spectrum; landmarks are not used for regions).

**Forces.** Region R pulls only its own elements: in full space
``f_R = k_ex M^(R) (u*_R − u)``, M^(R) the elastic mass assembled over R's
tetrahedra. The target is the region's interpolated example shape ``L_R c*_R``
(``L_R = Φ_R ⊗ I₃``, E_R places region vertex rows into the object's) **attached
where the region is attached**: ``u*_R = E_R (L_R c*_R + Q_R g)`` with Q_R
(3n_R, 6) the region's translations and infinitesimal rotations and g the rigid
motion that best fits ``u − L_R c*_R`` (lumped-mass least squares) on the region's
anchor — its vertices shared with the rest of the object, and its fixed vertices.
Region eigenfunctions exclude the constant, so a region's coefficients hold no
place of their own; anchoring puts the example where the region meets its
neighbours and supports (a limb curls about its hip, an arm twists from the
centre it is attached to, a beam through a fixed centre bends about that centre)
instead of pulling the region's mean to rest or fighting the support. With
``F_R`` (6, |anchor rows|) the fit, ``g = F_R (u − L_R c*_R)_anchor``; the forces
add up: ``f = k_ex (Σ_R M^(R) E_R [(I − Q_R F_R S_R) L_R c*_R + Q_R F_R S_R u_R] − S u)``
with ``S = Σ_R M^(R)``. In reduced coordinates q (``Uᵀ M U = I``):
``k_ex (Σ_R T'_R c*_R + Π q − S_q q)`` with the precomputed
``T'_R = T_R − (Uᵀ M^(R) Q_R)(F_R L_R,anchor)`` (r, 3m), ``T_R = Uᵀ M^(R) E_R L_R``,
``Π = Σ_R (Uᵀ M^(R) Q_R)(F_R U_anchor)`` (r, r) and ``S_q = Uᵀ S U`` (r, r); the
region descriptor of the current shape is ``D_R q``, ``D_R = diag(λ_R ⊗ 1₃) T_Rᵀ / ρ``
(3m, r). Like the target, the anchor fit uses the state at the start of the step.
The runtime step touches only these small matrices. ``free_rigid=False`` drops
the anchoring (``u*_R = E_R L_R c*_R``): the region's mean is then pulled to rest,
as the global path does for the whole object.

**A region without neighbours is not anchored.** The anchor attaches a region's
target to the rest of the object; a region covering every tetrahedron has no rest
of the object to attach to, so its anchor is empty (its fixed vertices alone do not
make one) and its target is placed as the global path places the examples: one
region covering the object with all the examples *is* the global path, with the
default settings. Anchoring it on its fixed vertices would be another model (the
target moved rigidly to fit the support), not the paper's §4 (numbers in
``docs/architecture.md``).

**Rules.** Regions are sets of tetrahedra: a physical group must be a volume
group; an expression selects the tetrahedra whose centroid satisfies it. Regions
must not share a tetrahedron (one-line error naming both). Tetrahedra in no region
feel no example force (``S`` then differs from M: the spring only acts on covered
elements). Each region must be one connected piece with more than m + 1 vertices.
With one region covering every tetrahedron the whole path equals the global one
(no anchor, see above). Messages number the examples from 0, as the scene's
``examples`` lists do.

**Targets.** Per region, weights by paper eq. 5 on the region's descriptors and a
target ``c*_R = argmin Σ_k w_k E_k(c − c_k)`` with E_k the StVK energy of example
k's region shape ``X_R + Φ_R c_k`` over R's tetrahedra, evaluated exactly as a
quartic polynomial (the ``lb-exact`` route, O((3m)⁴) per evaluation); for other
materials, or the ``euclidean`` baseline, the energy is summed over R's elements.
A region's target depends only on its few weights, so the precompute tabulates it
over the region's weight simplex like the global target
(:func:`region_target_table`, :mod:`lbshape.shapespace.target_table`: Hermite in
w₁ for two examples, cubic triangles for three, each checked against the exact
target at held-out weights as a share of the region's example separation). The
reduced method's step (:meth:`LocalExampleDriver.weights_into`,
:meth:`~LocalExampleDriver.target_from_weights_into`) then evaluates, per region,
the precomputed eq. 5 weights and one table lookup already mapped to the pull
``T'_R c*_R`` (r,), into preallocated arrays: no Newton, no n-sized array, no
allocation. A region without a table (more than three examples, or a refused
table) solves its target by Newton at run time.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.materials import Material
from lbshape.elastic.polynomial_energy import StVKPolynomialEnergy
from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.geometry.regions import evaluate_region
from lbshape.shapespace.basis_choice import METHODS
from lbshape.shapespace.euclidean_energy import EuclideanExampleEnergy
from lbshape.shapespace.example_driver import ExampleDriver, TargetInfo
from lbshape.shapespace.example_shapes import energy_elements, example_rest_shapes
from lbshape.shapespace.example_targets import tabulate_examples
from lbshape.shapespace.interpolation import TargetSolver, simplex_weights
from lbshape.shapespace.projections import (
    block_basis,
    descriptor_matrix,
    embed_example,
    reduced_projection,
)
from lbshape.shapespace.target_table import DEFAULT_TOLERANCE, TableSolver, TargetTable
from lbshape.spectral.spectrum import lb_spectrum

log = logging.getLogger(__name__)

#: target energies of the local examples: exact polynomial (StVK) or all region elements
LOCAL_ROUTES = ("lb-exact", "euclidean")
#: largest relative RMS residual of a region part's frame alignment. The residual is a
#: vertex-to-vertex distance, and an object's region often has only tens of vertices
#: (a teddy's leg: ~50 against the example part's ~800), so a matching part measures
#: ~0.25 by resolution alone; the basis alignment residual still guards the match.
REGION_FRAME_RMS = 0.35
#: an example whose RMS displacement on a region is below this share of the region's
#: extent is at rest to round-off (warned about: a scene does not mean that)
AT_REST = 1e-9


# ------------------------------------------------------------------ regions
def region_cells(mesh: TetMesh, *, group: str | None = None, region: str | None = None,
                 what: str = "region") -> np.ndarray:
    """(t_R,) sorted int64 tetrahedra of ``mesh`` in a region.

    Args:
        mesh: the mesh.
        group: a volume physical group of the mesh, or
        region: a safe expression in x, y, z (m) evaluated at tetrahedron centroids.
        what: label for error messages.

    Raises:
        LbshapeError: neither or both given, an unknown (or non-volume) group, or an
            empty selection.
    """
    if (group is None) == (region is None):
        raise LbshapeError(f"{what}: give exactly one of a group or an expression")
    if group is not None:
        if group not in mesh.cell_groups:
            raise LbshapeError(
                f"{what}: mesh has no volume group '{group}' (volume groups: "
                f"{', '.join(sorted(mesh.cell_groups)) or 'none'})")
        cells = np.unique(np.asarray(mesh.cell_groups[group], dtype=np.int64))
    else:
        centroids = mesh.points[mesh.tets].mean(axis=1)
        cells = np.flatnonzero(evaluate_region(region, centroids)).astype(np.int64)
    if cells.size == 0:
        raise LbshapeError(f"{what} selects no tetrahedron of the mesh")
    return cells


def check_partition(names: Sequence[str], cells: Sequence[np.ndarray], n_tets: int) -> np.ndarray:
    """(n_tets,) bool: covered tetrahedra; one-line error if two regions overlap."""
    owner = np.full(n_tets, -1, dtype=np.int64)
    for index, (name, selected) in enumerate(zip(names, cells, strict=True)):
        taken = owner[selected]
        if (taken >= 0).any():
            other = names[int(taken[taken >= 0][0])]
            count = int((taken >= 0).sum())
            raise LbshapeError(
                f"local-example regions '{other}' and '{name}' share {count} tetrahedra; "
                "regions must be disjoint")
        owner[selected] = index
    return owner >= 0


def submesh(mesh: TetMesh, cells: np.ndarray, *,
            what: str = "region") -> tuple[TetMesh, np.ndarray]:
    """The mesh of some tetrahedra and its vertices' indices in ``mesh``.

    Returns:
        ``(sub, vertices)``: the sub-mesh (vertices in increasing original order,
        no groups) and (n_R,) int64 original vertex indices.

    Raises:
        LbshapeError: the tetrahedra form more than one connected piece.
    """
    tets = np.asarray(mesh.tets, dtype=np.int64)[cells]
    vertices = np.unique(tets)
    local = np.searchsorted(vertices, tets)
    n = vertices.size
    rows = np.repeat(local, 4, axis=1).ravel()
    cols = np.tile(local, (1, 4)).ravel()
    graph = sp.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
    pieces, _ = connected_components(graph, directed=False)
    if pieces != 1:
        raise LbshapeError(f"{what} is not connected ({pieces} pieces); split it into regions")
    return TetMesh(np.asarray(mesh.points)[vertices], local), vertices


def rigid_fields(points: np.ndarray, mass: sp.spmatrix) -> np.ndarray:
    """(3n, 6) node-major translations and infinitesimal rotations about the mass
    centre of ``points`` (n, 3), orthonormal in ``mass`` (3n, 3n)."""
    points = np.asarray(points, dtype=float)
    n = points.shape[0]
    weights = np.asarray(mass[0::3, 0::3].sum(axis=1)).ravel()
    x = points - weights @ points / weights.sum()
    R = np.zeros((n, 3, 6))
    R[:, :, :3] = np.eye(3)
    for axis in range(3):  # e_axis × x
        R[:, :, 3 + axis] = np.cross(np.eye(3)[axis], x)
    R = R.reshape(3 * n, 6)
    gram = R.T @ (mass @ R)
    return np.linalg.solve(np.linalg.cholesky(gram), R.T).T


def region_anchor(mesh: TetMesh, cells: np.ndarray, vertices: np.ndarray,
                  fixed_vertices: np.ndarray | None = None) -> np.ndarray:
    """(n_R,) bool: where a region is attached to the rest of the object: its vertices
    shared with tetrahedra outside it, and its fixed vertices. All False for a region
    covering every tetrahedron (no neighbour to attach to: its target is placed as
    the global path's, see the module docstring)."""
    outside = np.ones(mesh.n_tets, dtype=bool)
    outside[cells] = False
    anchor = np.isin(vertices, np.asarray(mesh.tets)[outside])
    if fixed_vertices is not None and anchor.any():
        anchor |= np.isin(vertices, fixed_vertices)
    return anchor


def anchor_fit(points: np.ndarray, mass: sp.spmatrix, anchor: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rigid fit on a region's anchor.

    Args:
        points: (n_R, 3) region vertices.
        mass: (3n_R, 3n_R) the region's mass.
        anchor: (n_R,) bool anchor vertices; none: no fit (g = 0, an unanchored region).

    Returns:
        ``(Q, F, rows)``: Q (3n_R, 6) mass-orthonormal rigid fields, rows the
        node-major anchor rows and F (6, rows.size) with ``g = F v[rows]`` the
        lumped-mass least-squares rigid fit of a field v (3n_R,) on the anchor
        (``Q F v[rows] = v`` for a rigid v; a degenerate anchor, e.g. collinear,
        fits with the minimum-norm g; F is (6, 0) without anchor).
    """
    Q = rigid_fields(points, mass)
    anchor = np.asarray(anchor, dtype=bool)
    rows = (3 * np.flatnonzero(anchor)[:, None] + np.arange(3)).ravel()
    if rows.size == 0:
        return Q, np.zeros((6, 0)), rows
    w = np.asarray(mass.sum(axis=1)).ravel()[rows]
    QA = Q[rows]
    F = np.linalg.pinv((QA * w[:, None]).T @ QA, rcond=1e-10) @ (QA * w[:, None]).T
    return Q, F, rows


# ------------------------------------------------------------ shape space
@dataclass(frozen=True)
class RegionSpace:
    """One region's share of the local shape space (small arrays except ``cells``,
    ``vertices`` and ``eigenvectors``, used at set-up and for output only).

    Attributes:
        name: region name.
        cells: (t_R,) object tetrahedra of the region.
        vertices: (n_R,) object vertices of the region (increasing).
        examples: (k_R,) indices of its examples in the scene's example list.
        eigenvalues: (m,) λ_R in 1/m².
        eigenvectors: (n_R, m) Φ_R, M_R-orthonormal (M_R the region's volume mass, m³).
        example_coefficients: (k_R, m, 3) example displacement coefficients (m^(5/2)).
        alignment_residuals: (k_R,) basis alignment residuals.
        to_reduced: (r, 3m) ``T_R = Uᵀ M^(R) E_R L_R`` (no anchoring).
        rigid_reduced: (r, 6) ``Uᵀ M^(R) E_R Q_R``.
        rigid_coefficients: (3m, 6) ``(F_R L_R,anchor)ᵀ``: the anchor fit of ``L_R c``.
        anchor_reduced: (r, 6) ``(F_R U_anchor)ᵀ``: the anchor fit of ``U q``.
        anchor: (n_R,) bool, the anchor vertices (:func:`region_anchor`).
        rigid_lb: (3m, 6) ``L_Rᵀ M^(R) Q_R``: LB coefficients (times ρ) of the rigid fields.
        table: the region's exact target tabulated over its weight simplex, in the
            coefficients c (3m,) (:func:`region_target_table`), or None (more than three
            examples, a refused table, or not built).
        alignment_methods: (k_R,) int index into
            :data:`~lbshape.shapespace.basis_choice.METHODS` of each example's alignment
            method (:attr:`methods` gives the names).
    """

    name: str
    cells: np.ndarray
    vertices: np.ndarray
    examples: np.ndarray
    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    example_coefficients: np.ndarray
    alignment_residuals: np.ndarray
    to_reduced: np.ndarray
    rigid_reduced: np.ndarray
    rigid_coefficients: np.ndarray
    anchor_reduced: np.ndarray
    anchor: np.ndarray
    rigid_lb: np.ndarray
    table: TargetTable | None = None
    alignment_methods: np.ndarray = dataclasses.field(
        default_factory=lambda: np.zeros(0, dtype=np.int64))

    @property
    def methods(self) -> list[str]:
        """(k_R,) each example's alignment method (``overlay`` or ``intrinsic``)."""
        return [METHODS[int(c)] for c in self.alignment_methods]

    @property
    def m(self) -> int:
        return int(self.eigenvalues.size)

    def pull_matrix(self, *, free_rigid: bool = True) -> np.ndarray:
        """(r, 3m) ``T'_R`` (``T_R`` with ``free_rigid=False``): target coefficients to pull."""
        if not free_rigid:
            return self.to_reduced
        return self.to_reduced - self.rigid_reduced @ self.rigid_coefficients.T

    def rigid_pull(self) -> np.ndarray:
        """(r, r) ``Π_R``: reduced coordinates q to the pull of the anchor's rigid fit."""
        return self.rigid_reduced @ self.anchor_reduced.T

    def descriptor_matrix(self, density: float, *, free_rigid: bool = True) -> np.ndarray:
        """(3m, r) ``D_R``: the region descriptor of ``U q`` is ``D_R q`` — of the
        shape relative to its anchor's rigid fit (``free_rigid``), else as it is."""
        T = self.to_reduced.T
        if free_rigid:
            T = T - self.rigid_lb @ self.anchor_reduced.T
        return descriptor_matrix(self.eigenvalues, T.T, density)

    def example_descriptors(self, density: float, *, free_rigid: bool = True) -> np.ndarray:
        """(k_R, 3m) λ-weighted example coefficients (relative to the anchor's rigid
        fit with ``free_rigid``), flattened row-major."""
        k = self.example_coefficients.shape[0]
        c = self.example_coefficients.reshape(k, -1)
        if free_rigid:
            c = c - (c @ self.rigid_coefficients) @ self.rigid_lb.T / density
        return c * np.repeat(self.eigenvalues, 3)

    def submesh(self, mesh: TetMesh) -> TetMesh:
        """The region's own mesh (vertex order of :attr:`vertices`)."""
        local = np.searchsorted(self.vertices, np.asarray(mesh.tets)[self.cells])
        return TetMesh(np.asarray(mesh.points)[self.vertices], local)

    def example_energy_shapes(self, mesh: TetMesh) -> tuple[list[np.ndarray], np.ndarray]:
        """The examples' rest shapes (n_R, 3) on the region's mesh and the (e, 4)
        tetrahedra (region vertex numbering) their energies sum over
        (:func:`~lbshape.shapespace.example_shapes.energy_elements`)."""
        sub = self.submesh(mesh)
        rests = example_rest_shapes(sub.points, self.eigenvectors, self.example_coefficients)
        return rests, sub.tets[energy_elements(sub.points, sub.tets, rests)]

    def displacement(self, coefficients: np.ndarray) -> np.ndarray:
        """(n_R, 3) region displacement ``Φ_R c`` of coefficients (3m,) or (m, 3)."""
        return self.eigenvectors @ np.asarray(coefficients, dtype=float).reshape(self.m, 3)


@dataclass(frozen=True)
class LocalShapeSpace:
    """The regions, the spring matrix and what was measured at precompute.

    Attributes:
        regions: one :class:`RegionSpace` per scene region, in scene order.
        spring: (r, r) ``S_q = Uᵀ (Σ_R M^(R)) U`` (identity when every tetrahedron
            is covered).
        covered: fraction of the object's volume inside some region.
        representation_errors: region name -> {"per-region": e_B, "whole-object":
            e_A}: relative M_R-norm errors of reconstructing the region's posed
            displacement (the first example's pose applied to the object's own
            region) from m coefficients in each variant; no entry where that pose is
            not defined on the object's mesh (a posed file with its own rest).
    """

    regions: tuple[RegionSpace, ...]
    spring: np.ndarray
    covered: float
    representation_errors: dict

    @property
    def rigid_pull(self) -> np.ndarray:
        """(r, r) ``Π = Σ_R Π_R``."""
        return sum(reg.rigid_pull() for reg in self.regions)

    def projected(self, mesh: TetMesh, material: Material, U: np.ndarray) -> LocalShapeSpace:
        """The same regions with their maps to the reduced coordinates of U (3n, r)
        (``to_reduced``, ``rigid_reduced``, ``anchor_reduced``) and the spring
        ``S_q = Uᵀ (Σ_R M^(R)) U`` (r, r)."""
        regions, spring = [], np.zeros((U.shape[1],) * 2)
        for region in self.regions:
            region, share = _region_maps(mesh, material, region, U)
            regions.append(region)
            spring += share
        return dataclasses.replace(self, regions=tuple(regions),
                                   spring=0.5 * (spring + spring.T))

    def arrays(self) -> dict[str, np.ndarray]:
        """Flat arrays for the precompute artifact (see :func:`from_arrays`)."""
        out = {"local_spring": self.spring, "local_covered": np.array(self.covered)}
        for i, reg in enumerate(self.regions):
            for key in ("cells", "vertices", "examples", "eigenvalues", "eigenvectors",
                        "example_coefficients", "alignment_residuals", "alignment_methods",
                        "to_reduced", "rigid_reduced", "rigid_coefficients",
                        "anchor_reduced", "anchor", "rigid_lb"):
                out[f"local{i}_{key}"] = getattr(reg, key)
            if reg.table is not None:
                out.update(reg.table.to_arrays(prefix=f"local{i}_table_"))
        return out

    @classmethod
    def from_arrays(cls, names: Sequence[str], arrays: dict, errors: dict) -> LocalShapeSpace:
        """Inverse of :meth:`arrays` (``names``: region names in order)."""
        regions = []
        for i, name in enumerate(names):
            get = lambda key, i=i: np.asarray(arrays[f"local{i}_{key}"])  # noqa: E731
            regions.append(RegionSpace(
                name=name, cells=get("cells").astype(np.int64),
                vertices=get("vertices").astype(np.int64),
                examples=get("examples").astype(np.int64), eigenvalues=get("eigenvalues"),
                eigenvectors=get("eigenvectors"),
                example_coefficients=get("example_coefficients"),
                alignment_residuals=get("alignment_residuals"), to_reduced=get("to_reduced"),
                rigid_reduced=get("rigid_reduced"),
                rigid_coefficients=get("rigid_coefficients"),
                anchor_reduced=get("anchor_reduced"), anchor=get("anchor").astype(bool),
                rigid_lb=get("rigid_lb"),
                table=TargetTable.from_arrays(arrays, prefix=f"local{i}_table_"),
                alignment_methods=get("alignment_methods").astype(np.int64)))
        return cls(tuple(regions), np.asarray(arrays["local_spring"]),
                   float(arrays["local_covered"]), dict(errors))

    @staticmethod
    def required_arrays(n_regions: int) -> tuple[str, ...]:
        keys = ["local_spring", "local_covered"]
        for i in range(n_regions):
            keys += [f"local{i}_{k}" for k in ("cells", "vertices", "examples", "eigenvalues",
                                                "eigenvectors", "example_coefficients",
                                                "alignment_residuals", "alignment_methods",
                                                "to_reduced", "rigid_reduced",
                                                "rigid_coefficients",
                                                "anchor_reduced", "anchor", "rigid_lb")]
        return tuple(keys)


@dataclass(frozen=True)
class RegionSpec:
    """What the precompute needs of a scene region.

    Attributes:
        name: region name.
        group: volume physical group, or None.
        region: expression, or None.
        examples: indices of its examples.
    """

    name: str
    group: str | None
    region: str | None
    examples: tuple[int, ...]


def build_local_space(
    mesh: TetMesh,
    material: Material,
    U: np.ndarray,
    specs: Sequence[RegionSpec],
    example_part: Callable[[int, RegionSpec], tuple[TetMesh, np.ndarray]],
    *,
    m: int,
    spectrum: Callable | None = None,
    embed: Callable | None = None,
    object_pose: Callable[[int, TetMesh], np.ndarray] | None = None,
    global_eigenvectors: np.ndarray | None = None,
    fixed_vertices: np.ndarray | None = None,
    tabulate: bool = True,
) -> LocalShapeSpace:
    """Region spectra, example coefficients per region and the small matrices.

    Args:
        mesh: the object's rest mesh (n vertices).
        material: its material (density ρ for the elastic mass).
        U: (3n, r) basis with ``Uᵀ M U = I`` (M the elastic mass), or None: the regions'
            maps to reduced coordinates and the spring are left empty, for
            :meth:`LocalShapeSpace.projected` once the basis is final.
        specs: the regions.
        example_part: ``(k, spec) -> (rest part, posed part points)``: example k's
            part selected by the region on the example's rest mesh, at rest (a
            TetMesh) and posed ((n_e, 3) m).
        m: eigenpairs per region.
        spectrum: ``(mesh, m) -> LBSpectrum`` (default
            :func:`lbshape.spectral.spectrum.lb_spectrum`).
        embed: :func:`lbshape.shapespace.projections.embed_example` or a stand-in.
        object_pose: optional ``(k, region mesh, region vertices (n_R,) in the
            object) -> posed points (n_R, 3)``: example k's pose applied to the
            object's own region, for the representation measurement (skipped
            without it, or for a region where it raises :class:`LbshapeError`).
        global_eigenvectors: (n, m) the whole object's eigenvectors (M-orthonormal),
            for the whole-object variant of that measurement.
        fixed_vertices: the object's fixed vertices (part of a region's anchor).
        tabulate: tabulate each region's exact target over its weights
            (:func:`region_target_table`).

    Raises:
        LbshapeError: overlapping, disconnected or too small regions, or an example
            that cannot be embedded (message names region and example).
    """
    spectrum = spectrum or lb_spectrum
    if embed is None:
        def embed(*args):
            return embed_example(*args, max_frame_rms=REGION_FRAME_RMS)
    names = [s.name for s in specs]
    cells = [region_cells(mesh, group=s.group, region=s.region, what=f"region '{s.name}'")
             for s in specs]
    covered = check_partition(names, cells, mesh.n_tets)
    volumes = np.abs(mesh.signed_volumes())
    spring = None if U is None else np.zeros((U.shape[1],) * 2)
    regions, errors = [], {}
    for spec, selected in zip(specs, cells, strict=True):
        built = _build_region(mesh, material, U, spec, selected, example_part, m=m,
                              spectrum=spectrum, embed=embed, fixed_vertices=fixed_vertices)
        if U is not None:
            spring += built.spring
        if object_pose is not None:
            measured = _measure_representation(built, spec, object_pose, global_eigenvectors)
            if measured is not None:
                errors[spec.name] = measured
        region = built.region
        if tabulate:
            region = dataclasses.replace(region, table=region_target_table(mesh, material,
                                                                           region))
        regions.append(region)
    covered_fraction = float(volumes[covered].sum() / volumes.sum())
    if covered_fraction < 1.0:
        log.info("local examples: %.1f %% of the volume is in no region (no example force "
                 "there)", 100 * (1 - covered_fraction))
    if U is None:
        spring = np.zeros((0, 0))
    return LocalShapeSpace(tuple(regions), 0.5 * (spring + spring.T), covered_fraction, errors)


class _BuiltRegion(NamedTuple):
    """One region as :func:`build_local_space` assembles it."""

    region: RegionSpace  #: its shape space (no table yet)
    spring: np.ndarray | None  #: (r, r) its share ``U_Rᵀ M^(R) U_R`` of the spring matrix
    mesh: TetMesh  #: its own mesh
    volume_mass: sp.spmatrix  #: (n_R, n_R) M_R in m³


def _build_region(mesh: TetMesh, material: Material, U: np.ndarray | None, spec: RegionSpec,
                  selected: np.ndarray, example_part, *, m: int, spectrum, embed,
                  fixed_vertices: np.ndarray | None) -> _BuiltRegion:
    """A region's spectrum, its examples' coefficients and, with U, its small matrices
    (see the module docstring and :class:`RegionSpace`)."""
    label = f"region '{spec.name}'"
    rho = float(material.density)
    sub, vertices = submesh(mesh, selected, what=label)
    if sub.n_vertices <= m + 1:
        raise LbshapeError(f"{label}: m={m} needs more than {m + 1} vertices, it has "
                           f"{sub.n_vertices}")
    spec_R = spectrum(sub, m)
    mass_R = mass_matrix(sub, rho)  # (3n_R, 3n_R) kg
    volume_mass = mass_R[0::3, 0::3] / rho  # (n_R, n_R) m³
    anchor = region_anchor(mesh, selected, vertices, fixed_vertices)
    Q, F, anchor_rows = anchor_fit(sub.points, mass_R, anchor)
    L_R = block_basis(spec_R.eigenvectors)
    coefficients, residuals, methods = _region_examples(label, spec, sub, spec_R, example_part,
                                                        embed)
    region = RegionSpace(
        name=spec.name, cells=selected, vertices=vertices,
        examples=np.asarray(spec.examples, dtype=np.int64),
        eigenvalues=np.asarray(spec_R.eigenvalues, dtype=float),
        eigenvectors=np.asarray(spec_R.eigenvectors, dtype=float),
        example_coefficients=np.asarray(coefficients, dtype=float).reshape(-1, m, 3),
        alignment_residuals=np.asarray(residuals, dtype=float),
        alignment_methods=np.array([METHODS.index(k) for k in methods], dtype=np.int64),
        to_reduced=np.zeros((0, 3 * m)), rigid_reduced=np.zeros((0, 6)),
        rigid_coefficients=(F @ L_R[anchor_rows]).T,
        anchor_reduced=np.zeros((0, 6)), anchor=anchor,
        rigid_lb=L_R.T @ (mass_R @ Q))
    spring = None
    if U is not None:
        region, spring = _region_maps(mesh, material, region, U)
    return _BuiltRegion(region, spring, sub, volume_mass)


def _region_maps(mesh: TetMesh, material: Material, region: RegionSpace,
                 U: np.ndarray) -> tuple[RegionSpace, np.ndarray]:
    """The region with its maps to the reduced coordinates of U (3n, r) (``to_reduced``,
    ``rigid_reduced``, ``anchor_reduced``) and its share ``U_Rᵀ M^(R) U_R`` (r, r) of
    the spring matrix."""
    rho = float(material.density)
    sub = region.submesh(mesh)
    rows = (3 * region.vertices[:, None] + np.arange(3)).ravel()
    U_R = np.asarray(U, dtype=float)[rows]
    mass_R = mass_matrix(sub, rho)
    Q, F, anchor_rows = anchor_fit(sub.points, mass_R, region.anchor)
    region = dataclasses.replace(
        region,
        to_reduced=reduced_projection(U_R, region.eigenvectors, mass_R[0::3, 0::3] / rho, rho),
        rigid_reduced=U_R.T @ (mass_R @ Q), anchor_reduced=(F @ U_R[anchor_rows]).T)
    return region, U_R.T @ (mass_R @ U_R)


def _region_examples(label: str, spec: RegionSpec, sub: TetMesh, spectrum, example_part,
                     embed) -> tuple[list[np.ndarray], list[float], list[str]]:
    """The region's examples embedded in its shape space: (coefficients (m, 3) per
    example, alignment residuals, alignment methods)."""
    coefficients, residuals, methods = [], [], []
    for k in spec.examples:
        what = f"{label}, example {k}"
        rest_part, posed_points = example_part(k, spec)
        try:
            embedded = embed(sub, spectrum, rest_part, [posed_points])
        except LbshapeError as exc:
            raise LbshapeError(f"{what}: {exc}") from None
        coefficients.append(embedded.coefficients[0])
        residuals.append(embedded.alignment.residual)
        methods.append(embedded.alignment.method)
        log.info("%s: alignment residual %.3g (%s)", what, embedded.alignment.residual,
                 embedded.alignment.method)
        _warn_at_rest(what, embedded.coefficients[0], sub)
    return coefficients, residuals, methods


def _measure_representation(built: _BuiltRegion, spec: RegionSpec, object_pose,
                            global_eigenvectors: np.ndarray | None) -> dict | None:
    """The two variants' representation errors of the region's first example pose
    applied to the object's own region (:func:`_representation_errors`), or None when
    that pose does not fit the object's mesh."""
    region = built.region
    try:  # a pose may not fit the coarser object mesh: then nothing is measured
        posed = object_pose(spec.examples[0], built.mesh, region.vertices)
    except LbshapeError as exc:
        log.info("region '%s': representation not measured (%s)", spec.name, exc)
        return None
    return _representation_errors(built.mesh, region.vertices, built.volume_mass,
                                  region.eigenvectors, posed, global_eigenvectors)


def _warn_at_rest(what: str, coefficients: np.ndarray, region: TetMesh) -> None:
    """Log a warning when an example's region shape is its rest shape to round-off:
    its RMS displacement ``‖c‖ / √V_R`` (m; Φ_R is M_R-orthonormal, c (m, 3)) below
    :data:`AT_REST` of the region's extent."""
    rms = float(np.linalg.norm(coefficients)) / np.sqrt(region.volume())
    extent = float(np.ptp(region.points, axis=0).max())
    if rms <= AT_REST * extent:
        log.warning("%s is the region at rest (RMS displacement %.1e m): it only pulls the "
                    "region back to rest", what, rms)


def _representation_errors(sub, vertices, volume_mass, phi_R, posed, phi_global) -> dict:
    """Relative M_R errors of the two variants' m-term reconstructions of a region
    pose's displacement without its rigid part (which neither variant pulls)."""
    u = np.asarray(posed) - sub.points  # (n_R, 3)
    mass3 = sp.kron(volume_mass, sp.identity(3)).tocsr()
    Q = rigid_fields(sub.points, mass3)
    flat = u.reshape(-1)
    u = (flat - Q @ (Q.T @ (mass3 @ flat))).reshape(-1, 3)

    def norm(field):
        return float(np.sqrt(np.einsum("ik,ik->", field, volume_mass @ field)))

    size = norm(u)
    if size == 0.0:
        return {"per-region": 0.0, "whole-object": 0.0}
    per_region = phi_R @ (phi_R.T @ (volume_mass @ u))
    out = {"per-region": norm(u - per_region) / size}
    if phi_global is not None:
        phi = np.asarray(phi_global)
        # zero outside the region, projected on the whole object's eigenfunctions
        coefficients = phi[vertices].T @ (volume_mass @ u)
        out["whole-object"] = norm(u - phi[vertices] @ coefficients) / size
    return out


# ------------------------------------------------------------------ runtime
def region_energy_models(mesh: TetMesh, material: Material, region: RegionSpace, *,
                         route: str) -> list:
    """One target energy model per example of a region (see the module docstring)."""
    if route not in LOCAL_ROUTES:
        raise LbshapeError(f"local examples support the routes {', '.join(LOCAL_ROUTES)}, "
                           f"got {route!r}")
    basis = block_basis(region.eigenvectors)
    energy = StVKPolynomialEnergy if route == "lb-exact" else EuclideanExampleEnergy
    rests, tets = region.example_energy_shapes(mesh)
    return [energy(x, tets, material, basis) for x in rests]


def local_route(route: str, material: Material) -> str:
    """The local target route for a global route name and a material."""
    if route == "euclidean" or material.model != "stvk":
        return "euclidean"
    return "lb-exact"


def region_target_table(mesh: TetMesh, material: Material, region: RegionSpace, *,
                        tolerance: float = DEFAULT_TOLERANCE) -> TargetTable | None:
    """The region's exact target ``c*_R(w)`` (3m,) tabulated over its weight simplex.

    :func:`lbshape.shapespace.example_targets.tabulate_examples` on the region's mesh,
    eigenvectors Φ_R and example coefficients: the exact example energies (the
    quartic polynomial for StVK, else all of R's elements), the table and its check
    at held-out weights, the error measured in ``‖L_R Δc‖_{M_R}`` as a share of the
    region's example separation (``tolerance``, refining the grid until it holds).

    Returns:
        The checked table, or None for more than three examples or a refused table
        (logged; the target is then solved at run time).
    """
    started = time.perf_counter()
    sub = region.submesh(mesh)
    volume_mass = mass_matrix(sub, 1.0)[0::3, 0::3]  # M_R (n_R, n_R), m³
    table = tabulate_examples(sub.points, sub.tets, material, region.eigenvectors,
                              region.example_coefficients, mass=volume_mass,
                              tolerance=tolerance).table
    if table is not None and table.check is not None:
        log.info("region %s: target table (%s, N=%d), error max %.2g / median %.2g of the "
                 "example separation at %d held-out weights, %.2f s", region.name, table.kind,
                 table.intervals, table.check.max_error, table.check.median_error,
                 table.check.checks, time.perf_counter() - started)
    return table


class LocalExampleDriver:
    """Per-region :class:`ExampleDriver` s whose pulls add up (drop-in for the global one).

    Args:
        drivers: one driver per region; region R's ``to_reduced`` is ``T'_R``.
        spring: (r, r) ``S_q`` (see the module docstring).
        names: region names.
        rigid_pull: (r, r) ``Π`` added to the pull (``Π q``), or None.

    Attributes:
        spring: the spring matrix the dynamics use instead of the identity.
        last: per-region :class:`TargetInfo` of the last :meth:`target` call.

    The run-time step calls :meth:`weights_into` then :meth:`target_from_weights_into`:
    per region the precomputed weights and the target written into preallocated
    arrays (one table lookup per region when tabulated), nothing allocated.
    """

    def __init__(self, drivers: Sequence[ExampleDriver], spring: np.ndarray,
                 names: Sequence[str], *, rigid_pull: np.ndarray | None = None):
        if not drivers:
            raise LbshapeError("local examples need at least one region")
        self.drivers = list(drivers)
        self.spring = np.asarray(spring, dtype=float)
        self.names = tuple(names)
        r = self.drivers[0].D.shape[1]
        if self.spring.shape != (r, r):
            raise LbshapeError(f"spring must be ({r}, {r}), got {self.spring.shape}")
        self.rigid_pull = (None if rigid_pull is None
                           else np.ascontiguousarray(rigid_pull, dtype=float))
        self.last: tuple[TargetInfo, ...] = ()
        self._q = np.zeros(r)  # the state of the last weights_into call
        self._part = np.zeros(r)  # one region's pull

    def weights_into(self, q: np.ndarray) -> None:
        """Each region's weights for reduced coordinates q (r,), into its driver's ``w``."""
        self._q[:] = q
        for driver in self.drivers:
            driver.weights_into(q)

    def target_from_weights_into(self, out: np.ndarray) -> None:
        """The pull ``Σ_R T'_R c*_R + Π q`` (r,) for the weights of :meth:`weights_into`,
        written into ``out``."""
        if self.rigid_pull is None:
            out[:] = 0.0
        else:
            np.dot(self.rigid_pull, self._q, out=out)
        part = self._part
        for driver in self.drivers:
            driver.target_from_weights_into(part)
            np.add(out, part, out=out)

    def target(self, q: np.ndarray) -> TargetInfo:
        """Pull ``Σ_R T_R c*_R + Π q`` (r,), concatenated weights, total iterations."""
        started = time.perf_counter()
        infos = tuple(driver.target(q) for driver in self.drivers)
        self.last = infos
        total = np.sum([info.q_target for info in infos], axis=0)
        if self.rigid_pull is not None:
            total = total + self.rigid_pull @ q
        return TargetInfo(total, np.concatenate([info.weights for info in infos]),
                          int(sum(info.iterations for info in infos)),
                          time.perf_counter() - started)

    def region_weights(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """Region name -> (k_R,) eq.-5 weights for reduced coordinates q (r,)."""
        return {name: d.weights(q) for name, d in zip(self.names, self.drivers, strict=True)}


def local_example_driver(mesh: TetMesh, material: Material, space: LocalShapeSpace, *,
                         route: str, tabulate: bool = True, free_rigid: bool = True,
                         tolerance: float = 1e-6, max_iterations: int = 20) -> LocalExampleDriver:
    """The runtime driver of the local examples (set-up is n_R-sized, steps are not).

    Args:
        mesh: the object's rest mesh.
        material: its material.
        space: the local shape space of the precompute.
        route: one of :data:`LOCAL_ROUTES`.
        tabulate: on the ``lb-exact`` route, regions look their target up in their
            table (:attr:`RegionSpace.table`, built here when the precompute has none);
            the ``euclidean`` baseline solves every step.
        free_rigid: anchor each region's target where the region is attached (the
            module docstring); False leaves the targets unanchored.
        tolerance, max_iterations: Newton settings of the target solves.
    """
    if route not in LOCAL_ROUTES:
        raise LbshapeError(f"local examples support the routes {', '.join(LOCAL_ROUTES)}, "
                           f"got {route!r}")
    drivers = []
    rho = material.density
    for region in space.regions:
        k = region.example_coefficients.shape[0]
        offsets = region.example_coefficients.reshape(k, -1)
        pull = region.pull_matrix(free_rigid=free_rigid)
        table = None
        if tabulate and route == "lb-exact":  # the baseline solves every step
            table = region.table
            if table is None and k <= 3:
                log.info("region %s: no target table in the precompute, built at set-up",
                         region.name)
                table = region_target_table(mesh, material, region)
        if table is not None:
            solver = TableSolver(table.mapped(pull), [None] * k, offsets)
        else:
            models = region_energy_models(mesh, material, region, route=route)
            solver = TargetSolver(models, offsets, tolerance=tolerance,
                                  max_iterations=max_iterations)
        drivers.append(ExampleDriver(region.descriptor_matrix(rho, free_rigid=free_rigid),
                                     region.example_descriptors(rho, free_rigid=free_rigid),
                                     solver, to_reduced=pull))
    return LocalExampleDriver(drivers, space.spring, [reg.name for reg in space.regions],
                              rigid_pull=space.rigid_pull if free_rigid else None)


# --------------------------------------------------------------- full space
class FullSpaceLocalForce:
    """The local example force of the full-space reference (n-sized by design).

    Per step: region coefficients ``c_R = Φ_Rᵀ M_R u_R``, weights (eq. 5), target
    ``c*_R`` by Newton with the energy over all of R's elements, and the pull
    ``Σ_R M^(R) E_R (L_R c*_R + Q_R g_R)`` (3n,) in kg·m (g_R the anchor fit, see the
    module docstring); the spring matrix is
    :attr:`mass` = ``Σ_R M^(R)`` (3n, 3n) kg.

    Args:
        mesh: the object's rest mesh.
        material: its material.
        space: the local shape space.
        free_rigid: as in :func:`local_example_driver`.
        tolerance: target Newton tolerance.
    """

    def __init__(self, mesh: TetMesh, material: Material, space: LocalShapeSpace, *,
                 free_rigid: bool = True, tolerance: float = 1e-6):
        self.names = tuple(reg.name for reg in space.regions)
        self.free_rigid = bool(free_rigid)
        n, rho = mesh.n_vertices, float(material.density)
        self._regions = []
        blocks = []
        for region in space.regions:
            sub = region.submesh(mesh)
            mass_R = mass_matrix(sub, rho)
            rows = (3 * region.vertices[:, None] + np.arange(3)).ravel()
            place = sp.csr_matrix((np.ones(rows.size), (rows, np.arange(rows.size))),
                                  shape=(3 * n, rows.size))
            blocks.append(place @ mass_R @ place.T)
            L = block_basis(region.eigenvectors)
            ML = np.asarray(mass_R @ L)  # (3n_R, 3m) kg
            Q, F, anchor_rows = anchor_fit(sub.points, mass_R, region.anchor)
            mass_QF = np.asarray(mass_R @ Q) @ F  # (3n_R, anchor rows)
            relative = ML.T.copy()  # (3m, 3n_R): Lᵀ M_R (I − Q F S) when anchored
            if self.free_rigid:
                relative[:, anchor_rows] -= L.T @ mass_QF
                ML = ML - mass_QF @ L[anchor_rows]
            descriptor = descriptor_matrix(region.eigenvalues, relative.T, rho)
            k = region.example_coefficients.shape[0]
            rests, tets = region.example_energy_shapes(mesh)
            models = [EuclideanExampleEnergy(x, tets, material, L) for x in rests]
            solver = TargetSolver(models, region.example_coefficients.reshape(k, -1),
                                  tolerance=tolerance)
            examples = region.example_descriptors(rho, free_rigid=self.free_rigid)
            self._regions.append((rows, descriptor, examples, solver, ML,
                                  mass_QF, rows.reshape(-1)[anchor_rows]))
        self.mass = sp.csr_matrix(sum(blocks))
        self.weights: dict[str, np.ndarray] = {}

    def pull(self, u: np.ndarray) -> np.ndarray:
        """(3n,) the pull (kg·m) for the displacement u (3n,) or (n, 3)."""
        u = np.asarray(u, dtype=float).reshape(-1)
        out = np.zeros_like(u)
        for name, (rows, descriptor, examples, solver, ML, mass_QF, anchor_rows) in zip(
                self.names, self._regions, strict=True):
            w = simplex_weights(examples, descriptor @ u[rows])
            self.weights[name] = w
            out[rows] += ML @ solver.solve(w).z
            if self.free_rigid:
                out[rows] += mass_QF @ u[anchor_rows]
        return out


# ---------------------------------------------------------------- measures
def region_descriptor(mesh: TetMesh, region: RegionSpace, u: np.ndarray) -> np.ndarray:
    """(3m,) the region's descriptor ``λ_R ⊙ Φ_Rᵀ M_R (u_R − Q_R g)`` of a displacement
    u (n, 3), relative to its anchor's rigid fit g (as the runtime weighs examples)."""
    sub = region.submesh(mesh)
    mass = mass_matrix(sub, 1.0)
    u_R = np.asarray(u, dtype=float).reshape(-1, 3)[region.vertices].reshape(-1)
    Q, F, rows = anchor_fit(sub.points, mass, region.anchor)
    u_R = (u_R - Q @ (F @ u_R[rows])).reshape(-1, 3)
    c = region.eigenvectors.T @ (mass[0::3, 0::3] @ u_R)
    return c.reshape(-1) * np.repeat(region.eigenvalues, 3)


def region_example_distance(mesh: TetMesh, region: RegionSpace, u: np.ndarray, *,
                            density: float) -> tuple[float, np.ndarray]:
    """How far a region's shape is from its examples (paper eq. 5's residual, on the
    descriptors relative to the anchor's rigid fit; ``density`` ρ in kg/m³).

    Returns:
        ``(distance, weights)``: ``min_w ‖Σ w_k e_k − d‖ / max_k ‖e_k‖`` over the
        simplex (0 on the examples' hull, 1 at rest when one example is the
        largest) and the minimising weights (k_R,).
    """
    d = region_descriptor(mesh, region, u)
    E = region.example_descriptors(density)
    w = simplex_weights(E, d)
    scale = float(np.linalg.norm(E, axis=1).max()) or 1.0
    return float(np.linalg.norm(w @ E - d)) / scale, w
