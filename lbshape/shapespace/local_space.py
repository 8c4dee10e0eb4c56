"""The local shape space: regions of the object, each guided by its own examples
(paper §5), and the small matrices their forces use.

**Variant used: per-region eigenfunctions** (the paper's Figure 7 caption). Each
region R (a set of the object's tetrahedra, :mod:`lbshape.shapespace.local_regions`)
is a mesh of its own; its m smallest
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
``docs/decisions.md``). The space is built by
:func:`lbshape.shapespace.local_build.build_local_space`.

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
:func:`lbshape.shapespace.local_driver.local_example_driver` runs these forces in
reduced coordinates, :class:`lbshape.shapespace.local_full_force.FullSpaceLocalForce`
in full space.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.materials import Material
from lbshape.geometry.mesh import TetMesh
from lbshape.shapespace.basis_choice import METHODS
from lbshape.shapespace.example_shapes import energy_elements, example_rest_shapes
from lbshape.shapespace.interpolation import simplex_weights
from lbshape.shapespace.local_regions import anchor_fit
from lbshape.shapespace.projections import descriptor_matrix, reduced_projection
from lbshape.shapespace.target_table import TargetTable


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
        anchor: (n_R,) bool, the anchor vertices
            (:func:`~lbshape.shapespace.local_regions.region_anchor`).
        rigid_lb: (3m, 6) ``L_Rᵀ M^(R) Q_R``: LB coefficients (times ρ) of the rigid fields.
        table: the region's exact target tabulated over its weight simplex, in the
            coefficients c (3m,)
            (:func:`~lbshape.shapespace.local_build.region_target_table`), or None (more
            than three examples, a refused table, or not built).
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

    def example_fields(self, mesh: TetMesh) -> list[tuple[TetMesh, np.ndarray]]:
        """Each example's ``(region mesh, (n_R, 3) displacement Φ_R c_k in m)``: the
        example on the region's own mesh (the zero displacement outside is no jump)."""
        sub = self.submesh(mesh)
        return [(sub, self.displacement(c)) for c in self.example_coefficients]

    def displacement(self, coefficients: np.ndarray) -> np.ndarray:
        """(n_R, 3) region displacement ``Φ_R c`` of coefficients (3m,) or (m, 3)."""
        return self.eigenvectors @ np.asarray(coefficients, dtype=float).reshape(self.m, 3)

    def projected(self, mesh: TetMesh, material: Material,
                  U: np.ndarray) -> tuple[RegionSpace, np.ndarray]:
        """The region with its maps to the reduced coordinates of U (3n, r) (``to_reduced``,
        ``rigid_reduced``, ``anchor_reduced``) and its share ``U_Rᵀ M^(R) U_R`` (r, r) of
        the spring matrix."""
        rho = float(material.density)
        sub = self.submesh(mesh)
        rows = (3 * self.vertices[:, None] + np.arange(3)).ravel()
        U_R = np.asarray(U, dtype=float)[rows]
        mass_R = mass_matrix(sub, rho)
        Q, F, anchor_rows = anchor_fit(sub.points, mass_R, self.anchor)
        region = dataclasses.replace(
            self,
            to_reduced=reduced_projection(U_R, self.eigenvectors, mass_R[0::3, 0::3] / rho,
                                          rho),
            rigid_reduced=U_R.T @ (mass_R @ Q), anchor_reduced=(F @ U_R[anchor_rows]).T)
        return region, U_R.T @ (mass_R @ U_R)


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
            region, share = region.projected(mesh, material, U)
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
