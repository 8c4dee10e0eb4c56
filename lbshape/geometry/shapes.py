"""Registry of the built-in shapes: the gmsh scripts in ``meshes/`` and their sizes.

Each script ``meshes/<script>.py`` defines ``build(model, h)``: it builds the
geometry with the OCC kernel on ``model`` (the ``gmsh.model`` module), sets named
physical groups and the mesh size from the one size parameter ``h`` (metres), and
does not mesh. :func:`build_shape` runs a script in a fresh gmsh model, generates
the 3D mesh and returns a checked :class:`~lbshape.geometry.mesh.TetMesh`; physical group
names survive as ``cell_groups`` (volumes) and ``vertex_groups`` (all groups).

The default sizes put the vertex and tetrahedron counts within
:data:`TARGET_RTOL` of the sizes of the paper's Table 2 (DESIGN.md section 5).
"""

from __future__ import annotations

import importlib.util
import logging
import math
import numbers
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import (
    TetMesh,
    check_mesh,
    gmsh_model,
    mesh_from_gmsh_model,
    write_gmsh_model,
)
from lbshape.io.paths import MESHES_DIR

log = logging.getLogger(__name__)

#: folder of the gmsh scripts
#: relative window around the target counts that the default sizes must hit
TARGET_RTOL = 0.2
#: refuse sizes whose estimated tetrahedron count exceeds this (protects memory)
MAX_ESTIMATED_TETS = 2_000_000
#: above this estimated tetrahedron count the volume is meshed by gmsh's HXT algorithm
#: (``Mesh.Algorithm3D = 10``) instead of the default Delaunay: the 100k-vertex bar
#: (h = 6.5 mm) takes 5-8 s instead of 30-90 s; every default size stays below it. HXT is
#: not reproducible to the vertex (104.5k-104.7k vertices at h = 6.5 mm from run to run,
#: one thread); the precompute caches the mesh it used
HXT_ESTIMATED_TETS = 500_000



@dataclass(frozen=True)
class ShapeSpec:
    """A registered shape.

    Attributes:
        script: file name of the gmsh script in ``meshes/``.
        default_size: the size parameter ``h`` (m) used when none is given.
        description: one line for listings.
        target_vertices: vertex count the default size aims at.
        target_tets: tetrahedron count the default size aims at, or None.
        groups: names of the physical groups the script defines.
    """

    script: str
    default_size: float
    description: str
    target_vertices: int
    target_tets: int | None = None
    groups: tuple[str, ...] = ()


_BAR_GROUPS = ("top", "bottom", "body")
_CROSS_GROUPS = ("left", "right", "middle", "centre")
_TEDDY_GROUPS = ("torso", "left_arm", "right_arm", "left_leg", "right_leg", "back")

#: the built-in shapes by name
SHAPES: dict[str, ShapeSpec] = {
    "bar-cuboid": ShapeSpec(
        "bar_cuboid.py", 0.0665, "0.2 x 0.2 x 1 m bar along z (object of the bar scenes)",
        327, 1053, _BAR_GROUPS),
    "bar-cylinder": ShapeSpec(
        "bar_cylinder.py", 0.0263, "cylinder r = 0.1128 m, 1 m along z (bar-cylinder example)",
        2478, None, _BAR_GROUPS),
    "cross": ShapeSpec(
        "cross.py", 0.029, "planar cross of two 1 m beams, 0.1 m section, three regions",
        1561, 4912, _CROSS_GROUPS),
    "cross-example": ShapeSpec(
        "cross.py", 0.0214, "the cross, finer (example of the cross scene)",
        3172, None, _CROSS_GROUPS),
    "car": ShapeSpec(
        "car.py", 0.0765, "procedural car: chassis, cabin, rounded roof, four wheels",
        727, 2369, ("body",)),
    "car-example": ShapeSpec(
        "car.py", 0.066, "the car, finer (example of the car scene)",
        1019, None, ("body",)),
    "teddy": ShapeSpec(
        "teddy.py", 0.07, "procedural sitting teddy with limb regions and its back",
        591, 1755, _TEDDY_GROUPS),
    "teddy-example": ShapeSpec(
        "teddy.py", 0.0188, "the teddy, finer (example of the teddy scenes)",
        11193, None, _TEDDY_GROUPS),
    "demo-bar": ShapeSpec(
        "bar_cuboid.py", 0.15, "the cuboid bar, coarse (object of the demo)",
        90, None, _BAR_GROUPS),
    "demo-cylinder": ShapeSpec(
        "bar_cylinder.py", 0.075, "the cylinder bar, coarse (example of the demo)",
        225, None, _BAR_GROUPS),
    "cube": ShapeSpec(
        "cube.py", 0.16, "unit cube [0, 1]^3 (tests, repeated LB eigenvalues)",
        450, None, ("x0", "x1", "y0", "y1", "z0", "z1", "body")),
    "l-beam": ShapeSpec(
        "l_beam.py", 0.06, "L-shaped beam, 1 m arm along x, 0.6 m leg along z (a user's mesh "
        "in the real-time step tests)", 380, None, ("body",)),
}


def shape_names() -> list[str]:
    """The registered shape names, in registry order."""
    return list(SHAPES)


def get_shape(name: str) -> ShapeSpec:
    """The :class:`ShapeSpec` of ``name``.

    Raises:
        LbshapeError: unknown name (the message lists the valid names).
    """
    try:
        return SHAPES[name]
    except (KeyError, TypeError):
        raise LbshapeError(
            f"unknown shape '{name}'; valid names: {', '.join(SHAPES)}"
        ) from None


