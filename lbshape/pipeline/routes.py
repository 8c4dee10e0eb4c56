"""The interpolation routes: which basis and which elements the target energies use.

See :mod:`lbshape.shapespace.interpolation` for the target problem ``min_z Σ_k w_k E_k(z − z_k)``
and for the registry of routes (:data:`~lbshape.shapespace.interpolation.ROUTES`). The
routes differ in the coordinates z, the basis B that maps them to displacements
(metres) and the elements the energies sum over:

* ``modal`` (the paper's): z = reduced coordinates q (r,), ``B = U`` (3n, r), the
  elastic cubature of the precompute; the examples enter through the direct
  projection ``q_k = T c_k`` (``T`` = :attr:`GlobalExamples.lb_to_reduced`).
* ``lb``: z = LB displacement coefficients c (3m,), ``B = L = Φ ⊗ I₃`` (3n, 3m),
  the cubature trained on the LB displacement subspace by the precompute's
  ``lb-cubature`` stage (:attr:`GlobalExamples.lb_cubatures`; the scene's s,
  seeded, poses as large as the examples); the target maps to reduced
  coordinates through ``T``.
* ``lb-exact`` (StVK only): z = c, ``B = L``, the energy summed over all elements
  but evaluated exactly as a precomputed quartic polynomial in z
  (:class:`lbshape.elastic.polynomial_energy.StVKPolynomialEnergy`): the ``euclidean``
  target at a run-time cost of O((3m)⁴), independent of the mesh.
* ``euclidean`` (Zhu et al. 2015 baseline): z = c, ``B = L``, **all** elements
  with unit weights (:class:`lbshape.shapespace.euclidean_energy.EuclideanExampleEnergy`).
* ``lb-table`` (the default of the reduced method): the exact target (the
  ``lb-exact`` one for StVK, the all-element one otherwise) tabulated over the
  weight simplex at precompute (:mod:`lbshape.shapespace.target_table`, 1–3
  examples, its error checked against the exact target at held-out weights); at run
  time one spline evaluation in reduced coordinates. Without a table (more than 3
  examples, or a table refused by its check) it follows the target of ``lb-exact``
  (StVK) or ``lb`` (other materials) with :data:`FALLBACK_ITERATIONS` warm-started
  Newton step(s) per time step.

In every route example k's energy is that of its rest shape ``X_k = X + B_Φ c_k``
(the example reconstructed on the object's mesh, :meth:`GlobalExamples.rest_points`),
so ``E_k(0) = 0`` and a single example is its own target, summed over the same
elements (:meth:`GlobalExamples.energy_elements`: those no example's
reconstruction squeezes, :mod:`lbshape.shapespace.example_shapes`; the ``modal``
route's cubature keeps its elements among them, the ``lb`` cubature is trained on them).

**Boundary.** The LB eigenfunctions are free at the object's fixed vertices while U is
clamped there, so the examples' LB displacements ``Φ c_k`` keep a part at the fixed
vertices that no reduced coordinate can represent. With ``boundary="clamped"`` (the
default when the precompute found it safe, see
:attr:`~lbshape.pipeline.precomputed.GlobalExamples.target_boundary`) every route uses
the clamped basis ``L_F = Φ_F ⊗ I₃`` (Φ faded to zero at the fixed vertices,
:func:`lbshape.shapespace.clamped_basis.clamped_eigenvectors`) for the examples' rest
shapes, the target coordinates and the direct projection; ``boundary="free"`` keeps Φ
(the paper's construction, for comparison).

Set-up is per run from a :class:`~lbshape.pipeline.precomputed.Precomputed` and cheap (the
cubatures come from the precompute and its cache); nothing is cached here. The
returned objects are m/r/s-sized at run time (``euclidean`` by design is not;
``lb-exact`` costs O((3m)⁴) per evaluation and its set-up is n-sized).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from lbshape.elastic.polynomial_energy import StVKPolynomialEnergy
from lbshape.elastic.reduced_forces import ReducedForceModel
from lbshape.errors import LbshapeError
from lbshape.pipeline.precomputed import Precomputed
from lbshape.shapespace.euclidean_energy import EuclideanExampleEnergy
from lbshape.shapespace.example_driver import ExampleDriver
from lbshape.shapespace.interpolation import ROUTES, TargetSolver
from lbshape.shapespace.target_table import TableSolver

log = logging.getLogger(__name__)

#: the boundary treatments of the LB basis (see the module docstring)
BOUNDARIES = ("clamped", "free")
#: Newton steps per call (per time step, warm-started) of the lb-table route's fallback
#: when there is no table: the target follows the weights closely enough with one
#: (measured in docs/decisions.md, "Interpolation routes")
FALLBACK_ITERATIONS = 1


@dataclass(frozen=True)
class InterpolationRoute:
    """A target solver set up for one route, and what the runtime driver needs.

    Attributes:
        route: one of :data:`ROUTES`.
        solver: the warm-started :class:`~lbshape.shapespace.interpolation.TargetSolver` over
            the k example energies in coordinates z (p,).
        to_reduced: (r, p) ``R`` with ``q = R z``, or ``None`` when z already are
            reduced coordinates (``modal``, p = r).
        basis: (3n, p) node-major B: the displacement of coordinates z is ``B z``
            in metres (``U`` or ``L``). For output and error measurements only.
        elements: (s,) element indices the energies sum over (every one of
            :meth:`GlobalExamples.energy_elements` for ``euclidean`` and ``lb-exact``).
        weights: (s,) their non-negative weights (dimensionless).
        cubature_errors: the cubature's relative force errors (``train``,
            ``holdout``) as recorded by the precompute; empty without a cubature.
        seconds: wall time of the set-up (s).
    """

    route: str
    solver: TargetSolver
    to_reduced: np.ndarray | None
    basis: np.ndarray
    elements: np.ndarray
    weights: np.ndarray
    cubature_errors: dict = field(default_factory=dict)
    seconds: float = 0.0

    @property
    def offsets(self) -> np.ndarray:
        """(k, p) the examples' own coordinates z_k."""
        return self.solver.offsets

    @property
    def dimension(self) -> int:
        """p, the number of target coordinates."""
        return self.solver.dimension

    def reduced(self, z: np.ndarray) -> np.ndarray:
        """Reduced coordinates (r,) of target coordinates z (p,)."""
        z = self._coordinates(z)
        return z.copy() if self.to_reduced is None else self.to_reduced @ z

    def displacement(self, z: np.ndarray) -> np.ndarray:
        """Full-space displacement ``B z`` (n, 3) in metres of target coordinates z (p,)."""
        return (self.basis @ self._coordinates(z)).reshape(-1, 3)

    def _coordinates(self, z) -> np.ndarray:
        z = np.asarray(z, dtype=float)
        if z.shape != (self.dimension,):
            raise LbshapeError(
                f"{self.route} target coordinates must have shape ({self.dimension},), "
                f"got {z.shape}"
            )
        return z


