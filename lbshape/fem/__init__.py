"""The finite-element bridge: DOLFINx meshes, generalized eigenproblems (SLEPc), MPI helpers."""

__all__ = [
    "dolfinx_bridge",
    "eigenproblem",
    "mpi",
]
