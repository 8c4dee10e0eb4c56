"""Exact reduced StVK force and tangent as polynomials in q (Barbič & James 2005).

For a St. Venant-Kirchhoff material and displacements ``u = U q`` (U (3n, r)) the
elastic energy summed over **every** element is a quartic polynomial in q,

    E(q) = ½ qᵀ K q + Σ_abc C_abc q_a q_b q_c + Σ_abcd D_abcd q_a q_b q_c q_d,

(:class:`~lbshape.elastic.polynomial_energy.StVKPolynomialEnergy` builds K, C, D once, an
n-sized pass), so the reduced force ``f = ∇E`` is cubic and the tangent ``∇²E``
quadratic in q — with no cubature error at all. With C and D made fully symmetric and
stored over index pairs ``(a ≤ b)`` (P = r(r+1)/2 of them), one product
``z = D̃ w`` with ``w_(cd) = q_c q_d`` (times 2 off the diagonal) gives both the quartic
part of the tangent (``12 z_(ab)``) and of the force (``4 Σ_b z_(ab) q_b``), and
``y = C̃ q`` the cubic parts (``6 y_(ab)``, ``3 Σ_b y_(ab) q_b``). A call costs about
P² + P r multiply-adds (r = 30: 0.23 M; two BLAS matrix-vector products), independent
of the mesh. The product with D̃ is memory-bound: it is a symmetric BLAS product
(``dsymv``) that reads one triangle of D̃ (r = 30: 0.9 MB of its 1.7 MB), measured
1.7–2.2× faster than the general product at r = 30–60 and equal to it to round-off.

:class:`PolynomialForceModel` has the interface the reduced engines use
(``force_and_tangent``, the allocation-free ``force_and_tangent_into``, ``energy``).
Only StVK has this form; other materials keep the cubature. Building the coefficients
costs about 7 t P² multiply-adds (t elements), so :func:`resolve_force_model` keeps the
cubature for a mesh where that exceeds :data:`POLYNOMIAL_BUILD_FLOPS`.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import blas

from lbshape._jit import njit
from lbshape.elastic.materials import Material
from lbshape.elastic.polynomial_energy import StVKPolynomialEnergy
from lbshape.errors import LbshapeError

#: the reduced force models: exact polynomials (StVK only) or the trained cubature
FORCE_MODELS: tuple[str, ...] = ("polynomial", "cubature")
#: what a scene may ask for (``auto``: :func:`resolve_force_model`)
FORCE_CHOICES: tuple[str, ...] = ("auto",) + FORCE_MODELS
#: largest build cost (multiply-adds, ≈ 7 t P²) for which ``auto`` picks the polynomials
#: (about 25 s at the BLAS rate of one core; room for teddy-local's anchored read-out
#: responses, r 72 on 1,896 elements, ``docs/decisions.md``, 2026-11-28)
POLYNOMIAL_BUILD_FLOPS = 1.2e11


def polynomial_build_flops(n_tets: int, r: int) -> float:
    """Multiply-adds of building the quartic coefficients: 7 t P², P = r(r+1)/2."""
    pairs = r * (r + 1) // 2
    return 7.0 * n_tets * pairs * pairs


def check_force_choice(choice: str, material_model: str) -> None:
    """Raise :class:`~lbshape.errors.LbshapeError` (one line) for a ``reduced.forces``
    value that is unknown or asks for the polynomials of a material other than StVK."""
    if choice not in FORCE_CHOICES:
        raise LbshapeError(f"reduced.forces must be one of {FORCE_CHOICES}, got {choice!r}")
    if choice == "polynomial" and material_model != "stvk":
        raise LbshapeError(f"reduced.forces = 'polynomial' needs the stvk material, not "
                           f"{material_model!r}")


def resolve_force_model(choice: str, material_model: str, n_tets: int, r: int) -> str:
    """The force model a scene uses: ``choice`` unless ``auto``, which picks
    ``polynomial`` for StVK when its build costs at most :data:`POLYNOMIAL_BUILD_FLOPS`,
    else ``cubature``.

    Raises:
        LbshapeError: see :func:`check_force_choice`.
    """
    check_force_choice(choice, material_model)
    if choice != "auto":
        return choice
    if material_model == "stvk" and polynomial_build_flops(n_tets, r) <= POLYNOMIAL_BUILD_FLOPS:
        return "polynomial"
    return "cubature"


class PolynomialForceModel:
    """The exact reduced StVK force and tangent of ``u = U q`` over all elements.

    Args:
        rest_points: (n, 3) rest positions in m.
        tets: (t, 4) tetrahedra.
        material: an ``stvk`` material.
        U: (3n, r) node-major reduced basis.
        max_bytes: bound (bytes) on the temporaries of one chunk of elements while the
            coefficients are summed.
        comm: MPI communicator that splits the element chunks (None: serial).

    Attributes:
        r: number of reduced coordinates.
        K: (r, r) tangent at rest.
        pair_cubic: (P, r) ``C̃[(a, b), c]``, C fully symmetric, pairs a ≤ b.
        pair_quartic: (P, P) ``D̃[(a, b), (c, d)]``, D fully symmetric.
    """

    def __init__(self, rest_points: np.ndarray, tets: np.ndarray, material: Material,
                 U: np.ndarray, *, max_bytes: int | None = None, comm=None):
        kwargs = {} if max_bytes is None else {"max_bytes": max_bytes}
        energy = StVKPolynomialEnergy(rest_points, tets, material, U, comm=comm,
                                      structured=False, **kwargs)  # refuses other materials
        C = energy.cubic_tensor()  # (r, r, r), symmetric in the last two indices
        D = energy.quartic_tensor()  # (r, r, r, r), symmetric in a ↔ b, c ↔ d, (ab) ↔ (cd)
        first, second = np.triu_indices(energy.p)
        C_sym = (C + C.transpose(1, 2, 0) + C.transpose(2, 0, 1)) / 3.0
        D_sym = (D + D.transpose(0, 2, 1, 3) + D.transpose(0, 3, 2, 1)) / 3.0
        self._store(energy.K, C_sym[first, second, :], D_sym[first, second][:, first, second])

    @classmethod
    def from_arrays(cls, K: np.ndarray, pair_cubic: np.ndarray,
                    pair_quartic: np.ndarray) -> PolynomialForceModel:
        """The model from its stored coefficients (K (r, r), C̃ (P, r), D̃ (P, P))."""
        model = cls.__new__(cls)
        model._store(K, pair_cubic, pair_quartic)
        return model

    def _store(self, K: np.ndarray, pair_cubic: np.ndarray, pair_quartic: np.ndarray) -> None:
        """Keep the coefficients (checked against r) and the run-time work arrays."""
        r = K.shape[0]
        first, second = np.triu_indices(r)
        if pair_cubic.shape != (first.size, r) or pair_quartic.shape != (first.size,) * 2:
            raise LbshapeError(f"polynomial force coefficients of shapes {pair_cubic.shape} "
                               f"and {pair_quartic.shape} do not fit r = {r}")
        self.r = r
        self.K = np.ascontiguousarray(K, dtype=float)
        self.pair_cubic = np.ascontiguousarray(pair_cubic, dtype=float)
        self.pair_quartic = np.ascontiguousarray(pair_quartic, dtype=float)
        self._quartic_fortran = self.pair_quartic.T  # the same symmetric matrix, F-order
        self._first, self._second = first.astype(np.int64), second.astype(np.int64)
        self._w, self._y, self._z = (np.zeros(first.size) for _ in range(3))

    @property
    def n_coordinates(self) -> int:
        return self.r

    def energy(self, q: np.ndarray) -> float:
        """E(q) in J for q (r,): ``½ qᵀKq + w·(C̃ q) + w·(D̃ w)``."""
        q = np.ascontiguousarray(q, dtype=float)
        w = self._w
        _pairs(q, self._first, self._second, w)
        return float(0.5 * q @ (self.K @ q) + w @ (self.pair_cubic @ q)
                     + w @ (self.pair_quartic @ w))

    def force_and_tangent(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(force (r,), tangent (r, r)) at q (r,): ``∇E`` and ``∇²E``."""
        f, K = np.zeros(self.r), np.zeros((self.r, self.r))
        self.force_and_tangent_into(np.asarray(q, dtype=float), f, K)
        return f, K

    def force(self, q: np.ndarray) -> np.ndarray:
        return self.force_and_tangent(q)[0]

    def tangent(self, q: np.ndarray) -> np.ndarray:
        return self.force_and_tangent(q)[1]

    def force_and_tangent_into(self, q: np.ndarray, f: np.ndarray, K: np.ndarray) -> None:
        """The run-time path: force (r,) into ``f``, tangent (r, r) into ``K``; compiled,
        preallocated, no checks."""
        first, second = self._first, self._second
        _pairs(q, first, second, self._w)
        np.dot(self.pair_cubic, q, out=self._y)
        # D̃ is symmetric: its transpose is the same matrix in Fortran order, so dsymv
        # reads it in place (one triangle) and writes z in place
        blas.dsymv(1.0, self._quartic_fortran, self._w, beta=0.0, y=self._z, overwrite_y=1)
        _assemble(q, self.K, first, second, self._y, self._z, f, K)


