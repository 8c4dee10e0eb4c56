"""Hyperelastic materials: parameters and their strain-energy densities in UFL.

Two models:

* ``stvk`` — St. Venant-Kirchhoff (the paper's):
  ``Ψ(F) = μ E:E + λ/2 (tr E)²``, ``E = (FᵀF − I)/2``.
* ``neohookean`` — stable Neo-Hookean (Smith, de Goes, Kim 2018), well defined and
  resisting inversion (J ≤ 0) where StVK collapses:
  ``Ψ(F) = μ'/2 (I_C − 3) + λ'/2 (J − α)² − μ'/2 log(I_C + 1)``,
  ``α = 1 + μ'/λ' − μ'/(4λ')``, with ``μ' = 4μ/3``, ``λ' = λ + 5μ/6`` so that its
  linearisation at rest equals linear elasticity with the given (E, ν). The
  textbook form has a constant rest value ``Ψ(I) = 9μ'²/(32λ') − μ' ln 2`` (its
  stress is zero at rest); it is subtracted so that both models have ``Ψ(I) = 0``.

The numpy per-element kernels of the same energies live in
:mod:`lbshape.elastic.element_kernels`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import ufl

from lbshape.errors import LbshapeError

MaterialModel = Literal["stvk", "neohookean"]
MODELS: tuple[str, ...] = ("stvk", "neohookean")


@dataclass(frozen=True)
class Material:
    """Isotropic hyperelastic material (SI units).

    Attributes:
        model: ``"stvk"`` or ``"neohookean"``.
        young: Young's modulus E in Pa, > 0.
        poisson: Poisson ratio ν in (-1, 0.5).
        density: mass density ρ in kg/m³, > 0.
    """

    model: MaterialModel = "stvk"
    young: float = 1.0e5
    poisson: float = 0.3
    density: float = 1000.0

    def __post_init__(self):
        if self.model not in MODELS:
            raise LbshapeError(f"material model must be one of {MODELS}, got {self.model!r}")
        for name in ("young", "poisson", "density"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise LbshapeError(f"material {name} must be a number, got {value!r}")
        if not self.young > 0:
            raise LbshapeError(f"material young (Young's modulus) must be > 0 Pa, got {self.young}")
        if not -1.0 < self.poisson < 0.5:
            raise LbshapeError(f"material poisson must be in (-1, 0.5), got {self.poisson}")
        if not self.density > 0:
            raise LbshapeError(f"material density must be > 0 kg/m^3, got {self.density}")

    @property
    def mu(self) -> float:
        """Shear modulus μ = E / (2(1+ν)) in Pa."""
        return self.young / (2.0 * (1.0 + self.poisson))

    @property
    def lam(self) -> float:
        """Lamé's first parameter λ = Eν / ((1+ν)(1−2ν)) in Pa."""
        return self.young * self.poisson / ((1.0 + self.poisson) * (1.0 - 2.0 * self.poisson))

    @property
    def stable_nh_parameters(self) -> tuple[float, float, float]:
        """(μ', λ', α) of the stable Neo-Hookean energy (see the module docstring)."""
        mu_s = 4.0 * self.mu / 3.0
        lam_s = self.lam + 5.0 * self.mu / 6.0
        alpha = 1.0 + mu_s / lam_s - mu_s / (4.0 * lam_s)
        return mu_s, lam_s, alpha


def strain_energy_density_ufl(material: Material, F: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    """Ψ(F) in J/m³ as a UFL expression of the deformation gradient F (3×3)."""
    d = F.ufl_shape[0]
    I = ufl.Identity(d)
    if material.model == "stvk":
        E = 0.5 * (F.T * F - I)
        return material.mu * ufl.inner(E, E) + 0.5 * material.lam * ufl.tr(E) ** 2
    mu_s, lam_s, alpha = material.stable_nh_parameters
    Ic = ufl.tr(F.T * F)
    J = ufl.det(F)
    rest = 0.5 * lam_s * (1.0 - alpha) ** 2 - 0.5 * mu_s * math.log(d + 1.0)
    return (
        0.5 * mu_s * (Ic - d) + 0.5 * lam_s * (J - alpha) ** 2
        - 0.5 * mu_s * ufl.ln(Ic + 1.0) - rest
    )


def strain_energy_ufl(material: Material, u: ufl.Coefficient) -> ufl.Form:
    """Total strain energy ∫Ψ(I + ∇u) dx (J) of a displacement ``u`` (vector P1)."""
    F = ufl.Identity(3) + ufl.grad(u)
    return strain_energy_density_ufl(material, F) * ufl.dx
