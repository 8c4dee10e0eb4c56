"""The reduced elastic space: materials, kernels, modes, modal derivatives, basis, cubature,
the exact polynomial StVK energy and forces."""

__all__ = [
    "basis",
    "cubature",
    "element_kernels",
    "energy_densities",
    "materials",
    "modal_derivatives",
    "modes",
    "polynomial_energy",
    "polynomial_forces",
    "reduced_forces",
]