def target_solver(
    pre: Precomputed,
    route: str,
    *,
    tolerance: float = 1e-6,
    max_iterations: int = 20,
    boundary: str | None = None,
    tracking: bool = False,
) -> InterpolationRoute:
    """Set up the target solver of ``route`` from a precompute with examples.

    Args:
        pre: the scene's precompute (must have examples; the ``lb`` route also
            needs its LB-subspace cubature).
        route: one of :data:`ROUTES` (see the module docstring).
        tolerance: Newton tolerance of the :class:`TargetSolver`.
        max_iterations: Newton iterations per target solve.
        tracking: ``max_iterations`` warm-started Newton steps per call by design (see
            :class:`~lbshape.shapespace.interpolation.TargetSolver`).
        boundary: ``"clamped"`` or ``"free"`` LB basis; default: the precompute's
            :attr:`~lbshape.pipeline.precomputed.GlobalExamples.target_boundary` (``lb-table``:
            that one only).

    Returns:
        The :class:`InterpolationRoute`.

    Raises:
        LbshapeError: unknown route, a precompute without examples (or without the
            LB cubature for ``lb``), or inconsistent array shapes.
    """
    if route not in ROUTES:
        raise LbshapeError(f"unknown interpolation route {route!r} (routes: {', '.join(ROUTES)})")
    if boundary is None:
        boundary = "free" if pre.examples is None else pre.examples.target_boundary
    if boundary not in BOUNDARIES:
        raise LbshapeError(f"boundary must be one of {BOUNDARIES}, got {boundary!r}")
    check_precomputed(pre)
    clamped = boundary == "clamped"
    if route == "lb-table":
        if boundary != pre.examples.target_boundary:
            raise LbshapeError("the lb-table route is tabulated in the "
                               f"{pre.examples.target_boundary} LB basis only")
        if pre.examples.target_table is None:
            fallback = "lb-exact" if pre.material.model == "stvk" else "lb"
            log.info("no target table in the precompute of %s: the lb-table route follows the "
                     "%s target with %d warm-started Newton step(s) per time step", pre.scene,
                     fallback, FALLBACK_ITERATIONS)
            return target_solver(pre, fallback, tolerance=tolerance,
                                 max_iterations=FALLBACK_ITERATIONS, boundary=boundary,
                                 tracking=True)
        return _table_route(pre, clamped=clamped)
    started = time.perf_counter()
    energies = _route_energies(pre, route, clamped=clamped)
    solver = TargetSolver(energies.models, energies.offsets, tolerance=tolerance,
                          max_iterations=max_iterations, tracking=tracking)
    seconds = time.perf_counter() - started
    log.info("interpolation route %s: p=%d coordinates, %d elements, set up in %.3f s",
             route, energies.offsets.shape[1], np.size(energies.elements), seconds)
    return InterpolationRoute(
        route=route, solver=solver, to_reduced=energies.to_reduced, basis=energies.basis,
        elements=np.asarray(energies.elements, dtype=np.int64),
        weights=np.asarray(energies.weights, dtype=float),
        cubature_errors=energies.errors, seconds=seconds,
    )


