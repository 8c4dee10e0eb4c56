"""Intrinsic LB basis alignment: a functional map from corresponding descriptor functions.

In the spirit of the coupled quasi-harmonic bases of Kovnatsky et al. 2013 (the paper's
[21]) and of functional maps: each shape keeps its own LB eigenpairs, and the map is
found from functions known on both shapes *without the shapes overlapping in space*.

Descriptor functions (``d`` columns on each shape, :func:`descriptor_functions`):

* heat-kernel signatures ``h_t(x) = Σᵢ exp(−λᵢ t) φᵢ(x)²`` at the times
  ``t = τ / λ₁`` for τ in :data:`HKS_TIMES`, each shape with its *own* λ₁ and its own
  m eigenpairs (intrinsic, sign invariant, independent of size and of uniform
  stretching of the spectrum);
* the normalised principal-axis coordinates ``ξₖ = (x − c)·aₖ / σₖ`` (k = 1..3),
  with aₖ the object's principal axes (the example already in the object's frame,
  :func:`lbshape.shapespace.frames.align_to_object`), c and σₖ the shape's *own* centre
  of mass and standard deviation along aₖ (:func:`normalised_coordinates`), and their
  monomials up to degree :data:`MAX_DEGREE`. They break what an intrinsic descriptor
  cannot (a bar's two ends, a reflection of a symmetric shape) and map a 4:1 bar's axis
  onto an 8:1 bar's;
* matched segments: tent functions of each ξₖ centred at :data:`SEGMENTS` points evenly
  spaced over ``[−SEGMENT_SPAN, SEGMENT_SPAN]`` (spacing = half-width). Without them the
  higher longitudinal modes of a long bar were left unresolved (see
  ``docs/decisions.md``).

Every column is made M-mean free and scaled to unit M-norm on its own shape. Their LB
coefficients are ``A = Φᵀ M D`` (object: m × d; example: m_ex × d, m_ex ≥ m).

The map. C (m_ex × m, orthonormal columns, so that ``Φ_ex C ≈ Φ_obj`` as in
:class:`~lbshape.shapespace.alignment.BasisAlignment`) minimises the coupling energy

    E(C) = ‖C A_obj − A_ex‖² + μ ‖C Λ_obj − Λ_ex C‖²,

with ``Λ = diag(ln(λ / λ₁)) / ln(λ_obj,m / λ_obj,1)`` (each shape's eigenvalues in
units of its own λ₁, on a log scale so that a stretch, which moves some modes by a
constant factor, costs a bounded amount; scaled so that the object's largest is 1) and
μ = :data:`COMMUTATIVITY`. The unconstrained minimiser separates by rows of C (one
m × m solve each); its polar factor starts :data:`ITERATIONS` majorise–minimise steps
on the orthonormal matrices,
``C ← polar(A_ex A_objᵀ + μ (2 Λ_ex C Λ_obj + (L − Λ_ex²) C))`` with L = max Λ_ex²
(the linearised maximiser of a convex minorant of −E: with Λ ≥ 0 the steps never
increase E). :func:`refine_pointwise` then runs
:data:`REFINEMENTS` steps of spectral ICP (nearest neighbours between the two shapes'
own spectral embeddings).

Scores. The choice between this map and the overlay is made elsewhere
(:mod:`lbshape.shapespace.basis_choice`: a residual on normalised coordinates);
:func:`spectral_distortion` measures how far a map moves modes along the spectrum (the
refusal of genuinely different shapes).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from lbshape.errors import LbshapeError
from lbshape.shapespace.alignment import polar
from lbshape.shapespace.frames import BodyFrame, volume_moments
from lbshape.spectral.spectrum import LBSpectrum

#: heat-kernel signature times in units of 1/λ₁ (each shape its own λ₁)
HKS_TIMES = (0.5, 1.0, 2.0)
#: highest degree of the monomials of the normalised coordinates
MAX_DEGREE = 3
#: matched segments: tent functions of each normalised coordinate at SEGMENTS centres
#: evenly spaced over [−SEGMENT_SPAN, SEGMENT_SPAN]
SEGMENTS = 8
SEGMENT_SPAN = 1.7
#: weight μ of the commutativity term ‖C Λ_obj − Λ_ex C‖²
COMMUTATIVITY = 1.0
#: spectral ICP steps (:func:`refine_pointwise`) after the coupled solve
REFINEMENTS = 5
#: majorise–minimise steps on the orthonormal matrices after the first polar factor
ITERATIONS = 200


@dataclass(frozen=True)
class CouplingProblem:
    """The data of the coupling energy E(C) (see the module docstring).

    Attributes:
        A_obj: (m, d) object descriptor coefficients.
        A_ex: (m_ex, d) example descriptor coefficients.
        lam_obj: (m,) the object's normalised eigenvalues Λ_obj.
        lam_ex: (m_ex,) the example's Λ_ex.
        mu: weight of the commutativity term.
    """

    A_obj: np.ndarray
    A_ex: np.ndarray
    lam_obj: np.ndarray
    lam_ex: np.ndarray
    mu: float

    def energy(self, C: np.ndarray) -> float:
        """E(C) for C (m_ex, m)."""
        descriptor = C @ self.A_obj - self.A_ex
        commutator = C * self.lam_obj[None, :] - self.lam_ex[:, None] * C
        return float((descriptor**2).sum() + self.mu * (commutator**2).sum())


def principal_extent(points: np.ndarray, tets: np.ndarray,
                     frame: BodyFrame) -> tuple[np.ndarray, np.ndarray]:
    """(centre of mass (3,) in m, σ (3,) in m): a shape's own centre and standard
    deviations along ``frame``'s axes (exact volume moments of the linear tetrahedra)."""
    points = np.asarray(points, dtype=float)
    volume, first, second = volume_moments(points, tets)
    if not volume > 0.0:
        raise LbshapeError("the shape has zero volume; it has no normalised coordinates")
    centre = first / volume
    S = second / volume - np.outer(centre, centre)
    sigma = np.sqrt(np.maximum(np.einsum("ik,ij,jk->k", frame.axes, S, frame.axes), 1e-300))
    return centre, sigma


