"""Registry of the built-in shapes: the gmsh scripts in ``meshes/`` and their sizes.

Each script ``meshes/<script>.py`` defines ``build(model, h)``: it builds the
geometry with the OCC kernel on ``model`` (the ``gmsh.model`` module), sets named
physical groups and the mesh size from the one size parameter ``h`` (metres), and
does not mesh. :func:`build_shape` runs a script in a fresh gmsh model, generates
the 3D mesh and returns a checked :class:`~lbshape.geometry.mesh.TetMesh`; physical group
names survive as ``cell_groups`` (volumes) and ``vertex_groups`` (all groups).

A user's own script follows the same convention and is run by path
(:func:`build_script`, :func:`write_script`): ``build(model, h)`` and, optionally,
``DEFAULT_SIZE`` (m), the ``h`` used when no size is given. Everything that goes
wrong in it (missing file, no ``build``, an exception while loading or building, no
volume, a mesh that fails the checks) is a one-line
:class:`~lbshape.errors.LbshapeError` naming the script.

The default sizes put the vertex and tetrahedron counts within
:data:`TARGET_RTOL` of the sizes of the paper's Table 2 (DESIGN.md section 5).
"""

from __future__ import annotations

import hashlib
import importlib.util
import logging
import math
import numbers
import sys
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

#: the file suffix of a gmsh Python script (built-in or a user's)
SCRIPT_SUFFIX = ".py"
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
    return _build(_registered(name, size))


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
    return _write(_registered(name, size), path)


def is_script_path(text: str | Path) -> bool:
    """True if ``text`` names a gmsh Python script (ends in :data:`SCRIPT_SUFFIX`)."""
    return Path(text).suffix.lower() == SCRIPT_SUFFIX


def build_script(path: str | Path, *, size: float | None = None) -> TetMesh:
    """Mesh a user's gmsh Python script, written as the built-in ones in ``meshes/``.

    The script defines ``build(model, h)`` (the geometry on ``model``, the
    ``gmsh.model`` module, physical groups and the mesh size from ``h``; it does not
    initialise gmsh or generate the mesh) and may define ``DEFAULT_SIZE`` (m), the
    ``h`` used when ``size`` is None. Its folder is on ``sys.path`` while it loads,
    so it may import modules beside it.

    Args:
        path: the script (``.py``).
        size: ``h`` in metres (default: the script's ``DEFAULT_SIZE``).

    Returns:
        The checked tetrahedral mesh with the script's physical groups.

    Raises:
        LbshapeError: (one line) a missing file, a script that raises on loading or in
            ``build``, defines no ``build(model, h)``, has no size, builds no volume,
            cannot be meshed, or whose mesh fails :func:`check_mesh`.
    """
    return _build(_user_script(path, size))


def write_script(path: str | Path, out: str | Path, *, size: float | None = None) -> TetMesh:
    """Mesh a user's gmsh script (:func:`build_script`) and write ``out`` (``.msh``,
    format 4.1, with the script's physical groups), atomically."""
    return _write(_user_script(path, size), out)


def geometry_volume(name: str, *, size: float | None = None) -> float:
    """Exact volume (m^3) of a shape's CAD geometry, before meshing.

    The reference for a mesh's volume: meshes of curved shapes approach it as
    O(h^2). ``size`` matters only for scripts whose geometry depends on it (none
    of the built-in ones).

    Raises:
        LbshapeError: unknown name or bad size.
    """
    with _geometry(_registered(name, size)) as gmsh:
        return _occ_volume(gmsh)


@dataclass(frozen=True)
class _Script:
    """A loaded gmsh script with the size to run it at (``source`` names it in messages)."""

    module: ModuleType
    h: float
    source: str
    model_name: str


def _check_size(what: str, size: float | None, default: float | None) -> float:
    if size is None:
        size = default
    if isinstance(size, bool) or not isinstance(size, numbers.Real):
        raise LbshapeError(f"{what}: size must be a number in metres, got {size!r}")
    h = float(size)
    if not math.isfinite(h) or h <= 0.0:
        raise LbshapeError(f"{what}: size must be a finite positive length, got {h:g}")
    return h


def _registered(name: str, size: float | None) -> _Script:
    spec = get_shape(name)
    h = _check_size(f"shape '{name}'", size, spec.default_size)
    module = _load_module(MESHES_DIR / spec.script, f"lbshape_meshes_{Path(spec.script).stem}")
    return _Script(module, h, f"shape '{name}' (h = {h:g} m)", name)


