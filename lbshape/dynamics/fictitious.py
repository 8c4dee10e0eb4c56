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
because ``Σ M U = 0``. Every run-time quantity is an r- or r²-sized contraction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

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
        # flattened views: the run-time contractions become small matrix products
        r = self.G.shape[0]
        object.__setattr__(self, "_G9", np.ascontiguousarray(self.G.reshape(r, 9)))
        object.__setattr__(self, "_C9", np.ascontiguousarray(self.C.reshape(r * r, 9)))
        object.__setattr__(self, "_S3", np.ascontiguousarray(self.S.reshape(r * r, 3)))
        object.__setattr__(self, "_G_trace", np.einsum("jaa->j", self.G))
        object.__setattr__(self, "_C_trace", np.einsum("jkaa->jk", self.C))

    @property
    def r(self) -> int:
        return int(self.G.shape[0])

    @property
    def inertia0(self) -> np.ndarray:
        """(3, 3) rest inertia tensor about the centre of mass (kg·m²)."""
        return np.trace(self.Y0) * np.eye(3) - self.Y0

    # ------------------------------------------------------------- run time
    def second_moment(self, q: np.ndarray) -> np.ndarray:
        """(3, 3) ``Y(q)`` (kg·m²)."""
        lin = (q @ self._G9).reshape(3, 3)
        quad = (np.outer(q, q).reshape(-1) @ self._C9).reshape(3, 3)
        return self.Y0 + lin + lin.T + quad

    def inertia(self, q: np.ndarray) -> np.ndarray:
        """(3, 3) body-frame inertia tensor ``I(q)`` about the centre of mass (kg·m²)."""
        Y = self.second_moment(q)
        return np.trace(Y) * np.eye(3) - Y

    def relative_momentum(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """(3,) body-frame angular momentum of the deformation ``h(q, q̇)`` (kg·m²/s)."""
        return self.H @ qd + np.outer(q, qd).reshape(-1) @ self._S3

    def euler(self, q: np.ndarray, omega_dot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Euler force (r,) and its tangent ∂/∂q (r, r) for ω̇ (3,) rad/s² (body frame)."""
        r = self.G.shape[0]
        tangent = -(self._S3 @ omega_dot).reshape(r, r)  # ω̇ · S_kj
        return self.H.T @ omega_dot + tangent @ q, tangent

    def coriolis(self, omega: np.ndarray) -> np.ndarray:
        """(r, r) skew matrix Γ(ω) of the Coriolis force ``Γ q̇`` (ω body frame, rad/s)."""
        r = self.G.shape[0]
        return -2.0 * (self._S3 @ omega).reshape(r, r)

    def centrifugal(self, q: np.ndarray, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centrifugal force (r,) and its tangent ∂/∂q (r, r) for ω (3,) rad/s (body frame)."""
        r = self.G.shape[0]
        w2 = float(omega @ omega)
        ww = np.outer(omega, omega).reshape(-1)
        tangent = (self._C9 @ ww).reshape(r, r) - w2 * self._C_trace
        base = self._G9 @ ww - w2 * self._G_trace
        return base + tangent @ q, tangent


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