def normalised_coordinates(points: np.ndarray, tets: np.ndarray, frame: BodyFrame) -> np.ndarray:
    """(n, 3) ``ξₖ = (x − c)·aₖ / σₖ``: coordinates along ``frame``'s axes about the
    shape's own centre of mass, divided by its own σₖ (:func:`principal_extent`)."""
    centre, sigma = principal_extent(points, tets, frame)
    return ((np.asarray(points, dtype=float) - centre) @ frame.axes) / sigma


def descriptor_functions(spectrum: LBSpectrum, coordinates: np.ndarray, m: int) -> np.ndarray:
    """(n, d) the descriptor columns of one shape (see the module docstring).

    Args:
        spectrum: the shape's own LB eigenpairs; the first m are used for the
            heat-kernel signatures.
        coordinates: (n, 3) its :func:`normalised_coordinates`.
        m: eigenpairs used in the signatures (the object's m on both shapes).
    """
    lam = spectrum.eigenvalues[:m]
    phi = spectrum.eigenvectors[:, :m]
    columns = [(phi**2) @ np.exp(-lam * (tau / lam[0])) for tau in HKS_TIMES]
    xi = np.asarray(coordinates, dtype=float)
    for degree in range(1, MAX_DEGREE + 1):
        columns += [np.prod(xi[:, list(powers)], axis=1)
                    for powers in itertools.combinations_with_replacement(range(3), degree)]
    centres = np.linspace(-SEGMENT_SPAN, SEGMENT_SPAN, SEGMENTS)
    width = centres[1] - centres[0]
    columns += [np.maximum(1.0 - np.abs(xi[:, k] - c) / width, 0.0)
                for k in range(3) for c in centres]
    return _normalise(np.column_stack(columns), spectrum.mass)


def _normalise(D: np.ndarray, M: sp.spmatrix) -> np.ndarray:
    """Columns of D made M-mean free and of unit M-norm."""
    weights = np.asarray(M.sum(axis=0)).ravel()
    D = D - (weights @ D) / weights.sum()
    norms = np.sqrt(np.einsum("ij,ij->j", D, M @ D))
    return D / np.maximum(norms, 1e-300)


