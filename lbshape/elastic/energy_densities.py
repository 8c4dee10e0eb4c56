"""Hyperelastic strain-energy densities in numpy, vectorised over e elements.

Closed forms (no automatic differentiation) of the energies written in UFL in
:mod:`lbshape.elastic.materials`, their first Piola-Kirchhoff stress and its derivative:

* ``Ψ(F)`` in J/m³, shape (e,);
* ``P_ij = ∂Ψ/∂F_ij`` in Pa, shape (e, 3, 3);
* ``A_ijkl = ∂P_ij/∂F_kl`` in Pa, shape (e, 3, 3, 3, 3), major symmetric
  (``A_ijkl = A_klij``).

``F[e, i, j] = ∂x_i/∂X_j`` is the deformation gradient of element e.

**Zero at rest.** Both energies are shifted by a constant so that ``Ψ(I) = 0``.
StVK already is; the stable Neo-Hookean energy of Smith, de Goes and Kim (2018)
has ``Ψ(I) = 9μ'²/(32λ') − μ' ln 2 ≠ 0`` in its textbook form (its stress is zero
at rest). That constant is :func:`rest_energy_density`: the UFL density of
:func:`lbshape.elastic.materials.strain_energy_density_ufl` equals ``Ψ + rest_energy_density``.

The polynomials and ``ln(1 + I_C)`` (``I_C ≥ 0``) are finite for every finite F, so
nothing here produces NaN from finite input, inverted elements included.

**Layout and precision.** These functions sit in the real-time loop, where numpy's
cost is the number of calls and the length of the innermost loop. :class:`DensityModel`
therefore works internally on *element-last* arrays (``Ht[i, j, e]``) so that every
elementwise operation runs over e contiguous values, and it takes the displacement
gradient ``H = F − I`` rather than F: the energies are written in H (Green strain
``E = (H + Hᵀ + HᵀH)/2``; ``I_C − 3`` and ``J − 1`` as polynomials in H), so that
their round-off is relative to the strain, not to 1 — small deformations keep their
digits. The ``*_t`` methods use that layout (for :mod:`lbshape.elastic.element_kernels`);
the public functions take F element-first.
"""

from __future__ import annotations

import math

import numpy as np

from lbshape.elastic.materials import Material
from lbshape.errors import LbshapeError


def _levi_civita_hessian() -> np.ndarray:
    """(81, 9) matrix L with ∂²(det F)/∂F_ij∂F_kl = (L @ F.ravel())[((i*3+j)*3+k)*3+l].

    ``∂²J/∂F_ij∂F_kl = ε_ikn ε_jlq F_nq``, linear in F.
    """
    eps = np.zeros((3, 3, 3))
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        eps[i, j, k], eps[i, k, j] = 1.0, -1.0
    return np.einsum("ikn,jlq->ijklnq", eps, eps).reshape(81, 9)


_HESS_DET = _levi_civita_hessian()
# cof_ij = F_{i+1,j+1} F_{i+2,j+2} − F_{i+1,j+2} F_{i+2,j+1} (indices mod 3): the row
# indices into F flattened (9, e) of the four factors of all nine entries.
_COF_ROWS = np.array(
    [
        [((i + a) % 3) * 3 + (j + b) % 3 for i in range(3) for j in range(3)]
        for a, b in ((1, 1), (2, 2), (1, 2), (2, 1))
    ]
)


