"""Procedural car-like body (``car``, ``car-example``): one connected solid.

Object frame: length along x (front at +x), width along y, up along z, wheels
standing on the ground plane z = 0. A chassis box, a cabin box with a rounded
roof (a circular segment 0.1 m high) and four wheel cylinders that overlap the
chassis sides, fused into a single volume ``body``; overall 1.0 m x 0.56 m x 0.5 m.
Mesh with ``lbshape mesh car``.
"""

import gmsh

CHASSIS = (-0.5, -0.22, 0.08, 1.0, 0.44, 0.2)  # box x, y, z, dx, dy, dz in m
CABIN = (-0.3, -0.18, 0.28, 0.5, 0.36, 0.12)
ROOF_HEIGHT = 0.1  # m, above the cabin box
WHEEL_RADIUS = 0.12  # m; axles at z = WHEEL_RADIUS
WHEEL_WIDTH = 0.1  # m, of which WHEEL_OVERLAP is inside the chassis
WHEEL_OVERLAP = 0.04  # m
WHEEL_X = 0.31  # m, axles at x = +-WHEEL_X


def build(model, h: float) -> None:
    """Build the car on ``model`` (the ``gmsh.model`` module); uniform size ``h`` (m)."""
    occ = model.occ
    chassis = occ.addBox(*CHASSIS)
    cabin = occ.addBox(*CABIN)
    x0, y0, z0, dx, dy, dz = CABIN
    # rounded roof: the part of a cylinder along y above the cabin, a segment of
    # chord dx and height ROOF_HEIGHT
    radius = ((dx / 2) ** 2 + ROOF_HEIGHT**2) / (2 * ROOF_HEIGHT)
    top = z0 + dz
    roll = occ.addCylinder(x0 + dx / 2, y0, top + ROOF_HEIGHT - radius, 0.0, dy, 0.0, radius)
    above = occ.addBox(x0, y0, top, dx, dy, ROOF_HEIGHT)
    roof, _ = occ.intersect([(3, roll)], [(3, above)])
    wheels = []
    half_width = CHASSIS[4] / 2
    for x in (-WHEEL_X, WHEEL_X):
        for start, width in (
            (half_width - WHEEL_OVERLAP, WHEEL_WIDTH),
            (-half_width + WHEEL_OVERLAP, -WHEEL_WIDTH),
        ):
            wheel = occ.addCylinder(x, start, WHEEL_RADIUS, 0.0, width, 0.0, WHEEL_RADIUS)
            wheels.append((3, wheel))
    body, _ = occ.fuse([(3, chassis)], [(3, cabin), *roof, *wheels])
    occ.synchronize()
    if len(body) != 1:
        raise RuntimeError(f"car: fusion gave {len(body)} volumes instead of one")
    model.setPhysicalName(3, model.addPhysicalGroup(3, [body[0][1]]), "body")
    gmsh.option.setNumber("Mesh.MeshSizeMin", h)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    gmsh.option.setNumber("Mesh.RandomSeed", 1)
