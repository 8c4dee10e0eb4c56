"""Cylindrical bar: radius 0.1128 m (the cuboid bar's cross-section area), z in [0, 1].

Used as the bar-cylinder scene's example shape and, coarse, as the demo's example.
Physical groups: surface ``top`` (z = 1), surface ``bottom`` (z = 0), volume
``body``. Mesh with ``lbshape mesh bar-cylinder``.
"""

import gmsh

RADIUS = 0.1128  # m; pi r^2 = 0.04 m^2 = 0.2 m x 0.2 m
LENGTH = 1.0  # m


def build(model, h: float) -> None:
    """Build the bar on ``model`` (the ``gmsh.model`` module); uniform size ``h`` (m)."""
    occ = model.occ
    body = occ.addCylinder(0.0, 0.0, 0.0, 0.0, 0.0, LENGTH, RADIUS)
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
