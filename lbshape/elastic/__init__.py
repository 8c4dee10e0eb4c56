"""The reduced elastic space: materials, kernels, modes, modal derivatives, basis, cubature."""

__all__ = [
    "basis",
    "cubature",
    "element_kernels",
    "energy_densities",
    "materials",
    "modal_derivatives",
    "modes",
    "reduced_forces",
]