def _table_route(pre: Precomputed, *, clamped: bool) -> InterpolationRoute:
    """The ``lb-table`` route: the precompute's table, mapped to reduced coordinates."""
    started = time.perf_counter()
    k = pre.examples.example_coefficients.shape[0]
    lb_to_reduced = pre.examples.lb_to_reduced_for(clamped=clamped)
    table = pre.examples.target_table
    table.set_reduced_map(lb_to_reduced)
    solver = TableSolver(table, [None] * k, pre.examples.example_coefficients.reshape(k, -1))
    check = table.check
    return InterpolationRoute(
        route="lb-table", solver=solver, to_reduced=lb_to_reduced,
        basis=pre.shape.lb_basis(clamped=clamped), elements=np.zeros(0, dtype=np.int64),
        weights=np.zeros(0), seconds=time.perf_counter() - started,
        cubature_errors={} if check is None else {"table_max_error": check.max_error})


class _RouteEnergies(NamedTuple):
    """The example energies of a solved route and what maps its coordinates z."""

    models: list  #: k energy models in z
    offsets: np.ndarray  #: (k, p) the examples' own coordinates z_k
    to_reduced: np.ndarray | None  #: (r, p) ``q = R z``, None when z = q
    basis: np.ndarray  #: (3n, p) B
    elements: np.ndarray  #: (s,) the elements the energies sum over
    weights: np.ndarray  #: (s,) their weights
    errors: dict  #: the cubature's recorded errors


def _route_energies(pre: Precomputed, route: str, *, clamped: bool) -> _RouteEnergies:
    """The example energies of ``route`` (not ``lb-table``) on the examples' rest shapes,
    over the example energies' elements (see the module docstring)."""
    k = pre.examples.example_coefficients.shape[0]
    coefficients = pre.examples.example_coefficients.reshape(k, -1)
    tets, material = pre.mesh.tets, pre.material
    lb_to_reduced = pre.examples.lb_to_reduced_for(clamped=clamped)
    rests = [pre.examples.rest_points(i, clamped=clamped) for i in range(k)]
    kept = pre.examples.energy_elements(clamped=clamped)  # n-sized: set-up only
    if route in ("euclidean", "lb-exact"):
        energy = EuclideanExampleEnergy if route == "euclidean" else StVKPolynomialEnergy
        basis = pre.shape.lb_basis(clamped=clamped)
        models = [energy(x, tets[kept], material, basis) for x in rests]
        return _RouteEnergies(models, coefficients, lb_to_reduced, basis, kept,
                              np.ones(kept.size), {})
    if route == "modal":
        inside = np.isin(pre.elastic.cubature_elements, kept)
        if not inside.all():  # none on the built-in scenes (docs/decisions.md)
            share = pre.elastic.cubature_weights[~inside].sum() / pre.elastic.cubature_weights.sum()
            log.warning("modal route: %d of %d cubature elements are squeezed by the "
                        "examples and left out (%.1f %% of the weight); the others keep "
                        "their weights", int((~inside).sum()), inside.size, 100 * share)
        basis = pre.U
        elements = pre.elastic.cubature_elements[inside]
        weights = pre.elastic.cubature_weights[inside]
        models = [ReducedForceModel(x, tets, material, basis, elements, weights)
                  for x in rests]
        return _RouteEnergies(models, coefficients @ lb_to_reduced.T, None, basis, elements,
                              weights, dict(pre.elastic.cubature_errors))
    rules = _lb_cubature(pre, k)
    basis = pre.shape.lb_basis(clamped=clamped)
    models = [ReducedForceModel(x, tets, material, basis, e, w)
              for x, (e, w) in zip(rests, rules, strict=True)]
    elements = np.unique(np.concatenate([e for e, _ in rules]))
    return _RouteEnergies(models, coefficients, lb_to_reduced, basis, elements,
                          np.ones(elements.size),
                          pre.examples.lb_cubatures.named_errors)