class DensityModel:
    """Ψ, P and ∂P/∂F of one material, with its constants computed once.

    Build one with :func:`density_model`. The public methods take F (e, 3, 3); the
    ``*_t`` methods take the element-last displacement gradient ``Ht`` (3, 3, e),
    ``Ht[i, j, e] = F[e, i, j] − δ_ij``, and return ``Pt`` (3, 3, e) and
    ``At`` (3, 3, 3, 3, e) element-last.
    """

    def energy_t(self, Ht: np.ndarray) -> np.ndarray:
        """Ψ (e,) in J/m³, zero at H = 0."""
        raise NotImplementedError

    def stress_t(self, Ht: np.ndarray) -> np.ndarray:
        """Pt (3, 3, e) in Pa."""
        raise NotImplementedError

    def stress_and_derivative_t(self, Ht: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(Pt (3, 3, e), At (3, 3, 3, 3, e)) in Pa, sharing the work."""
        raise NotImplementedError

    def energy(self, F: np.ndarray) -> np.ndarray:
        """Ψ(F) (e,) in J/m³ of F (e, 3, 3)."""
        return self.energy_t(_displacement_gradient_t(F))

    def stress(self, F: np.ndarray) -> np.ndarray:
        """P (e, 3, 3) in Pa of F (e, 3, 3)."""
        Pt = self.stress_t(_displacement_gradient_t(F))
        return np.ascontiguousarray(np.moveaxis(Pt, 2, 0))

    def stress_and_derivative(self, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(P (e, 3, 3), ∂P/∂F (e, 3, 3, 3, 3)) in Pa of F (e, 3, 3)."""
        Pt, At = self.stress_and_derivative_t(_displacement_gradient_t(F))
        return (
            np.ascontiguousarray(np.moveaxis(Pt, 2, 0)),
            np.ascontiguousarray(np.moveaxis(At, 4, 0)),
        )


def _plus_identity(Ht: np.ndarray) -> np.ndarray:
    """Ft = Ht + I, (3, 3, e), a new array."""
    Ft = Ht.copy()
    Ft.reshape(9, -1)[::4] += 1.0
    return Ft


class StVKDensity(DensityModel):
    """St. Venant-Kirchhoff: ``Ψ = μ E:E + λ/2 (tr E)²``, ``E = (FᵀF − I)/2``.

    ``P = F S`` with ``S = 2μE + λ tr(E) I = μ(C − I) + λ tr(E) I``;
    ``A_ijkl = δ_ik S_lj + μ F_il F_kj + μ (FFᵀ)_ik δ_jl + λ F_ij F_kl``.
    """

    def __init__(self, material: Material):
        self.mu = float(material.mu)
        self.lam = float(material.lam)

    @staticmethod
    def _green_strain(Ht):
        """E = (H + Hᵀ + HᵀH)/2, (3, 3, e)."""
        E = np.einsum("ije,ile->jle", Ht, Ht, optimize=False)
        E += Ht
        E += Ht.transpose(1, 0, 2)
        E *= 0.5
        return E

    def energy_t(self, Ht):
        E = self._green_strain(Ht).reshape(9, -1)
        tr_e = E[0] + E[4] + E[8]
        e_e = np.einsum("je,je->e", E, E, optimize=False)
        return self.mu * e_e + (0.5 * self.lam) * tr_e * tr_e

    def _second_piola(self, Ht):
        E = self._green_strain(Ht).reshape(9, -1)
        S = (2.0 * self.mu) * E
        S[::4] += self.lam * (E[0] + E[4] + E[8])
        return S.reshape(Ht.shape)

    def stress_t(self, Ht):
        return np.einsum("ime,mje->ije", _plus_identity(Ht), self._second_piola(Ht), optimize=False)

    def stress_and_derivative_t(self, Ht):
        e = Ht.shape[2]
        Ft = _plus_identity(Ht)
        S = self._second_piola(Ht)
        Pt = np.einsum("ime,mje->ije", Ft, S, optimize=False)
        # FF[i, j, k, l] = F_ij F_kl; FFᵀ is one of its traces
        FF = (Ft.reshape(9, 1, e) * Ft.reshape(1, 9, e)).reshape(3, 3, 3, 3, e)
        B = self.mu * np.einsum("ijkje->ike", FF)
        At = self.lam * FF
        At += self.mu * FF.transpose(0, 3, 2, 1, 4)  # μ F_il F_kj
        # writeable diagonal views: At[i, j, i, l] and At[i, j, k, j]
        np.einsum("ijile->ijle", At)[...] += S  # δ_ik S_lj (S symmetric)
        np.einsum("ijkje->ijke", At)[...] += B[:, None]  # μ B_ik δ_jl
        return Pt, At


class StableNeoHookeanDensity(DensityModel):
    """Stable Neo-Hookean (Smith, de Goes, Kim 2018) with (μ', λ', α) of the material.

    ``Ψ = μ'/2 (I_C − 3) + λ'/2 (J − α)² − μ'/2 ln(1 + I_C) − Ψ_rest``;
    ``P = μ'(1 − 1/(1 + I_C)) F + λ'(J − α) cof F``;
    ``A = μ'(1 − 1/(1 + I_C)) 𝟙 + 2μ'/(1 + I_C)² F⊗F + λ' cof⊗cof + λ'(J − α) ∂²J/∂F²``.
    """

    def __init__(self, material: Material):
        self.mu, self.lam, self.alpha = (float(v) for v in material.stable_nh_parameters)

    @staticmethod
    def _invariants(F9):
        g = np.take(F9, _COF_ROWS, axis=0)  # (4, 9, e)
        cof9 = g[0] * g[1] - g[2] * g[3]
        J = np.einsum("je,je->e", F9[:3], cof9[:3], optimize=False)
        ic = np.einsum("je,je->e", F9, F9, optimize=False)
        return cof9, J, ic

    def energy_t(self, Ht):
        H9 = Ht.reshape(9, -1)
        # cofactor entries (0,0), (0,1), (0,2), (1,1), (2,2) of H
        g = np.take(H9, _COF_ROWS[:, [0, 1, 2, 4, 8]], axis=0)
        c = g[0] * g[1] - g[2] * g[3]
        tr_h = H9[0] + H9[4] + H9[8]
        # J − 1 = tr H + I₂(H) + det H; I_C − 3 = 2 tr H + H:H
        dj = tr_h + c[0] + c[3] + c[4] + (H9[0] * c[0] + H9[1] * c[1] + H9[2] * c[2])
        delta = 2.0 * tr_h + np.einsum("je,je->e", H9, H9, optimize=False)
        # Ψ(F) − Ψ(I) = μ'/2 (δ − ln(1 + δ/4)) + λ'/2 (J − 1)(J − 1 + 2(1 − α))
        return (0.5 * self.mu) * (delta - np.log1p(0.25 * delta)) + (0.5 * self.lam) * dj * (
            dj + 2.0 * (1.0 - self.alpha)
        )

    def stress_t(self, Ht):
        F9 = _plus_identity(Ht).reshape(9, -1)
        cof9, J, ic = self._invariants(F9)
        Pt = (self.mu * (1.0 - 1.0 / (1.0 + ic))) * F9
        Pt += (self.lam * (J - self.alpha)) * cof9
        return Pt.reshape(Ht.shape)

    def stress_and_derivative_t(self, Ht):
        e = Ht.shape[2]
        F9 = _plus_identity(Ht).reshape(9, e)
        cof9, J, ic = self._invariants(F9)
        inv = 1.0 / (1.0 + ic)
        c1 = self.mu * (1.0 - inv)
        cj = self.lam * (J - self.alpha)
        Pt = c1 * F9
        Pt += cj * cof9
        At = _HESS_DET @ F9  # (81, e): ∂²J/∂F²
        At *= cj
        At[::10] += c1
        At = At.reshape(9, 9, e)
        At += ((2.0 * self.mu) * inv * inv * F9).reshape(9, 1, e) * F9.reshape(1, 9, e)
        At += (self.lam * cof9).reshape(9, 1, e) * cof9.reshape(1, 9, e)
        return Pt.reshape(3, 3, e), At.reshape(3, 3, 3, 3, e)


def rest_energy_density(material: Material) -> float:
    """Ψ(I) in J/m³ of the unshifted UFL energy of ``material`` (0 for StVK)."""
    if material.model == "stvk":
        return 0.0
    mu_s, lam_s, alpha = material.stable_nh_parameters
    return 0.5 * lam_s * (1.0 - alpha) ** 2 - 0.5 * mu_s * math.log(4.0)


def density_model(material: Material) -> DensityModel:
    """The numpy density of ``material.model`` with its constants precomputed."""
    if material.model == "stvk":
        return StVKDensity(material)
    return StableNeoHookeanDensity(material)


def _displacement_gradient_t(F: np.ndarray) -> np.ndarray:
    """Element-last H = F − I, (3, 3, e), of F (e, 3, 3)."""
    F = np.asarray(F, dtype=np.float64)
    if F.ndim != 3 or F.shape[1:] != (3, 3):
        raise LbshapeError(f"deformation gradients must have shape (e, 3, 3), got {F.shape}")
    Ht = np.moveaxis(F, 0, 2).copy(order="C")  # always a copy: F is not modified
    Ht.reshape(9, -1)[::4] -= 1.0
    return Ht


def energy_density(material: Material, F: np.ndarray) -> np.ndarray:
    """Strain-energy density Ψ(F) (e,) in J/m³, zero at rest, of F (e, 3, 3)."""
    return density_model(material).energy(F)


def first_piola(material: Material, F: np.ndarray) -> np.ndarray:
    """First Piola-Kirchhoff stress P = ∂Ψ/∂F (e, 3, 3) in Pa of F (e, 3, 3)."""
    return density_model(material).stress(F)


def first_piola_derivative(material: Material, F: np.ndarray) -> np.ndarray:
    """Stress derivative ∂P_ij/∂F_kl (e, 3, 3, 3, 3) in Pa of F (e, 3, 3)."""
    return density_model(material).stress_and_derivative(F)[1]