def build_shape(name: str, *, size: float | None = None) -> TetMesh:
    """Mesh a registered shape.

    Args:
        name: a key of :data:`SHAPES`.
        size: the size parameter ``h`` in metres (default: the shape's default_size).

    Returns:
        The checked tetrahedral mesh with the script's physical groups.

    Raises:
        LbshapeError: unknown name, a size that is not a finite positive number or
            is too small to mesh, or a mesh that fails :func:`check_mesh`.
    """
    with _generated(name, size) as (gmsh, source):
        mesh = mesh_from_gmsh_model(gmsh.model, source=source)
    return check_mesh(mesh, source=source)


def write_shape(name: str, path: str | Path, *, size: float | None = None) -> TetMesh:
    """Mesh a registered shape and write it as a gmsh ``.msh`` (format 4.1) file.

    The file is written atomically (a temporary file in the target folder, then a
    rename), so a failure leaves no partial file; the folder is created if needed.

    Args:
        name: a key of :data:`SHAPES`.
        path: output file, ending in ``.msh``.
        size: the size parameter ``h`` in metres (default: the shape's default_size).

    Returns:
        The checked mesh that was written (as :func:`build_shape` returns it).

    Raises:
        LbshapeError: as :func:`build_shape`, or a path that is not ``.msh`` or
            cannot be written.
    """
    path = Path(path)
    if path.suffix.lower() != ".msh":
        raise LbshapeError(f"{path}: output must be a .msh file")
    with _generated(name, size) as (gmsh, source):
        mesh = check_mesh(mesh_from_gmsh_model(gmsh.model, source=source), source=source)
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.option.setNumber("Mesh.Binary", 0)
        gmsh.option.setNumber("Mesh.SaveAll", 0)  # the physical groups cover the body
        write_gmsh_model(gmsh, path)
    log.info("wrote %s (%d vertices, %d tets)", path, mesh.n_vertices, mesh.n_tets)
    return mesh


def geometry_volume(name: str, *, size: float | None = None) -> float:
    """Exact volume (m^3) of a shape's CAD geometry, before meshing.

    The reference for a mesh's volume: meshes of curved shapes approach it as
    O(h^2). ``size`` matters only for scripts whose geometry depends on it (none
    of the built-in ones).

    Raises:
        LbshapeError: unknown name or bad size.
    """
    with _geometry(name, size) as (gmsh, _, _):
        return _occ_volume(gmsh)


def _check_size(name: str, size: float | None, spec: ShapeSpec) -> float:
    if size is None:
        return spec.default_size
    if isinstance(size, bool) or not isinstance(size, numbers.Real):
        raise LbshapeError(f"shape '{name}': size must be a number in metres, got {size!r}")
    h = float(size)
    if not math.isfinite(h) or h <= 0.0:
        raise LbshapeError(f"shape '{name}': size must be a finite positive length, got {h:g}")
    return h


def _load_script(spec: ShapeSpec) -> ModuleType:
    path = MESHES_DIR / spec.script
    if not path.is_file():
        raise LbshapeError(f"shape script not found: {path}")
    module_spec = importlib.util.spec_from_file_location(f"lbshape_meshes_{path.stem}", path)
    module = importlib.util.module_from_spec(module_spec)
    module_spec.loader.exec_module(module)
    if not callable(getattr(module, "build", None)):
        raise LbshapeError(f"{path}: defines no build(model, h) function")
    return module


@contextmanager
def _geometry(name: str, size: float | None) -> Iterator[tuple[ModuleType, float, str]]:
    """Yield ``(gmsh, h, source)`` with the shape's geometry built in a fresh model.

    The gmsh options a script may touch start from
    :data:`lbshape.geometry.mesh.GMSH_OPTION_BASELINE` and
    are restored to the caller's values afterwards; the model is cleared on exit.
    """
    spec = get_shape(name)
    h = _check_size(name, size, spec)
    script = _load_script(spec)
    source = f"shape '{name}' (h = {h:g} m)"
    with gmsh_model(name) as gmsh:
        script.build(gmsh.model, h)
        gmsh.model.occ.synchronize()
        yield gmsh, h, source


@contextmanager
def _generated(name: str, size: float | None) -> Iterator[tuple[ModuleType, str]]:
    """Yield ``(gmsh, source)`` with the shape meshed in a fresh model; clean up after."""
    started = time.perf_counter()
    with _geometry(name, size) as (gmsh, h, source):
        estimate = 6.0 * math.sqrt(2.0) * _occ_volume(gmsh) / h**3  # regular tets of edge h
        if estimate > MAX_ESTIMATED_TETS:
            raise LbshapeError(
                f"{source}: size too small, about {estimate:.3g} tetrahedra "
                f"(limit {MAX_ESTIMATED_TETS:.3g})"
            )
        if estimate > HXT_ESTIMATED_TETS:
            gmsh.option.setNumber("Mesh.Algorithm3D", 10)
        try:
            gmsh.model.mesh.generate(3)
        except Exception as exc:  # gmsh raises a bare Exception with its message
            raise LbshapeError(f"{source}: gmsh could not mesh it ({exc})") from None
        log.info("meshed %s in %.2f s", source, time.perf_counter() - started)
        yield gmsh, source


def _occ_volume(gmsh) -> float:
    return float(sum(gmsh.model.occ.getMass(d, t) for d, t in gmsh.model.getEntities(3)))