def example_driver(pre: Precomputed, *, route: str, **options):
    """The runtime :class:`~lbshape.shapespace.example_driver.ExampleDriver` of ``route``.

    Args:
        pre: the scene's precompute (must have examples).
        route: one of :data:`ROUTES`.
        **options: keyword options of :func:`target_solver`.
    """
    setup = target_solver(pre, route, **options)
    return ExampleDriver(pre.examples.descriptor_matrix, pre.examples.example_descriptors,
                         setup.solver, to_reduced=setup.to_reduced)


def exact_route(pre: Precomputed) -> str:
    """The route whose target is exact for the precompute's material: ``lb-exact``
    (StVK, a polynomial) or ``euclidean`` (all elements)."""
    return "lb-exact" if pre.material.model == "stvk" else "euclidean"


def check_precomputed(pre: Precomputed) -> None:
    """Raise a one-line :class:`LbshapeError` if ``pre`` cannot feed the routes.

    Checks that the precompute has examples and that the object's spectrum Φ
    (n, m), its eigenvalues (m,), the example coefficients (k, m, 3), the basis U
    (3n, r) and the direct projection (r, 3m) agree in n, m and r.
    """
    if not pre.has_examples or pre.shape is None or pre.shape.eigenvectors is None \
            or pre.examples.projection is None or pre.shape.eigenvalues is None:
        raise LbshapeError(
            f"scene {pre.scene!r} has no examples: there is no interpolation target to set up"
        )
    n = pre.mesh.n_vertices
    phi = np.asarray(pre.shape.eigenvectors)
    if phi.ndim != 2 or phi.shape[0] != n:
        raise LbshapeError(f"LB eigenvectors must have shape (n={n}, m), got {phi.shape}")
    m = phi.shape[1]
    if np.shape(pre.shape.eigenvalues) != (m,):
        raise LbshapeError(
            f"expected {m} LB eigenvalues, got shape {np.shape(pre.shape.eigenvalues)}")
    c = np.asarray(pre.examples.example_coefficients)
    if c.ndim != 3 or c.shape[0] < 1 or c.shape[2] != 3:
        raise LbshapeError(f"example coefficients must have shape (k, m, 3), got {c.shape}")
    if c.shape[1] != m:
        raise LbshapeError(
            f"examples have {c.shape[1]} LB coefficients per component but the object's "
            f"shape space has m={m}"
        )
    if not np.isfinite(c).all():
        raise LbshapeError("example coefficients contain NaN or infinite values")
    r = pre.r
    if pre.U.shape[0] != 3 * n:
        raise LbshapeError(f"basis U must have shape (3n={3 * n}, r), got {pre.U.shape}")
    if np.shape(pre.examples.projection) != (r, 3 * m):
        raise LbshapeError(
            f"direct projection must have shape (r={r}, 3m={3 * m}), "
            f"got {np.shape(pre.examples.projection)}"
        )


def _lb_cubature(pre: Precomputed, k: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """The precompute's LB-subspace cubature per example: k pairs (elements (s_k,),
    weights (s_k,)); a shared (s,) rule is repeated."""
    lb = pre.examples.lb_cubatures
    if lb is None or lb.elements is None or lb.weights is None:
        raise LbshapeError(
            f"the precompute of scene {pre.scene!r} has no LB-subspace cubature; "
            "re-run 'lbshape precompute --force' for the 'lb' interpolation route"
        )
    elements = np.asarray(lb.elements, dtype=np.int64)
    weights = np.asarray(lb.weights, dtype=float)
    if elements.ndim == 1:
        return [(elements, weights)] * k
    if elements.shape[0] != k or weights.shape != elements.shape:
        raise LbshapeError(f"per-example LB cubature must have shape ({k}, s), got "
                           f"{elements.shape} and {weights.shape}")
    return [(e[e >= 0], w[e >= 0]) for e, w in zip(elements, weights, strict=True)]
