"""Cuboid bar: 0.2 x 0.2 x 1.0 m, x, y in [-0.1, 0.1], z in [0, 1] (``bar-cuboid``).

Physical groups: surface ``top`` (z = 1, fixed in the scenes), surface ``bottom``
(z = 0, twisted) and volume ``body``. Mesh with ``lbshape mesh bar-cuboid``.
"""

import gmsh

HALF_WIDTH = 0.1  # m
LENGTH = 1.0  # m


def build(model, h: float) -> None:
    """Build the bar on ``model`` (the ``gmsh.model`` module); uniform size ``h`` (m)."""
    occ = model.occ
    body = occ.addBox(-HALF_WIDTH, -HALF_WIDTH, 0.0, 2 * HALF_WIDTH, 2 * HALF_WIDTH, LENGTH)
    occ.synchronize()
    eps = 1e-6
    top = model.getEntitiesInBoundingBox(-1, -1, LENGTH - eps, 1, 1, LENGTH + eps, dim=2)
    bottom = model.getEntitiesInBoundingBox(-1, -1, -eps, 1, 1, eps, dim=2)
    for dim, tags, name in (
        (2, [t for _, t in top], "top"),
        (2, [t for _, t in bottom], "bottom"),
        (3, [body], "body"),
    ):
        model.setPhysicalName(dim, model.addPhysicalGroup(dim, tags), name)
    gmsh.option.setNumber("Mesh.MeshSizeMin", h)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    gmsh.option.setNumber("Mesh.RandomSeed", 1)