def coupling_problem(object_spectrum: LBSpectrum, object_descriptors: np.ndarray,
                     example_spectrum: LBSpectrum, example_descriptors: np.ndarray, *,
                     mu: float = COMMUTATIVITY) -> CouplingProblem:
    """The coupling energy's data from both shapes' spectra and descriptors (n_·, d)."""
    phi_o, phi_e = object_spectrum.eigenvectors, example_spectrum.eigenvectors
    m = phi_o.shape[1]
    A_obj = phi_o.T @ (object_spectrum.mass @ object_descriptors)
    A_ex = phi_e.T @ (example_spectrum.mass @ example_descriptors)
    lam_o = np.log(object_spectrum.eigenvalues / object_spectrum.eigenvalues[0])
    lam_e = np.log(example_spectrum.eigenvalues / example_spectrum.eigenvalues[0])
    scale = lam_o[m - 1]
    return CouplingProblem(A_obj, A_ex, lam_o / scale, lam_e / scale, float(mu))


def solve_map(problem: CouplingProblem, *, iterations: int = ITERATIONS) -> np.ndarray:
    """The orthonormal C (m_ex, m) that (locally) minimises E (module docstring)."""
    A_o, A_e, lo, le, mu = (problem.A_obj, problem.A_ex, problem.lam_obj, problem.lam_ex,
                            problem.mu)
    gram, rhs = A_o @ A_o.T, A_e @ A_o.T
    C = np.empty_like(rhs)
    for i in range(rhs.shape[0]):
        C[i] = np.linalg.solve(gram + mu * np.diag((le[i] - lo) ** 2), rhs[i])
    C = polar(C)
    bound = float((le**2).max())
    for _ in range(iterations):
        C = polar(rhs + mu * (2.0 * le[:, None] * C * lo[None, :] + (bound - le**2)[:, None] * C))
    return C


def intrinsic_map(object_spectrum: LBSpectrum, object_coordinates: np.ndarray,
                  example_spectrum: LBSpectrum, example_coordinates: np.ndarray) -> np.ndarray:
    """The intrinsic map C (m_ex, m): descriptors, coupled solve, spectral ICP.

    Args:
        object_spectrum: the object's m eigenpairs.
        object_coordinates: (n_o, 3) the object's :func:`normalised_coordinates`.
        example_spectrum: the example's m_ex ≥ m eigenpairs (at the object's volume).
        example_coordinates: (n_e, 3) the example's, in the object's frame.
    """
    m = object_spectrum.eigenvalues.shape[0]
    problem = coupling_problem(
        object_spectrum, descriptor_functions(object_spectrum, object_coordinates, m),
        example_spectrum, descriptor_functions(example_spectrum, example_coordinates, m))
    C = solve_map(problem)
    return refine_pointwise(C, object_spectrum.eigenvectors, example_spectrum.eigenvectors,
                            example_spectrum.mass)


def spectral_distortion(C: np.ndarray, object_eigenvalues: np.ndarray,
                        example_eigenvalues: np.ndarray) -> float:
    """``sqrt(Σᵢⱼ Cᵢⱼ² (ln λ̂_ex,i − ln λ̂_obj,j)² / m)`` with λ̂ = λ / λ₁ (each shape's own):
    the RMS over object modes of how far (in log eigenvalue) a map moves a mode.
    0 for a map between two shapes with the same normalised spectrum; ln(k²) where it
    sends modes onto modes k times finer."""
    lo = np.log(np.asarray(object_eigenvalues) / object_eigenvalues[0])
    le = np.log(np.asarray(example_eigenvalues)[: C.shape[0]] / example_eigenvalues[0])
    return float(np.sqrt((C**2 * (le[:, None] - lo[None, :]) ** 2).sum() / C.shape[1]))


def refine_pointwise(C: np.ndarray, phi_obj: np.ndarray, phi_ex: np.ndarray, mass_ex: sp.spmatrix,
                     *, iterations: int = REFINEMENTS) -> np.ndarray:
    """Spectral ICP: C ← polar(Φ_exᵀ M_ex Π Φ_obj) with Π the nearest-neighbour map of
    the example's rows of ``Φ_ex C`` among the object's rows of ``Φ_obj`` (each shape's
    own spectral embedding; nothing geometric). Φ_obj (n_o, m), Φ_ex (n_e, m_ex),
    C (m_ex, m), M_ex (n_e, n_e)."""
    tree = cKDTree(phi_obj)
    for _ in range(iterations):
        _, nearest = tree.query(phi_ex @ C)
        C = polar(phi_ex.T @ (mass_ex @ phi_obj[nearest]))
    return C
