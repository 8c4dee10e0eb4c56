"""Unit cube [0, 1]^3 (``cube``): tests and degenerate (repeated) LB spectra.

Physical groups: surfaces ``x0``, ``x1``, ``y0``, ``y1``, ``z0``, ``z1`` (the faces
at x = 0, x = 1, ...) and volume ``body``. Mesh with ``lbshape mesh cube``.
"""

import gmsh


def build(model, h: float) -> None:
    """Build the cube on ``model`` (the ``gmsh.model`` module); uniform size ``h`` (m)."""
    occ = model.occ
    body = occ.addBox(0.0, 0.0, 0.0, 1.0, 1.0, 1.0)
    occ.synchronize()
    eps = 1e-6
    for axis, letter in enumerate("xyz"):
        for value in (0.0, 1.0):
            low = [-eps] * 3
            high = [1.0 + eps] * 3
            low[axis], high[axis] = value - eps, value + eps
            faces = model.getEntitiesInBoundingBox(*low, *high, dim=2)
            group = model.addPhysicalGroup(2, [t for _, t in faces])
            model.setPhysicalName(2, group, f"{letter}{int(value)}")
    model.setPhysicalName(3, model.addPhysicalGroup(3, [body]), "body")
    gmsh.option.setNumber("Mesh.MeshSizeMin", h)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    gmsh.option.setNumber("Mesh.RandomSeed", 1)
