"""Planar cross (plus sign) in the xy-plane, thickness along z (``cross``, ``cross-example``).

A horizontal beam along x (x in [-0.5, 0.5]) and a vertical beam along y
(y in [-0.5, 0.5]), both of square section 0.1 m x 0.1 m (z in [-0.05, 0.05]).
Three regions for local examples (the paper's Figure 7), as physical volumes that
share conforming interfaces (``occ.fragment``):

* ``left``: the horizontal arm with x < -0.05,
* ``right``: the horizontal arm with x > 0.05,
* ``middle``: the centre block and the vertical arms (|x| <= 0.05).

Surface group ``centre``: the two faces (z = +-0.05) of the centre block
|x|, |y| <= 0.05, for fixing the cross at its centre. Mesh with ``lbshape mesh cross``.
"""

import gmsh

ARM = 0.5  # m, centre to tip
HALF_SECTION = 0.05  # m


def build(model, h: float) -> None:
    """Build the cross on ``model`` (the ``gmsh.model`` module); uniform size ``h`` (m)."""
    occ = model.occ
    a, s = ARM, HALF_SECTION
    horizontal = occ.addBox(-a, -s, -s, 2 * a, 2 * s, 2 * s)
    vertical = occ.addBox(-s, -a, -s, 2 * s, 2 * a, 2 * s)
    pieces, _ = occ.fragment([(3, horizontal)], [(3, vertical)])
    occ.synchronize()
    regions = {"left": [], "right": [], "middle": []}
    centre_block = None
    for dim, tag in pieces:
        x, y, _ = occ.getCenterOfMass(dim, tag)
        if x < -s:
            regions["left"].append(tag)
        elif x > s:
            regions["right"].append(tag)
        else:
            regions["middle"].append(tag)
            if abs(y) < s:
                centre_block = tag
    if sorted(len(v) for v in regions.values()) != [1, 1, 3] or centre_block is None:
        raise RuntimeError(f"cross: unexpected fragments {pieces}")
    for name, tags in regions.items():
        model.setPhysicalName(3, model.addPhysicalGroup(3, tags), name)
    eps = 1e-6
    centre = [
        tag
        for _, tag in model.getBoundary([(3, centre_block)], oriented=False)
        if abs(abs(occ.getCenterOfMass(2, tag)[2]) - s) < eps
    ]
    model.setPhysicalName(2, model.addPhysicalGroup(2, centre), "centre")
    gmsh.option.setNumber("Mesh.MeshSizeMin", h)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    gmsh.option.setNumber("Mesh.RandomSeed", 1)
