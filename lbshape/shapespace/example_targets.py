"""The examples' exact targets at precompute: their energies, the table, the path.

Given the examples' LB displacement coefficients c_k in a basis Φ (free or clamped,
:mod:`lbshape.shapespace.clamped_basis`), :func:`tabulate_examples` builds what the
target routes and the LB cubature train on:

* the exact example energies ``E_k`` (:func:`exact_example_energies`) of the examples'
  rest shapes ``X_k = X + Φ c_k`` over the elements no reconstruction squeezes
  (:func:`~lbshape.shapespace.example_shapes.energy_elements`);
* the exact target tabulated over the weight simplex
  (:func:`~lbshape.shapespace.target_table.build_target_table`, 1–3 examples), or None;
* the path of exact targets spread over the simplex (:func:`example_path`): the table's
  nodes, or without a table exact solves along the edges between two examples.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from lbshape.elastic.materials import Material
from lbshape.elastic.polynomial_energy import StVKPolynomialEnergy
from lbshape.shapespace.euclidean_energy import EuclideanExampleEnergy
from lbshape.shapespace.example_shapes import (
    MIN_VOLUME_RATIO,
    energy_elements,
    example_rest_shapes,
)
from lbshape.shapespace.interpolation import TargetSolver
from lbshape.shapespace.projections import block_basis
from lbshape.shapespace.target_table import (
    DEFAULT_TOLERANCE,
    KINDS,
    TableRefused,
    TargetTable,
    build_target_table,
)

log = logging.getLogger(__name__)


class ExampleTargets(NamedTuple):
    """What :func:`tabulate_examples` builds.

    Attributes:
        table: the checked :class:`~lbshape.shapespace.target_table.TargetTable`, or
            None (more than 3 examples, or refused by its check).
        path: (P, 3m) exact targets spread over the weight simplex (P >= 4), for training.
        models: the k exact example energy models.
    """

    table: TargetTable | None
    path: np.ndarray
    models: list


def exact_example_energies(rest_points: Sequence[np.ndarray], tets: np.ndarray,
                           material: Material, basis: np.ndarray) -> list:
    """The exact (all-element) energy model per example rest shape X_k (n, 3).

    StVK: the quartic polynomial
    (:class:`~lbshape.elastic.polynomial_energy.StVKPolynomialEnergy`, O(p⁴) per call);
    other materials: the all-element kernel
    (:class:`~lbshape.shapespace.euclidean_energy.EuclideanExampleEnergy`). Basis B (3n, p).
    """
    Energy = StVKPolynomialEnergy if material.model == "stvk" else EuclideanExampleEnergy
    return [Energy(x, tets, material, basis) for x in rest_points]


def example_path(solver: TargetSolver, table: TargetTable | None, *,
                 points_per_edge: int = 9) -> np.ndarray:
    """(P, p) exact targets spread over the weight simplex: the table's nodes, or
    without a table the exact targets along every edge between two examples."""
    if table is not None and table.nodes.shape[0] >= 4:
        return table.nodes
    offsets = solver.offsets
    k = offsets.shape[0]
    exact = TargetSolver(solver.models, offsets, tolerance=1e-8, max_iterations=100)
    path = [offsets[i] for i in range(k)]
    for i in range(k):
        for j in range(i + 1, k):
            z = offsets[i].copy()
            for t in np.linspace(0.0, 1.0, points_per_edge)[1:-1]:
                w = np.zeros(k)
                w[i], w[j] = 1.0 - t, t
                z = exact.solve(w, start=z).z
                path.append(z)
    while len(path) < 4:
        path.append(offsets[0])
    return np.asarray(path)


def tabulate_examples(
    rest_points: np.ndarray,
    tets: np.ndarray,
    material: Material,
    eigenvectors: np.ndarray,
    coefficients: np.ndarray,
    *,
    mass=None,
    tolerance: float = DEFAULT_TOLERANCE,
) -> ExampleTargets:
    """The precompute's table stage: exact example energies, table, path.

    The energies sum over the elements of
    :func:`~lbshape.shapespace.example_shapes.energy_elements` (a warning names how many
    the examples squeeze).

    Args:
        rest_points: (n, 3) the object's rest shape.
        tets: (t, 4) tetrahedra.
        material: the material.
        eigenvectors: (n, m) the target basis' Φ (free or clamped, see
            :func:`~lbshape.shapespace.clamped_basis.clamped_eigenvectors`).
        coefficients: (k, m, 3) the examples' displacement coefficients.
        mass: (n, n) the volume mass matrix M (m³): the table's error is measured in
            ``‖Φ ⊗ I₃ · Δz‖_M`` (when None, in the coefficients' Euclidean norm, which
            is the same for an M-orthonormal Φ).
        tolerance: the table's accepted error (share of the separation).

    Returns:
        The :class:`ExampleTargets`.
    """
    k = coefficients.shape[0]
    offsets = coefficients.reshape(k, -1)
    rests = example_rest_shapes(rest_points, eigenvectors, coefficients)
    kept = energy_elements(rest_points, tets, rests)
    if kept.size < len(tets):
        log.warning("the examples' reconstructions (m=%d) squeeze %d of %d elements below "
                    "%g %% of their volume: the example energies leave them out",
                    eigenvectors.shape[1], len(tets) - kept.size, len(tets),
                    100 * MIN_VOLUME_RATIO)
    models = exact_example_energies(rests, np.asarray(tets)[kept], material,
                                    block_basis(eigenvectors))
    solver = TargetSolver(models, offsets)
    metric = None
    if mass is not None:
        metric = np.kron(eigenvectors.T @ (mass @ eigenvectors), np.eye(3))
    table = None
    if k in KINDS:
        try:
            table = build_target_table(solver, tolerance=tolerance, metric=metric)
        except TableRefused as exc:
            log.warning("no target table: %s; the target is solved at run time", exc)
    else:
        log.info("%d examples: no target table (at most 3); the target is solved at run time", k)
    return ExampleTargets(table, example_path(solver, table), models)
