"""Building the local shape space (paper §5) at precompute: each region's spectrum,
its examples' coefficients, the small matrices of
:mod:`lbshape.shapespace.local_space` and the target table.

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

The representation errors of the two variants (per-region and whole-object
eigenfunctions, :mod:`lbshape.shapespace.local_space`) are measured here, on the
first example's pose applied to the object's own region.

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
runtime (:mod:`lbshape.shapespace.local_driver`) looks the target up in that table.
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

from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.materials import Material
from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.shapespace.basis_choice import METHODS, warn_doubtful_transfer
from lbshape.shapespace.example_targets import tabulate_examples
from lbshape.shapespace.local_regions import (
    anchor_fit,
    check_partition,
    region_anchor,
    region_cells,
    rigid_fields,
    submesh,
)
from lbshape.shapespace.local_space import LocalShapeSpace, RegionSpace
from lbshape.shapespace.projections import block_basis, embed_example
from lbshape.shapespace.target_table import DEFAULT_TOLERANCE, TargetTable
from lbshape.spectral.spectrum import lb_spectrum

log = logging.getLogger(__name__)

#: largest relative RMS residual of a region part's frame alignment. The residual is a
#: vertex-to-vertex distance, and an object's region often has only tens of vertices
#: (a teddy's leg: ~50 against the example part's ~800), so a matching part measures
#: ~0.25 by resolution alone; the basis alignment residual still guards the match.
REGION_FRAME_RMS = 0.35
#: an example whose RMS displacement on a region is below this share of the region's
#: extent is at rest to round-off (warned about: a scene does not mean that)
AT_REST = 1e-9


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
    (see :mod:`lbshape.shapespace.local_space` and :class:`RegionSpace`)."""
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
        region, spring = region.projected(mesh, material, U)
    return _BuiltRegion(region, spring, sub, volume_mass)


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
        log.info("%s: alignment residual %.3g (%s), transfer difference %.3g", what,
                 embedded.alignment.residual, embedded.alignment.method,
                 embedded.transfer_differences[0])
        warn_doubtful_transfer(what, embedded)
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