def _user_script(path: str | Path, size: float | None) -> _Script:
    path = Path(path).expanduser()
    if not is_script_path(path):
        raise LbshapeError(f"{path}: a gmsh script must be a Python file ending in "
                           f"{SCRIPT_SUFFIX}")
    if not path.is_file():
        raise LbshapeError(f"gmsh script not found: {path}")
    path = path.resolve()
    digest = hashlib.sha256(str(path).encode()).hexdigest()[:12]
    module = _load_module(path, f"lbshape_user_script_{digest}", user=True)
    default = getattr(module, "DEFAULT_SIZE", None)
    if size is None and default is None:
        raise LbshapeError(f"{path}: no mesh size: give one (lbshape mesh/eigen/modes --size H, "
                           "a scene's size = H, in metres) or define DEFAULT_SIZE in the script")
    h = _check_size(f"{path}", size, default)
    return _Script(module, h, f"{path} (h = {h:g} m)", path.stem)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _load_module(path: Path, module_name: str, *, user: bool = False) -> ModuleType:
    if not path.is_file():
        raise LbshapeError(f"shape script not found: {path}")
    module_spec = importlib.util.spec_from_file_location(module_name, path)
    module = importlib.util.module_from_spec(module_spec)
    folder = str(path.parent)
    added = user and folder not in sys.path
    if added:
        sys.path.insert(0, folder)  # a user's script may import its neighbours
    try:
        module_spec.loader.exec_module(module)
    except LbshapeError:
        raise
    except Exception as exc:  # a user's script may raise anything, SyntaxError included
        raise LbshapeError(f"{path}: the script failed while loading ({_one_line(exc)})") from None
    finally:
        if added:
            sys.path.remove(folder)
    if not callable(getattr(module, "build", None)):
        raise LbshapeError(f"{path}: defines no build(model, h) function (the convention of "
                           "the scripts in meshes/)")
    return module


@contextmanager
def _geometry(script: _Script) -> Iterator[ModuleType]:
    """Yield ``gmsh`` with the script's geometry built in a fresh model.

    The gmsh options a script may touch start from
    :data:`lbshape.geometry.mesh.GMSH_OPTION_BASELINE` and
    are restored to the caller's values afterwards; the model is cleared on exit.
    """
    with gmsh_model(script.model_name) as gmsh:
        try:
            script.module.build(gmsh.model, script.h)
            gmsh.model.occ.synchronize()
        except LbshapeError:
            raise
        except Exception as exc:  # gmsh raises a bare Exception; a script anything
            raise LbshapeError(f"{script.source}: build(model, h) failed "
                               f"({_one_line(exc)})") from None
        if not gmsh.model.getEntities(3):
            raise LbshapeError(f"{script.source}: the script built no volume (lbshape needs a "
                               "solid: build(model, h) must add a 3D entity)")
        yield gmsh


@contextmanager
def _generated(script: _Script) -> Iterator[ModuleType]:
    """Yield ``gmsh`` with the script's geometry meshed in a fresh model; clean up after."""
    started = time.perf_counter()
    source, h = script.source, script.h
    with _geometry(script) as gmsh:
        volume = _occ_volume(gmsh)
        estimate = 6.0 * math.sqrt(2.0) * volume / h**3  # regular tets of edge h
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
            raise LbshapeError(f"{source}: gmsh could not mesh it ({_one_line(exc)})") from None
        log.info("meshed %s in %.2f s", source, time.perf_counter() - started)
        yield gmsh


def _build(script: _Script) -> TetMesh:
    with _generated(script) as gmsh:
        mesh = mesh_from_gmsh_model(gmsh.model, source=script.source)
    return check_mesh(mesh, source=script.source)


def _write(script: _Script, path: str | Path) -> TetMesh:
    path = Path(path)
    if path.suffix.lower() != ".msh":
        raise LbshapeError(f"{path}: output must be a .msh file")
    with _generated(script) as gmsh:
        mesh = check_mesh(mesh_from_gmsh_model(gmsh.model, source=script.source),
                          source=script.source)
        gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
        gmsh.option.setNumber("Mesh.Binary", 0)
        gmsh.option.setNumber("Mesh.SaveAll", 0)  # the physical groups cover the body
        write_gmsh_model(gmsh, path)
    log.info("wrote %s (%d vertices, %d tets)", path, mesh.n_vertices, mesh.n_tets)
    return mesh


def _occ_volume(gmsh) -> float:
    """The OCC volume of the model's solids (0 for a script on gmsh's built-in kernel,
    whose volume OCC cannot measure: the size guard is then skipped)."""
    try:
        return float(sum(gmsh.model.occ.getMass(d, t) for d, t in gmsh.model.getEntities(3)))
    except Exception:  # not OCC entities
        return 0.0
