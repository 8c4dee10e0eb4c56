"""Finite elements: the DOLFINx bridge, generalized eigenproblems (SLEPc), MPI and PETSc gathers."""

__all__ = [
    "dolfinx_bridge",
    "eigenproblem",
    "mpi",
    "petsc_gather",
]
