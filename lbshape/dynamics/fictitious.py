"""Reduced tensors of a free body's rigid frame: inertia and fictitious forces.

**Frame convention.** A vertex of rest position ``X_i`` (object frame, m) sits in
the world at ``x_i = c + R (X̄_i + U_i q)``, with ``X̄_i = X_i − X_cm`` the rest
position relative to the rest centre of mass, ``U_i`` (3, r) the vertex's rows of
the reduced basis (body frame), ``c`` (3,) the centre of mass and ``R`` (3, 3) the
body-to-world rotation. U is M-orthogonal to the six rigid motions of the rest
shape (``Σ M U = 0``: the deformation keeps the centre of mass at ``c`` and has no
linear momentum; ``Σ M X̄ × U = 0``: no angular momentum to first order in q).

With the consistent mass ``M = M₁ ⊗ I₃`` the kinetic energy ``½ ẋᵀ M ẋ`` of
``x = c + R y``, ``y = X̄ + U q`` and the body angular velocity ω (``Ṙ = R [ω]×``) is

``T = ½ m_tot |ċ|² + ½ ωᵀ I(q) ω + ωᵀ h(q, q̇) + ½ |q̇|²``,

with the second moment ``Y(q) = Σ M y yᵀ = Y₀ + Σ_j q_j (G_j + G_jᵀ) + Σ_jk q_j q_k C_jk``,
the inertia tensor ``I(q) = tr(Y) I₃ − Y`` and the relative angular momentum
``h(q, q̇) = Σ M y × U q̇ = (H + Σ_j q_j S_j) q̇``. Sums ``Σ M a bᵀ`` are the
mass-weighted bilinear forms ``Σ_il (M₁)_il a_i b_lᵀ``. The tensors are

* ``Y₀`` (3, 3): ``Σ M X̄ X̄ᵀ`` (m²·kg);
* ``G`` (r, 3, 3): ``G_j = Σ M U_j X̄ᵀ`` (m·√kg);
* ``C`` (r, r, 3, 3): ``C_jk = Σ M U_j U_kᵀ`` (dimensionless, U is M-orthonormal);
* ``H`` (3, r): ``H_k = Σ M X̄ × U_k`` (≈ 0 by the convention above);
* ``S`` (r, r, 3): ``S_jk = Σ M U_j × U_k = ε : C_jk``, antisymmetric in j, k.

The Euler–Lagrange equations of the deformation (body frame) then read

``q̈ + f_int(q) + F_euler + F_coriolis + F_centrifugal = Uᵀ Rᵀ f_ext``,

``F_euler_j = ω̇ · h_j(q)``, ``h_j(q) = H_j + Σ_k q_k S_kj``;
``F_coriolis = Γ(ω) q̇``, ``Γ_jk = 2 ω · S_kj`` (skew: does no work);
``F_centrifugal_j = ωᵀ A_j ω − |ω|² tr A_j``, ``A_j(q) = G_j + Σ_k q_k C_jk``
(``= U_jᵀ M (ω × (ω × y))``); and the linear inertial force ``Uᵀ M Rᵀ c̈`` vanishes
because ``Σ M U = 0``. Every run-time quantity is an r- or r²-sized contraction,
computed by the compiled kernels of this module (:func:`inertia_momentum_into`,
:func:`fictitious_into`, :func:`coriolis_into`) into arrays the caller owns; the
methods of :class:`FrameTensors` return new arrays from the same kernels. The kernels
take the tensors as one :class:`FrameArrays` (named views of one buffer,
:attr:`FrameTensors.kernel_arrays`; a kernel called from Python takes its ``data`` and
rebuilds the views with :func:`frame_arrays`, see :mod:`lbshape.dynamics.kernels`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from lbshape._jit import njit, py_func
from lbshape.dynamics.kernels import check_size, take
from lbshape.errors import LbshapeError

#: largest accepted ``‖Σ M U_j‖ / √m_tot`` (translation content of the basis)
TRANSLATION_TOLERANCE = 1e-6

#: Levi-Civita symbol ε_abc
LEVI_CIVITA = np.zeros((3, 3, 3))
LEVI_CIVITA[0, 1, 2] = LEVI_CIVITA[1, 2, 0] = LEVI_CIVITA[2, 0, 1] = 1.0
LEVI_CIVITA[0, 2, 1] = LEVI_CIVITA[2, 1, 0] = LEVI_CIVITA[1, 0, 2] = -1.0


@dataclass(frozen=True)
class FrameTensors:
    """The precomputed reduced tensors of a free body (see the module docstring).

    Attributes:
        mass: total mass m_tot (kg).
        center: (3,) rest centre of mass in the object frame (m).
        Y0: (3, 3) rest second moment about the centre of mass (kg·m²).
        G: (r, 3, 3) linear second-moment tensor.
        C: (r, r, 3, 3) quadratic second-moment tensor.
        H: (3, r) linear relative angular momentum tensor.
        S: (r, r, 3) quadratic relative angular momentum tensor.
        translation: (r, 3) ``Σ M U_j`` (kg·√kg⁻¹; zero for a rigid-free basis).
    """

    mass: float
    center: np.ndarray
    Y0: np.ndarray
    G: np.ndarray
    C: np.ndarray
    H: np.ndarray
    S: np.ndarray
    translation: np.ndarray

    def __post_init__(self):
        # the kernels' buffer: flattened tensors, so the run-time contractions become
        # small matrix products
        r = self.G.shape[0]
        data = np.zeros(FrameArrays.size(r))
        arrays = py_func(frame_arrays)(data, r)
        arrays.mass[0] = self.mass
        arrays.Y0[:] = self.Y0
        arrays.G9[:] = self.G.reshape(r, 9)
        arrays.C9[:] = self.C.reshape(r * r, 9)
        arrays.S3[:] = self.S.reshape(r * r, 3)
        arrays.H[:] = self.H
        arrays.G_trace[:] = np.einsum("jaa->j", self.G)
        arrays.C_trace[:] = np.einsum("jkaa->jk", self.C)
        object.__setattr__(self, "_data", data)

    @property
    def r(self) -> int:
        return int(self.G.shape[0])

    def leading(self, count: int) -> FrameTensors:
        """The tensors of the basis's leading ``count`` columns."""
        if not 0 < count <= self.r:
            raise LbshapeError(f"a frame of {self.r} columns has no leading {count}")
        return self.columns(np.arange(count))

    def columns(self, indices: np.ndarray) -> FrameTensors:
        """The tensors of the sub-basis of the columns ``indices`` (k,), in that order:
        the blocks of these (every tensor is a sum over the columns' coordinates, so a
        sub-basis's are its blocks)."""
        i = np.asarray(indices, dtype=np.int64)
        if i.ndim != 1 or not i.size or i.min() < 0 or i.max() >= self.r:
            raise LbshapeError(f"a frame of {self.r} columns has no columns {i}")
        return FrameTensors(self.mass, self.center, self.Y0, self.G[i], self.C[np.ix_(i, i)],
                            self.H[:, i], self.S[np.ix_(i, i)], self.translation[i])

    @property
    def inertia0(self) -> np.ndarray:
        """(3, 3) rest inertia tensor about the centre of mass (kg·m²)."""
        return np.trace(self.Y0) * np.eye(3) - self.Y0

    @property
    def kernel_arrays(self) -> FrameArrays:
        """The tensors as the compiled kernels take them (:class:`FrameArrays`)."""
        return py_func(frame_arrays)(self._data, self.r)

    # ------------------------------------------------------------- run time
    def inertia(self, q: np.ndarray) -> np.ndarray:
        """(3, 3) body-frame inertia tensor ``I(q)`` about the centre of mass (kg·m²)."""
        inertia, h = np.zeros((3, 3)), np.zeros(3)
        q = np.asarray(q, dtype=float)
        _inertia_momentum(q, np.zeros_like(q), self._data, inertia, h)
        return inertia

    def relative_momentum(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """(3,) body-frame angular momentum of the deformation ``h(q, q̇)`` (kg·m²/s)."""
        inertia, h = np.zeros((3, 3)), np.zeros(3)
        _inertia_momentum(np.asarray(q, dtype=float), np.asarray(qd, dtype=float), self._data,
                          inertia, h)
        return h

    def euler(self, q: np.ndarray, omega_dot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Euler force (r,) and its tangent ∂/∂q (r, r) for ω̇ (3,) rad/s² (body frame)."""
        return self._forces(q, np.zeros(3), omega_dot)

    def coriolis(self, omega: np.ndarray) -> np.ndarray:
        """(r, r) skew matrix Γ(ω) of the Coriolis force ``Γ q̇`` (ω body frame, rad/s)."""
        r = self.r
        out = np.zeros((r, r))
        _coriolis(np.asarray(omega, dtype=float), self._data, np.zeros((r, r)), out)
        return out

    def centrifugal(self, q: np.ndarray, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centrifugal force (r,) and its tangent ∂/∂q (r, r) for ω (3,) rad/s (body frame)."""
        return self._forces(q, omega, np.zeros(3))

    def _forces(self, q, omega, omega_dot) -> tuple[np.ndarray, np.ndarray]:
        r = self.r
        f, K = np.zeros(r), np.zeros((r, r))
        _fictitious(np.asarray(q, dtype=float), np.asarray(omega, dtype=float),
                    np.asarray(omega_dot, dtype=float), self._data, f, K)
        return f, K


class FrameArrays(NamedTuple):
    """The frame tensors as the compiled kernels take them: views of the one buffer
    ``data`` (:func:`frame_arrays`), G, C and S flattened."""

    #: the buffer every field below views
    data: np.ndarray
    #: (1,) total mass m_tot (kg)
    mass: np.ndarray
    #: (3, 3) rest second moment
    Y0: np.ndarray
    #: (r, 9) ``G`` flattened, ``G9[j, 3a + b] = G_j[a, b]``
    G9: np.ndarray
    #: (r², 9) ``C`` flattened, row ``j r + k``
    C9: np.ndarray
    #: (r², 3) ``S`` flattened, row ``j r + k``
    S3: np.ndarray
    #: (3, r) ``H``
    H: np.ndarray
    #: (r,) ``tr G_j``
    G_trace: np.ndarray
    #: (r, r) ``tr C_jk``
    C_trace: np.ndarray

    @staticmethod
    def size(r: int) -> int:
        """Floats in the buffer of a basis of r columns."""
        return 1 + 9 + 9 * r + 9 * r * r + 3 * r * r + 3 * r + r + r * r


# ------------------------------------------------------------------ compiled kernels
@njit
def frame_arrays(data, r):
    """The :class:`FrameArrays` views of a buffer of :meth:`FrameArrays.size` floats."""
    mass, at = take(data, 0, 1)
    Y0, at = take(data, at, 9)
    G9, at = take(data, at, 9 * r)
    C9, at = take(data, at, 9 * r * r)
    S3, at = take(data, at, 3 * r * r)
    H, at = take(data, at, 3 * r)
    G_trace, at = take(data, at, r)
    C_trace, at = take(data, at, r * r)
    check_size(data, at)
    return FrameArrays(data, mass, Y0.reshape((3, 3)), G9.reshape((r, 9)),
                       C9.reshape((r * r, 9)), S3.reshape((r * r, 3)), H.reshape((3, r)),
                       G_trace, C_trace.reshape((r, r)))


@njit
def inertia_momentum_into(q, qd, frame, inertia, h):
    """Write ``I(q)`` (3, 3) into ``inertia`` and ``h(q, q̇)`` (3,) into ``h`` (``frame``
    a :class:`FrameArrays`)."""
    Y0, G9, C9, S3, H = frame.Y0, frame.G9, frame.C9, frame.S3, frame.H
    r = q.shape[0]
    Y = inertia  # Y(q) first, then I = tr(Y) I₃ − Y in place
    for a in range(3):
        for b in range(3):
            Y[a, b] = Y0[a, b]
    for j in range(r):
        for a in range(3):
            for b in range(3):
                Y[a, b] += q[j] * (G9[j, 3 * a + b] + G9[j, 3 * b + a])
    for j in range(r):
        if q[j] == 0.0:
            continue
        for k in range(r):
            w = q[j] * q[k]
            row = j * r + k
            for a in range(3):
                for b in range(3):
                    Y[a, b] += w * C9[row, 3 * a + b]
    trace = Y[0, 0] + Y[1, 1] + Y[2, 2]
    for a in range(3):
        for b in range(3):
            Y[a, b] = -Y[a, b]
        Y[a, a] += trace
    for c in range(3):
        value = 0.0
        for k in range(r):
            value += H[c, k] * qd[k]
        h[c] = value
    for j in range(r):
        if q[j] == 0.0:
            continue
        for k in range(r):
            w = q[j] * qd[k]
            row = j * r + k
            for c in range(3):
                h[c] += w * S3[row, c]


@njit
def fictitious_parts_into(omega, omega_dot, frame, force0, T):
    """The Euler and centrifugal forces at (ω, ω̇), linear in q: their value at q = 0
    (r,) into ``force0`` and their tangent (r, r) into ``T`` (``frame`` a
    :class:`FrameArrays`); the forces at q are ``force0 + T q`` (:func:`add_fictitious`).

    Euler: ``H_jᵀ ω̇ + Σ_k q_k (−ω̇ · S_jk)``; centrifugal: ``G_j : ωωᵀ − |ω|² tr G_j +
    Σ_k q_k (C_jk : ωωᵀ − |ω|² tr C_jk)``.
    """
    G9, C9, S3, H = frame.G9, frame.C9, frame.S3, frame.H
    G_trace, C_trace = frame.G_trace, frame.C_trace
    r = force0.shape[0]
    w2 = omega[0] * omega[0] + omega[1] * omega[1] + omega[2] * omega[2]
    for j in range(r):
        value = 0.0
        for c in range(3):
            value += H[c, j] * omega_dot[c]
        for a in range(3):
            for b in range(3):
                value += G9[j, 3 * a + b] * omega[a] * omega[b]
        force0[j] = value - w2 * G_trace[j]
        for k in range(r):
            row = j * r + k
            tangent = -(S3[row, 0] * omega_dot[0] + S3[row, 1] * omega_dot[1]
                        + S3[row, 2] * omega_dot[2]) - w2 * C_trace[j, k]
            for a in range(3):
                for b in range(3):
                    tangent += C9[row, 3 * a + b] * omega[a] * omega[b]
            T[j, k] = tangent


@njit
def add_fictitious(q, force0, T, f, K):
    """Add the Euler and centrifugal forces ``force0 + T q`` (r,) to ``f`` and their
    tangent T (r, r) to ``K`` (:func:`fictitious_parts_into`)."""
    r = q.shape[0]
    for j in range(r):
        value = force0[j]
        for k in range(r):
            K[j, k] += T[j, k]
            value += T[j, k] * q[k]
        f[j] += value


@njit
def fictitious_into(q, omega, omega_dot, frame, f, K):
    """Add the Euler and centrifugal forces (r,) at (q, ω, ω̇) to ``f`` and their tangent
    (r, r) to ``K`` (``frame`` a :class:`FrameArrays`; see :func:`fictitious_parts_into`)."""
    r = q.shape[0]
    force0, T = np.empty(r), np.empty((r, r))
    fictitious_parts_into(omega, omega_dot, frame, force0, T)
    add_fictitious(q, force0, T, f, K)


@njit
def coriolis_into(omega, frame, damping, out):
    """``out = damping + Γ(ω)`` (r, r), ``Γ_jk = −2 ω · S_jk`` (the Coriolis matrix;
    ``frame`` a :class:`FrameArrays`)."""
    S3 = frame.S3
    r = out.shape[0]
    for j in range(r):
        for k in range(r):
            row = j * r + k
            out[j, k] = damping[j, k] - 2.0 * (S3[row, 0] * omega[0] + S3[row, 1] * omega[1]
                                                + S3[row, 2] * omega[2])


# the kernels above for the methods of FrameTensors: the buffer in, the views rebuilt
@njit
def _inertia_momentum(q, qd, data, inertia, h):
    inertia_momentum_into(q, qd, frame_arrays(data, q.shape[0]), inertia, h)


@njit
def _fictitious(q, omega, omega_dot, data, f, K):
    fictitious_into(q, omega, omega_dot, frame_arrays(data, q.shape[0]), f, K)


@njit
def _coriolis(omega, data, damping, out):
    coriolis_into(omega, frame_arrays(data, out.shape[0]), damping, out)


def frame_tensors(points: np.ndarray, tets: np.ndarray, mass: sp.spmatrix,
                  U: np.ndarray) -> FrameTensors:
    """Build the :class:`FrameTensors` of a free body (one O(n r²) pass).

    Args:
        points: (n, 3) rest positions (m).
        tets: (t, 4) tetrahedra (only for the error message's size check).
        mass: (3n, 3n) consistent node-major mass (kg).
        U: (3n, r) basis, ``Uᵀ M U = I``, M-orthogonal to the rigid motions.

    Raises:
        LbshapeError: shapes that do not match, or a basis that carries translation
            (``‖Σ M U_j‖ > TRANSLATION_TOLERANCE √m_tot``).
    """
    points = np.asarray(points, dtype=float)
    n = points.shape[0]
    U = np.asarray(U, dtype=float)
    if U.ndim != 2 or U.shape[0] != 3 * n or mass.shape != (3 * n, 3 * n):
        raise LbshapeError(f"frame tensors need U (3n, r) and M (3n, 3n) for n={n}, "
                           f"got {U.shape} and {mass.shape}")
    r = U.shape[1]
    M1 = sp.csr_matrix(mass)[0::3, 0::3]  # scalar mass (n, n), kg
    total = float(M1.sum())
    ones = np.ones(n)
    center = (M1 @ ones) @ points / total
    Xbar = points - center
    MX = M1 @ Xbar  # (n, 3)
    Ur = U.reshape(n, 3, r)
    MU = (M1 @ Ur.reshape(n, 3 * r)).reshape(n, 3, r)
    Y0 = Xbar.T @ MX
    G = np.einsum("iaj,ib->jab", MU, Xbar)
    C = np.einsum("iaj,ibk->jkab", Ur, MU)
    C = 0.5 * (C + C.transpose(1, 0, 3, 2))  # exact symmetry C_jk = C_kjᵀ
    S = np.einsum("cab,jkab->jkc", LEVI_CIVITA, C)
    H = np.einsum("cab,kba->ck", LEVI_CIVITA, G)
    translation = MU.sum(axis=0).T  # (r, 3)
    worst = float(np.abs(translation).max()) / np.sqrt(total) if r else 0.0
    if worst > TRANSLATION_TOLERANCE:
        raise LbshapeError(
            f"the reduced basis is not free of rigid translation (|sum M U| / sqrt(m) = "
            f"{worst:.2e} > {TRANSLATION_TOLERANCE:g}); a free body needs a basis computed "
            "without fixed vertices"
        )
    return FrameTensors(total, center, Y0, G, C, H, S, translation)
