"""Procedural sitting teddy (``teddy``, ``teddy-example``) from OCC primitives.

Object frame: up along z, the teddy faces -y (its back is at +y), its left is +x.
An ellipsoidal torso (semi-axes 0.2, 0.16, 0.28 m, centred at the origin) with a
head sphere, two ear spheres and a muzzle sphere fused on top; two arm ellipsoids
hanging from the shoulders; two leg ellipsoids pointing forward (-y) from the hips.
About 0.8 m wide and 0.9 m tall.

Physical volumes (conforming interfaces, ``occ.fragment``): ``torso`` (torso,
head, ears, muzzle), ``left_arm``, ``right_arm``, ``left_leg``, ``right_leg``;
each limb is the part of its primitive outside the torso. Surface ``back``: the
torso's outer surface with y > 0.08 m and |z| < 0.2 m (the fixed region of the
teddy scenes). Mesh with ``lbshape mesh teddy``.
"""

import math

import gmsh

TORSO = (0.2, 0.16, 0.28)  # m, ellipsoid semi-axes, centred at the origin
HEAD = ((0.0, 0.0, 0.40), 0.17)  # centre (m), radius (m)
EARS = (((0.12, 0.0, 0.54), 0.06), ((-0.12, 0.0, 0.54), 0.06))
MUZZLE = ((0.0, -0.14, 0.37), 0.07)
ARM = ((0.25, -0.02, 0.1), (0.16, 0.07, 0.07), 30.0)  # left arm: centre, semi-axes, droop (deg)
LEG = ((0.11, -0.14, -0.22), (0.08, 0.17, 0.08))  # left leg: centre, semi-axes
BACK = (0.08, 0.2)  # the back: y > BACK[0], |z| < BACK[1]


def _ellipsoid(occ, centre, semi_axes) -> int:
    """A unit sphere scaled to ``semi_axes`` and moved to ``centre``; returns its tag."""
    tag = occ.addSphere(0.0, 0.0, 0.0, 1.0)
    occ.dilate([(3, tag)], 0.0, 0.0, 0.0, *semi_axes)
    occ.translate([(3, tag)], *centre)
    return tag


def build(model, h: float) -> None:
    """Build the teddy on ``model`` (the ``gmsh.model`` module); uniform size ``h`` (m)."""
    occ = model.occ
    torso = _ellipsoid(occ, (0.0, 0.0, 0.0), TORSO)
    extras = [(3, occ.addSphere(*centre, radius)) for centre, radius in (HEAD, *EARS, MUZZLE)]
    fused, _ = occ.fuse([(3, torso)], extras)
    if len(fused) != 1:
        raise RuntimeError(f"teddy: torso fusion gave {len(fused)} volumes")
    limbs = {}
    for side, sign in (("left", 1.0), ("right", -1.0)):
        (x, y, z), axes, droop = ARM
        arm = _ellipsoid(occ, (0.0, 0.0, 0.0), axes)
        occ.rotate([(3, arm)], 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, sign * math.radians(droop))
        occ.translate([(3, arm)], sign * x, y, z)
        limbs[f"{side}_arm"] = arm
        (x, y, z), axes = LEG
        limbs[f"{side}_leg"] = _ellipsoid(occ, (sign * x, y, z), axes)
    limb_parts = {}
    for name, tag in limbs.items():
        outside, _ = occ.cut([(3, tag)], fused, removeObject=True, removeTool=False)
        limb_parts[name] = outside
    y_back, z_back = BACK
    back_box = occ.addBox(-0.5, y_back, -z_back, 1.0, 0.5, 2 * z_back)
    tools = [part for parts in limb_parts.values() for part in parts] + [(3, back_box)]
    _, pieces = occ.fragment(fused, tools)
    occ.synchronize()
    # pieces[i] lists the fragments of input i: the torso, then the limb parts, then the box
    torso_pieces = {tag for _, tag in pieces[0]}
    box_pieces = {tag for _, tag in pieces[-1]}
    back_cap = sorted(torso_pieces & box_pieces)
    groups = {"torso": sorted(torso_pieces)}
    i = 1
    for name, parts in limb_parts.items():
        groups[name] = sorted({tag for k in range(len(parts)) for _, tag in pieces[i + k]})
        i += len(parts)
    occ.remove([(3, tag) for tag in sorted(box_pieces - torso_pieces)], recursive=True)
    occ.synchronize()
    if not back_cap or any(not tags for tags in groups.values()):
        raise RuntimeError(f"teddy: unexpected fragments {groups}, back {back_cap}")
    for name, tags in groups.items():
        model.setPhysicalName(3, model.addPhysicalGroup(3, tags), name)
    volumes = model.getEntities(3)
    outer = {tag for _, tag in model.getBoundary(volumes, combined=True, oriented=False)}
    cap_faces = {
        tag for _, tag in model.getBoundary([(3, t) for t in back_cap], oriented=False)
    }
    model.setPhysicalName(2, model.addPhysicalGroup(2, sorted(cap_faces & outer)), "back")
    gmsh.option.setNumber("Mesh.MeshSizeMin", h)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    gmsh.option.setNumber("Mesh.RandomSeed", 1)
