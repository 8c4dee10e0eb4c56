"""L-shaped beam (``l-beam``): a 1 m arm along x and a 0.6 m leg along z, 0.15 m square
section, meeting at x = 0. Stands in for a user's own mesh in the real-time step tests
and benchmark (written to a ``.msh`` file and read back as a user's would be).

Physical groups: volume ``body``. Mesh with ``lbshape mesh l-beam``.
"""

import gmsh


def build(model, h: float) -> None:
    """Build the L-beam on ``model`` (the ``gmsh.model`` module); uniform size ``h`` (m)."""
    occ = model.occ
    arm = occ.addBox(0.0, 0.0, 0.0, 1.0, 0.15, 0.15)
    leg = occ.addBox(0.0, 0.0, 0.0, 0.15, 0.15, 0.6)
    fused, _ = occ.fuse([(3, arm)], [(3, leg)])
    occ.synchronize()
    model.setPhysicalName(3, model.addPhysicalGroup(3, [t for _, t in fused]), "body")
    gmsh.option.setNumber("Mesh.MeshSizeMin", h)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    gmsh.option.setNumber("Mesh.RandomSeed", 1)
