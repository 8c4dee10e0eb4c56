"""What a scene drives its object with, as the basis needs it
(:mod:`lbshape.elastic.basis`).

* **Load patterns** (:func:`mesh_load_patterns`): the scene's ``[[loads]]`` as
  full-space force patterns (3n,) in N with their time profiles — the same patterns
  every method is driven by (:func:`lbshape.pipeline.simulate.load_patterns`).
* **Response loads** (:func:`response_loads`): the load patterns f, whose static
  responses ``K⁻¹ f`` (the linear static shapes the object takes under each) are solved
  with the modal derivatives' factorisation of K
  (:func:`lbshape.elastic.modal_derivatives.modal_derivatives`, ``static_loads``). They
  depend on a load's type, region and direction, not on its size or profile (the
  static equilibria below do depend on its size, :func:`response_key`). Fixed objects
  only: a free body's loads move it rigidly, and its deformation is already held by the
  plain basis.
* **Static load** (:func:`static_load`): every load at full strength, summed — the
  load whose nonlinear static equilibria the basis holds
  (:func:`lbshape.elastic.static_equilibrium.static_equilibria`, the precompute's
  ``static-equilibria`` stage; fixed objects only, :func:`static_load_applies`). The
  time profiles all peak at 1, so this is the strongest load the scene applies. The
  equilibria depend on the loads' sizes, which are part of the cache key
  (:func:`response_key`).
* **Example responses** (:func:`example_target_fields`, :func:`example_responses`): the
  example force ``k_ex S (v − u)`` pulls towards targets v (3n,) — global examples: the
  exact targets ``L z`` over the weight simplex, pulled with the elastic mass M; local
  examples: each region's targets and its rigid fields (the anchored target moves
  rigidly with the region), pulled with ``S = Σ_R M^(R)``. The object's answer to that
  pull is a Krylov sequence of the spring-shifted stiffness ``K + k_ex S``, which
  :func:`lbshape.elastic.basis.append_directions` appends to U (the precompute's
  ``example-basis`` stage). The shift makes them depend on k_ex, which is therefore part
  of the cache key (:func:`example_response_stiffness`). A free body's targets and
  responses lose their rigid part (its frame holds the rigid motion, and the full
  reference pulls towards the target placed by its best rigid fit); ``K + k_ex M`` is
  positive definite without supports.
* **Anchor responses** (:func:`anchor_responses`, :func:`anchored_readout_responses`):
  local examples move a region's target rigidly with the anchor fit ``Q_R F_R u[anchor]``,
  a feedback from a ring of anchor vertices that the example responses do not hold. For
  each region the pull is stiffer than (:func:`strongly_pulled_regions`) the
  ``example-basis`` stage appends the fit's read-out responses carried through the
  anchored operator's adjoint, as many as the exact force's budget allows
  (:func:`anchor_room`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

from lbshape.dynamics.loads import (
    TimedLoad,
    gravity_pattern,
    region_force_pattern,
    region_torque_pattern,
)
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.polynomial_forces import resolve_force_model
from lbshape.errors import LbshapeError
from lbshape.fem.cholesky import serial_cholesky
from lbshape.geometry.mesh import TetMesh, free_dof_mask
from lbshape.pipeline.meshes import selected_vertices
from lbshape.scene.schema import Scene
from lbshape.shapespace.auto_stiffness import AUTO_RULE, example_field_stiffness
from lbshape.shapespace.local_regions import anchor_fit, rigid_fields
from lbshape.shapespace.local_space import RegionSpace
from lbshape.shapespace.projections import block_basis

#: Krylov blocks of the example responses (:func:`example_responses`)
EXAMPLE_RESPONSE_DEPTH = 2


def mesh_load_patterns(scene: Scene, mesh: TetMesh, mass) -> list[TimedLoad]:
    """The scene's loads as full-space patterns (3n,) in N with their time profiles.

    Args:
        scene: the scene (its ``loads``).
        mesh: the object's rest mesh (regions are selected on it).
        mass: (3n, 3n) node-major consistent mass in kg.
    """
    patterns = []
    for index, load in enumerate(scene.loads):
        what = f"loads[{index}] region"
        if load.type == "gravity":
            pattern = gravity_pattern(mass, load.vector)
        elif load.type == "region_force":
            pattern = region_force_pattern(mass, selected_vertices(load.selection, mesh, what=what),
                                           load.vector)
        elif load.type == "region_torque":
            pattern = region_torque_pattern(
                mass, mesh.points, selected_vertices(load.selection, mesh, what=what), load.vector)
        else:  # the scene schema only admits the types above
            raise LbshapeError(f"unsupported load type {load.type!r}")
        patterns.append(TimedLoad(pattern, load.profile))
    return patterns


def response_loads(scene: Scene, mesh: TetMesh, mass,
                   fixed_vertices: np.ndarray) -> np.ndarray:
    """(3n, c) forces in N whose static responses the basis keeps: the scene's load
    patterns (none for a free body, see the module docstring).

    Args:
        scene: the scene (its loads).
        mesh: the object's rest mesh.
        mass: (3n, 3n) consistent mass, kg.
        fixed_vertices: (f,) clamped vertices; none means a free body.
    """
    if np.size(fixed_vertices) == 0 or not scene.loads:
        return np.zeros((3 * mesh.n_vertices, 0))
    return np.column_stack([load.pattern for load in mesh_load_patterns(scene, mesh, mass)])


def static_load_applies(scene: Scene) -> bool:
    """Whether the scene's loads have static equilibria for the basis: a fixed object
    with loads."""
    return not scene.is_free and bool(scene.loads)


def static_load(scene: Scene, mesh: TetMesh, mass) -> np.ndarray:
    """(3n,) N: the scene's load patterns at full strength, summed.

    Args:
        scene: the scene (its loads).
        mesh: the object's rest mesh.
        mass: (3n, 3n) consistent mass, kg.
    """
    return sum((load.pattern for load in mesh_load_patterns(scene, mesh, mass)),
               np.zeros(3 * mesh.n_vertices))


def example_response_stiffness(scene: Scene, auto: float | None = None) -> float:
    """k_ex (1/s²) the example responses are shifted by, or 0 when the scene gets none
    (no examples, or k_ex = 0). ``stiffness = "auto"``: ``auto``, the value the precompute
    set (:mod:`lbshape.shapespace.auto_stiffness`); without it, ``inf`` (some k_ex > 0 that
    the precompute sets)."""
    if scene.examples is None or not scene.examples.poses:
        return 0.0
    if scene.examples.auto:
        return math.inf if auto is None else float(auto)
    return float(scene.examples.stiffness)


def example_target_fields(mesh: TetMesh, mass, density: float, *,
                          eigenvectors: np.ndarray | None = None,
                          targets: np.ndarray | None = None,
                          regions: Sequence[RegionSpace] = ()
                          ) -> tuple[np.ndarray, sp.csr_matrix]:
    """The displacements the example force pulls towards, and the mass it pulls with.

    Global examples: the exact targets along the weight simplex, ``L z_p`` (L = Φ ⊗ I₃)
    for each target z_p (3m,), pulled with the elastic mass M. Local examples: per
    region, its targets ``E_R L_R z_p`` and, when it has an anchor, its six rigid fields
    ``E_R Q_R`` (the anchor fit moves the region's target rigidly; a region covering the
    object has none and is the global path), pulled with ``S = Σ_R M^(R)``.

    Args:
        mesh: the object's rest mesh (n vertices).
        mass: (3n, 3n) the elastic mass M in kg (global examples' spring).
        density: ρ in kg/m³ (the regions' masses).
        eigenvectors: (n, m) the targets' Φ (global examples).
        targets: (P, 3m) exact targets over the weight simplex (global examples).
        regions: the local shape space's regions (local examples; their ``table`` nodes
            are the targets, or the examples' coefficients without a table).

    Returns:
        ``(V, S)``: V (3n, p) displacements in m, S (3n, 3n) in kg.
    """
    n = mesh.n_vertices
    if not regions:
        V = block_basis(eigenvectors) @ np.asarray(targets, dtype=float).T
        return V, sp.csr_matrix(mass)
    spring = sp.csr_matrix((3 * n, 3 * n))
    columns = []
    for region in regions:
        sub = region.submesh(mesh)
        rows = (3 * region.vertices[:, None] + np.arange(3)).ravel()
        place = sp.csr_matrix((np.ones(rows.size), (rows, np.arange(rows.size))),
                              shape=(3 * n, rows.size))
        mass_R = mass_matrix(sub, density)
        spring = spring + place @ mass_R @ place.T
        nodes = (region.table.nodes if region.table is not None
                 else region.example_coefficients.reshape(len(region.examples), -1))
        fields = np.column_stack([region.displacement(z).ravel() for z in nodes])
        if region.anchor.any():
            fields = np.hstack([fields, rigid_fields(sub.points, mass_R)])
        columns.append(place @ fields)
    return np.hstack(columns), spring.tocsr()


def example_responses(stiffness, spring, k_ex: float, fields: np.ndarray, mass,
                      fixed_vertices: np.ndarray, *, rigid: np.ndarray | None = None,
                      depth: int = EXAMPLE_RESPONSE_DEPTH) -> np.ndarray:
    """(3n, depth · p) the object's responses to the example pull, a Krylov sequence of
    the spring-shifted stiffness: ``X₁ = (K + k_ex S)⁻¹ S V``, ``X_{j+1} = (K + k_ex S)⁻¹ M
    X_j`` on the free DOFs (zero at the fixed ones).

    ``X₁`` is the static shape the object takes when the example force
    ``k_ex S (v − u)`` pulls it towards a target v together with its elasticity (for
    k_ex ≫ ω² it is v itself away from the supports, with the boundary layer where the
    supports hold it; for k_ex ≪ ω² the static response ``K⁻¹ S v``); the later blocks are
    the load-dependent Ritz vectors of that pull (Wilson, Yuan & Dickens 1982), which hold
    its dynamic response.

    Args:
        stiffness: (3n, 3n) K without constraints, N/m.
        spring: (3n, 3n) S, kg (:func:`example_target_fields`).
        k_ex: the example stiffness in 1/s², > 0.
        fields: (3n, p) target displacements V in m.
        mass: (3n, 3n) M, kg.
        fixed_vertices: (f,) clamped vertices; none for a free body.
        rigid: (3n, 6) M-orthonormal rigid fields of a free body, removed from the
            targets and the responses (the reduced frame holds the rigid motion and the
            full reference pulls towards the target placed by its best rigid fit).
        depth: Krylov blocks.
    """
    def deformation(X):
        return X if rigid is None else X - rigid @ (rigid.T @ (mass @ X))

    n3 = stiffness.shape[0]
    free = free_dof_mask(n3 // 3, fixed_vertices)
    shifted = sp.csr_matrix(stiffness + k_ex * spring)[free][:, free]
    blocks = []
    with serial_cholesky(shifted, prefix="responses_", what="the spring-shifted stiffness") \
            as solve:
        load = spring @ deformation(fields)
        for _ in range(depth):
            block = np.zeros((n3, fields.shape[1]))
            block[free] = solve(np.asarray(load)[free])
            block = deformation(block)
            blocks.append(block)
            load = mass @ block
    return np.hstack(blocks)


def anchor_responses(stiffness, spring, k_ex: float, mesh: TetMesh, density: float,
                     regions: Sequence[RegionSpace], fixed_vertices: np.ndarray,
                     sets: int = 2) -> tuple[np.ndarray, ...]:
    """The object's static responses to each anchored region's rigid fit: ``(load,
    read-out)``, each (3n, 6 per anchored region), zero at the fixed DOFs; ``sets`` 1:
    the loads' only, 0: none.

    The anchor fit ``g = F_R u[anchor]`` places the region's target ``Q_R g``; the pull
    ``k_ex M_R Q_R g`` loads the object along ``M_R Q_R`` (load responses ``(K + k_ex
    S)⁻¹ M_R Q_R``) and reads the state through ``F_R`` (read-out responses ``(K + k_ex
    S)⁻¹ F_Rᵀ``).

    Args:
        stiffness: (3n, 3n) K without constraints, N/m.
        spring: (3n, 3n) S = Σ_R M^(R), kg (:func:`example_target_fields`).
        k_ex: the example stiffness in 1/s², > 0.
        mesh: the object's rest mesh.
        density: ρ in kg/m³ (the regions' masses).
        regions: the local shape space's regions (unanchored ones give none, no
            regions none at all).
        fixed_vertices: (f,) clamped vertices.
        sets: 0, 1 or 2, see above.
    """
    n3 = stiffness.shape[0]
    if not sets:
        return (np.zeros((n3, 0)),)
    loads, readouts = anchor_fit_fields(mesh, density, regions)
    if not loads.shape[1]:
        return (loads,) * sets
    G = np.hstack([loads, readouts][:sets])
    X = np.zeros_like(G)
    free = free_dof_mask(n3 // 3, fixed_vertices)
    with serial_cholesky(sp.csr_matrix(stiffness + k_ex * spring)[free][:, free],
                         prefix="anchor_", what="the spring-shifted stiffness") as solve:
        X[free] = solve(G[free])
    return tuple(np.hsplit(X, sets))


def anchored_readout_responses(stiffness, spring, k_ex: float, mesh: TetMesh,
                               density: float, regions: Sequence[RegionSpace],
                               fixed_vertices: np.ndarray,
                               pulled: Sequence[str] | None = None) -> np.ndarray:
    """(3n, 6 per anchored region in ``pulled``, default all): the read-out responses of
    :func:`anchor_responses` carried through the adjoint of the anchored operator (of
    every anchored region), ``Aᵀ⁻¹ B⁻¹ F_Rᵀ``, zero at the fixed DOFs.

    With the weights held the local pull is ``pull(0) + G u``, ``G = L Rᵀ`` (L: the fit's
    loads ``M_R Q_R``, R: its read-outs ``F_Rᵀ``, 6 columns per region), so the example
    force's stiffness is the non-symmetric ``A = B − k_ex L Rᵀ``, ``B = K + k_ex S``.
    With ``P = B⁻¹ R`` and ``C = Lᵀ P`` (Woodbury), ``Aᵀ⁻¹ Z = B⁻¹ Z + k_ex P (I − k_ex
    C)⁻¹ Lᵀ B⁻¹ Z``, taken at ``Z = P``. Measured on teddy-local (``docs/decisions.md``,
    "Local examples: k_ex raised to the regions' static equilibrium"): its 48 columns
    alone are 12.8 % from full at k_ex = 2000 1/s², with these 24 appended 3.7 %, with
    ``P`` itself in their place 5.4 % (the block ``[P, B⁻¹P]``: 5.6 % at 2500).

    Args: as :func:`anchor_responses`; ``pulled``: the regions' names whose read-outs
    are wanted (:func:`strongly_pulled_regions`).
    """
    n3 = stiffness.shape[0]
    loads, readouts = anchor_fit_fields(mesh, density, regions)
    names = [region.name for region in regions if region.anchor.any()]
    chosen = np.repeat([pulled is None or name in pulled for name in names], 6)
    if not chosen.any():
        return np.zeros((n3, 0))
    free = free_dof_mask(n3 // 3, fixed_vertices)
    L, R = loads[free], readouts[free]
    X = np.zeros((n3, int(chosen.sum())))
    with serial_cholesky(sp.csr_matrix(stiffness + k_ex * spring)[free][:, free],
                         prefix="anchor_", what="the spring-shifted stiffness") as solve:
        P = solve(R)
        BP = solve(P[:, chosen])
    C = L.T @ P
    X[free] = BP + k_ex * P @ np.linalg.solve(np.eye(C.shape[0]) - k_ex * C, L.T @ BP)
    return X


def strongly_pulled_regions(k_ex: float, mesh: TetMesh, material,
                            regions: Sequence[RegionSpace]) -> tuple[str, ...]:
    """The anchored regions the example pull is at least as stiff as: ``k_ex ≥ ω_e²``
    (1/s², ω_e² of :func:`lbshape.shapespace.auto_stiffness.example_field_stiffness`) of
    the region's softest example. There the pull, not the region's elasticity, sets its
    shape, and the anchor fit's feedback drives the reduced run away from the full one
    (teddy-local at k_ex = 958 / 2000: 7.1 / 12.8 % without the anchored read-outs); the
    built-in scenes' own k_ex pull none (teddy-local 100 against 475, cross 1000 against
    1138), the cross's auto 2275 its middle only (its arms' ω_e² 4,602 and 59,056)."""
    if not k_ex > 0.0 or not math.isfinite(k_ex):
        return ()
    return tuple(region.name for region in regions if region.anchor.any() and k_ex >= min(
        example_field_stiffness(sub, material, field)[0]
        for sub, field in region.example_fields(mesh)))


def anchor_fit_fields(mesh: TetMesh, density: float, regions: Sequence[RegionSpace]
                      ) -> tuple[np.ndarray, np.ndarray]:
    """``(L, R)``, each (3n, 6 per anchored region): the anchor fits' loads ``M_R Q_R``
    (kg) on each region's rows and read-outs ``F_Rᵀ`` on its anchor rows
    (:func:`lbshape.shapespace.local_regions.anchor_fit`; ``ρ = density`` kg/m³)."""
    n3 = 3 * mesh.n_vertices
    loads, readouts = [np.zeros((n3, 0))], [np.zeros((n3, 0))]
    for region in regions:
        if not region.anchor.any():
            continue
        sub = region.submesh(mesh)
        mass_R = mass_matrix(sub, density)
        Q, F, anchor_rows = anchor_fit(sub.points, mass_R, region.anchor)
        rows = (3 * region.vertices[:, None] + np.arange(3)).ravel()
        load, readout = np.zeros((n3, 6)), np.zeros((n3, 6))
        load[rows] = np.asarray(mass_R @ Q)
        readout[rows[anchor_rows]] = F.T
        loads.append(load)
        readouts.append(readout)
    return np.hstack(loads), np.hstack(readouts)


def anchor_room(scene: Scene, n_tets: int, r: int, wanted: int) -> int:
    """How many of ``wanted`` anchor responses a basis of r columns takes: all while the
    scene's reduced force stays the exact polynomial one
    (:func:`lbshape.elastic.polynomial_forces.resolve_force_model`), none under the
    cubature (its few elements, trained for the smaller basis, miss the new columns)."""
    def exact(columns: int) -> bool:
        return resolve_force_model(scene.reduced.forces, scene.material.model, n_tets,
                                   columns) == "polynomial"

    room = wanted if exact(r) else 0
    while room > 0 and not exact(r + room):
        room -= 1
    return room


def response_key(scene: Scene) -> dict:
    """What the responses depend on beyond the precompute's own fields: each load's
    type, selection and vector (the linear responses depend on its direction only, the
    static equilibria on its size too), and the k_ex the example responses are shifted by
    (:func:`example_response_stiffness`)."""
    loads = []
    for load in scene.loads:
        loads.append({"type": load.type, "group": load.selection.group if load.selection
                      else None, "region": load.selection.region if load.selection else None,
                      "vector": np.asarray(load.vector, dtype=float).round(12).tolist()})
    k_ex = example_response_stiffness(scene)
    if scene.examples is not None and scene.examples.auto:  # a function of the rest
        k_ex = {"auto": list(AUTO_RULE)}
    return {"loads": loads, "example_response_stiffness": k_ex,
            "free": scene.is_free}
