"""Parametric meshes of simple solids, for tests, benchmarks and analytic checks.

``structured_box`` is a Kuhn (6 tets per hexahedron) subdivision: deterministic and
uniformly refinable, which convergence-rate tests need. ``box`` and ``cylinder``
are unstructured gmsh meshes of the same solids.
"""

from __future__ import annotations

import numpy as np

from lbshape.geometry.mesh import (
    TetMesh,
    check_mesh,
    gmsh_model,
    mesh_from_gmsh_model,
    signed_volumes,
)

# The 6 tetrahedra of the unit cube sharing the diagonal (0,0,0)-(1,1,1), in terms of
# the local corner index i + 2j + 4k.
_KUHN = np.array(
    [[0, 1, 3, 7], [0, 1, 5, 7], [0, 2, 3, 7], [0, 2, 6, 7], [0, 4, 5, 7], [0, 4, 6, 7]]
)


def structured_box(
    size: tuple[float, float, float] = (1.0, 1.0, 1.0),
    divisions: tuple[int, int, int] = (4, 4, 4),
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> TetMesh:
    """A box ``[o, o + size]`` split into ``nx*ny*nz`` cubes of 6 tetrahedra each.

    Args:
        size: edge lengths (a, b, c) in metres.
        divisions: cells per axis (nx, ny, nz), each >= 1.
        origin: the minimum corner.

    Returns:
        TetMesh with ``(nx+1)(ny+1)(nz+1)`` vertices and ``6 nx ny nz`` tets.
    """
    nx, ny, nz = (int(d) for d in divisions)
    axes = [
        np.linspace(o, o + s, d + 1)
        for o, s, d in zip(origin, size, (nx, ny, nz), strict=True)
    ]
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    points = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])

    def vid(i, j, k):
        return (i * (ny + 1) + j) * (nz + 1) + k

    i, j, k = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    i, j, k = i.ravel(), j.ravel(), k.ravel()
    corners = np.stack(
        [vid(i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1)) for c in range(8)], axis=1
    )
    tets = corners[:, _KUHN].reshape(-1, 4)
    negative = signed_volumes(points, tets) < 0  # half of the Kuhn tets are left-handed
    tets[negative] = tets[negative][:, [0, 2, 1, 3]]
    return check_mesh(TetMesh(points, tets), source="structured box")


def box(
    size: tuple[float, float, float] = (1.0, 1.0, 1.0),
    h: float = 0.2,
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> TetMesh:
    """Unstructured gmsh tet mesh of a box with target edge length ``h`` (metres)."""
    with gmsh_model("box") as gmsh:
        gmsh.model.occ.addBox(*origin, *size)
        return _mesh_current_model(gmsh, h, "box")


def cylinder(radius: float = 0.1, length: float = 1.0, h: float = 0.05) -> TetMesh:
    """Unstructured tet mesh of a cylinder along z, base centred at the origin."""
    with gmsh_model("cylinder") as gmsh:
        gmsh.model.occ.addCylinder(0, 0, 0, 0, 0, length, radius)
        return _mesh_current_model(gmsh, h, "cylinder")


def ball(radius: float = 0.5, h: float = 0.15) -> TetMesh:
    """Unstructured gmsh tet mesh of a ball of ``radius`` about the origin (metres)."""
    with gmsh_model("ball") as gmsh:
        gmsh.model.occ.addSphere(0.0, 0.0, 0.0, radius)
        return _mesh_current_model(gmsh, h, "ball")


def _mesh_current_model(gmsh, h: float, name: str) -> TetMesh:
    gmsh.model.occ.synchronize()
    gmsh.option.setNumber("Mesh.MeshSizeMin", h)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    gmsh.option.setNumber("Mesh.RandomSeed", 1)
    gmsh.model.mesh.generate(3)
    return check_mesh(mesh_from_gmsh_model(gmsh.model, source=name), source=name)
