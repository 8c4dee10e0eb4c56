"""Between :class:`~lbshape.geometry.mesh.TetMesh` (input vertex order, numpy) and DOLFINx.

DOLFINx reorders vertices and degrees of freedom. Every array that leaves this
module is in the mesh's *input vertex order*; vector fields are node-major
``(3n,)`` (see :mod:`lbshape`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import ufl
from mpi4py import MPI

from lbshape.fem.petsc_gather import gather_csr
from lbshape.geometry.mesh import TetMesh


def to_dolfinx(mesh: TetMesh, comm: MPI.Comm = MPI.COMM_SELF):
    """Create a DOLFINx mesh (P1 geometry). In parallel, rank 0's data is distributed.

    Args:
        mesh: the checked tetrahedral mesh (only rank 0's copy is used).
        comm: the communicator; serial by default.

    Returns:
        ``dolfinx.mesh.Mesh``.
    """
    import dolfinx.mesh

    domain = ufl.Mesh(ufl.VectorElement("Lagrange", ufl.tetrahedron, 1))
    if comm.rank == 0:
        cells, x = mesh.tets.astype(np.int64), mesh.points
    else:
        cells, x = np.empty((0, 4), dtype=np.int64), np.empty((0, 3), dtype=np.float64)
    return dolfinx.mesh.create_mesh(comm, cells, x, domain)


def p1_dof_vertices(V) -> np.ndarray:
    """Input vertex index of every local (owned + ghost) dof block of a P1 space.

    Args:
        V: a (scalar or blocked vector) P1 ``FunctionSpace`` on a mesh made by
            :func:`to_dolfinx`.

    Returns:
        (num_local_blocks,) int64: ``out[d]`` is the input vertex of dof block ``d``.
    """
    msh = V.mesh
    imap = V.dofmap.index_map
    out = np.full(imap.size_local + imap.num_ghosts, -1, dtype=np.int64)
    cell_dofs = V.dofmap.list.array.reshape(-1, 4)
    geom_dofs = msh.geometry.dofmap.array.reshape(-1, 4)
    out[cell_dofs] = np.asarray(msh.geometry.input_global_indices, dtype=np.int64)[geom_dofs]
    return out


def petsc_to_scipy(A, dof_vertices: np.ndarray, block_size: int = 1) -> sp.csr_matrix:
    """Serial PETSc AIJ matrix -> scipy CSR in input vertex order (node-major blocks).

    Args:
        A: assembled ``petsc4py.PETSc.Mat`` (serial).
        dof_vertices: (nb,) from :func:`p1_dof_vertices`.
        block_size: 1 for scalar P1, 3 for vector P1.
    """
    order = dof_to_input_order(dof_vertices, block_size)
    return gather_csr(A, order, comm=MPI.COMM_SELF, size=A.getSize()[0])


def dof_to_input_order(dof_vertices: np.ndarray, block_size: int = 1) -> np.ndarray:
    """(nb*bs,) position in the input-ordered node-major vector of every dof."""
    bs = block_size
    return (dof_vertices[:, None] * bs + np.arange(bs)[None, :]).ravel()


def petsc_vec_to_input_order(values: np.ndarray, dof_vertices: np.ndarray, block_size=1):
    """Serial dof-ordered array (nb*bs,) -> input-ordered node-major array."""
    out = np.empty_like(values)
    out[dof_to_input_order(dof_vertices, block_size)] = values
    return out


def input_order_to_dofs(values: np.ndarray, dof_vertices: np.ndarray, block_size=1):
    """Input-ordered node-major array -> local dof-ordered array (nb*bs,)."""
    return np.asarray(values)[dof_to_input_order(dof_vertices, block_size)]