@njit
def _pairs(q, first, second, w):
    """w_(cd) = q_c q_d, doubled off the diagonal (the sum over ordered pairs)."""
    for p in range(first.shape[0]):
        c, d = first[p], second[p]
        w[p] = q[c] * q[d] * (1.0 if c == d else 2.0)


@njit
def linear_part_into(A, x, f, K):
    """``K = A`` and ``f = A x`` (A (r, r), x (r,)): the linear part a force model's
    nonlinear terms are then added to."""
    r = x.shape[0]
    for a in range(r):
        value = 0.0
        for b in range(r):
            K[a, b] = A[a, b]
            value += A[a, b] * x[b]
        f[a] = value


@njit
def _assemble(q, K0, first, second, y, z, f, K):
    """Force and tangent from y = C̃ q and z = D̃ w (pairs): ``K = K₀ + 6y + 12z``,
    ``f = K₀ q + Σ_b (3 y_ab + 4 z_ab) q_b``."""
    linear_part_into(K0, q, f, K)
    for p in range(first.shape[0]):
        a, b = first[p], second[p]
        K[a, b] += 6.0 * y[p] + 12.0 * z[p]
        if a != b:
            K[b, a] = K[a, b]
        value = 3.0 * y[p] + 4.0 * z[p]
        f[a] += value * q[b]
        if a != b:
            f[b] += value * q[a]
