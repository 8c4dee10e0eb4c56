"""Reading scenes: a TOML file or a built-in name to a validated :class:`~.schema.Scene`.

Built-in scenes ship in ``lbshape/scene/builtin/*.toml`` and are addressed by their
stem (``load_scene("demo")``); anything else is a path. Validation is strict: an
unknown key at any level, a value of the wrong type (``true`` is not a number;
integers are accepted where floats are expected), a non-finite or out-of-range
number, an unsafe region expression or a missing mesh file raises
:class:`~lbshape.errors.LbshapeError` with a one-line message that names the key
path, e.g. ``scene bar.toml: unknown key 'material.yung'``. The schema is in
:mod:`lbshape.scene.schema`; the choices come from the modules that own them
(shapes, poses, materials, interpolation routes, integrators, load profiles).

A document built in code (:func:`lbshape.scene.build.scene_from_mesh`) may give a
:class:`~lbshape.geometry.mesh.TetMesh` for an object's or an example's ``mesh`` (or an
example's ``rest``): a mesh in memory, checked as a file's mesh is.
"""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from lbshape.dynamics.contact import ContactPlane
from lbshape.dynamics.loads import PROFILES, TimeProfile
from lbshape.dynamics.schemes import INTEGRATORS
from lbshape.elastic.materials import MODELS, Material
from lbshape.elastic.polynomial_forces import FORCE_CHOICES, check_force_choice
from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh, check_mesh
from lbshape.geometry.mesh_files import (
    CAD_FORMATS,
    LENGTH_UNITS,
    SURFACE_FORMATS,
    is_cad_file,
    is_surface_file,
    takes_size,
)
from lbshape.geometry.poses import POSE_CHOICES, POSE_PARAMETERS, POSES
from lbshape.geometry.regions import parse_region
from lbshape.geometry.shapes import SHAPES, is_script_path
from lbshape.scene.schema import (
    IMPACT_COLUMN_SETS,
    LOAD_TYPES,
    Damping,
    ExamplePose,
    Examples,
    Initial,
    Load,
    LocalRegion,
    MeshSource,
    PosedPart,
    PoseValue,
    Reduced,
    Scene,
    Selection,
    Simulation,
)
from lbshape.shapespace.interpolation import ROUTE_CHOICES

__all__ = ["builtin_scene_names", "load_scene", "mesh_source", "scene_from_dict"]


def builtin_scene_names() -> tuple[str, ...]:
    """Names of the scenes shipped in ``lbshape/scene/builtin/``, sorted."""
    folder = resources.files("lbshape.scene").joinpath("builtin")
    if not folder.is_dir():
        return ()
    return tuple(sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml")))


def load_scene(name_or_path: str | os.PathLike) -> Scene:
    """Load and validate a scene: a built-in name or a path to a TOML file.

    A string naming an existing file, or ending in ``.toml``, or containing a path
    separator is a path; anything else is looked up among
    :func:`builtin_scene_names`.

    Raises:
        LbshapeError: unknown scene, unreadable file or invalid content.
    """
    text = os.fspath(name_or_path)
    path = Path(text)
    if path.is_file() or path.suffix == ".toml" or os.sep in text or "/" in text:
        if not path.is_file():
            raise LbshapeError(f"scene file not found: {path}")
        return _load_file(path.resolve())
    names = builtin_scene_names()
    if text not in names:
        raise LbshapeError(
            f"unknown scene '{text}' (built-in scenes: {', '.join(names)}; "
            "or give the path of a .toml file)"
        )
    resource = resources.files("lbshape.scene").joinpath("builtin", f"{text}.toml")
    with resources.as_file(resource) as file:
        return _load_file(Path(file))


def _load_file(path: Path) -> Scene:
    label = f"scene {path.name}"
    try:
        data = tomllib.loads(path.read_bytes().decode("utf-8"))
    except OSError as exc:
        raise LbshapeError(f"{label}: cannot read {path} ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise LbshapeError(f"{label}: not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise LbshapeError(f"{label}: invalid TOML: {exc}") from None
    return scene_from_dict(data, name=path.stem, base_dir=path.parent, label=label, source=path)


def scene_from_dict(
    data: Mapping[str, Any],
    *,
    name: str = "scene",
    base_dir: str | os.PathLike = ".",
    label: str | None = None,
    source: Path | None = None,
) -> Scene:
    """Validate a parsed TOML document (nested dicts) and build the :class:`Scene`.

    Tables are validated in document order of the schema, one function each.

    Args:
        data: the document.
        name: default scene name (the file stem) if the document has none.
        base_dir: folder that relative mesh paths are resolved against.
        label: prefix of error messages (default ``scene <name>``).
        source: recorded in :attr:`Scene.source`.
    """
    ctx = _Context(label or f"scene {name}", Path(base_dir))
    top = ctx.table(data, "", _TOP_KEYS)
    scene_name = top.string("name", name)
    if not scene_name.strip():
        raise ctx.error("'name' must be a non-empty string")
    description = top.string("description", "")
    obj = _mesh_source(top.subtable("object", ("shape", "mesh", "size") + _FILE_KEYS,
                                    required=True), ctx)
    material = _material(top, ctx)
    damping = _damping(top)
    reduced = _reduced(top)
    try:
        check_force_choice(reduced.forces, material.model)
    except LbshapeError as exc:
        raise ctx.error(str(exc)) from None
    examples = _examples(top, ctx)
    fixed = _fixed(top, ctx)
    if fixed is None and damping.alpha > 0:
        raise ctx.error(
            f"damping.alpha = {damping.alpha:g} on a free body (no [fixed]): the full-space "
            "reference would brake its rigid motion while the reduced method damps only the "
            "deformation; set alpha = 0 and damp the deformation with damping.beta")
    loads = tuple(_load(t, ctx) for t in top.array_of_tables("loads", _LOAD_KEYS))
    planes = tuple(_plane(t, ctx) for t in top.array_of_tables("planes", _PLANE_KEYS))
    rubbing = [i for i, plane in enumerate(planes) if plane.friction > 0]
    if fixed is not None and rubbing:
        raise ctx.error(f"'planes[{rubbing[0]}].friction' acts on free bodies only; this "
                        "object has '[fixed]' (set friction = 0)")
    if reduced.impact_columns and (fixed is not None or not planes):
        raise ctx.error("'reduced.impact_columns' acts on free bodies with contact planes "
                        "only; this object " + ("has '[fixed]'" if fixed is not None
                                                else "has no '[[planes]]'")
                        + " (set impact_columns = 0)")
    if reduced.sets_per_feature and not reduced.impact_columns:
        raise ctx.error("'reduced.impact_columns_per' needs impact_columns > 0")
    simulation = _simulation(top)
    if simulation.contact_dt is not None and (fixed is not None or not planes):
        raise ctx.error("'simulation.contact_dt' sets a free body's step in contact only; "
                        "this object " + ("has '[fixed]'" if fixed is not None
                                          else "has no '[[planes]]'")
                        + " (remove contact_dt)")
    if simulation.flight_dt is not None and fixed is not None:
        raise ctx.error("'simulation.flight_dt' sets a free body's step in flight only; "
                        "this object has '[fixed]' (remove flight_dt)")
    return Scene(
        name=scene_name, description=description, object=obj, material=material,
        damping=damping, reduced=reduced, examples=examples, fixed=fixed, loads=loads,
        planes=planes, regions=_regions(top, ctx, examples), simulation=simulation,
        initial=_initial(top, ctx, fixed), source=source,
    )


# ------------------------------------------------------------------ tables
_TOP_KEYS = ("name", "description", "object", "material", "damping", "reduced", "examples",
             "fixed", "loads", "planes", "regions", "simulation", "initial")
#: how a mesh file is read (beside 'mesh'): its unit, and which piece / hole filling
_FILE_KEYS = ("units", "scale", "piece", "fill_holes")
_POSE_KEYS = ("shape", "mesh", "size", "pose", "parameters", "landmarks", "rest", "parts",
              "hold") + _FILE_KEYS
_PART_KEYS = ("region", "group", "pose", "parameters")
_LOAD_KEYS = ("type", "vector", "region", "group", "profile", "start", "duration")
_PLANE_KEYS = ("point", "normal", "stiffness", "friction")
_REGION_KEYS = ("name", "region", "group", "examples")


def _material(top: _Table, ctx: _Context) -> Material:
    mat = top.subtable("material", ("model", "young", "poisson", "density"))
    defaults = Material()
    values = {
        "model": mat.choice("model", defaults.model, MODELS),
        "young": mat.number("young", defaults.young),
        "poisson": mat.number("poisson", defaults.poisson),
        "density": mat.number("density", defaults.density),
    }
    try:  # Material owns the ranges
        return Material(**values)
    except LbshapeError as exc:
        raise ctx.error(str(exc)) from None


def _damping(top: _Table) -> Damping:
    damp = top.subtable("damping", ("alpha", "beta"))
    return Damping(alpha=damp.number("alpha", 0.0, low=0.0, unit="1/s"),
                   beta=damp.number("beta", 0.0, low=0.0, unit="s"))


def _reduced(top: _Table) -> Reduced:
    red = top.subtable("reduced", ("m", "r", "s", "linear_modes", "cubature_tolerance",
                                   "interpolation", "forces", "impact_columns",
                                   "impact_columns_per"))
    r = red.integer("r", Reduced.r, low=1)
    return Reduced(
        m=red.integer("m", Reduced.m, low=1),
        r=r,
        s=red.integer("s", Reduced.s, low=1),
        linear_modes=red.integer("linear_modes", 0, low=0, high=r),
        cubature_tolerance=red.number("cubature_tolerance", Reduced.cubature_tolerance,
                                      low=0.0, high=1.0, open_low=True, open_high=True),
        interpolation=red.choice("interpolation", Reduced.interpolation, ROUTE_CHOICES),
        forces=red.choice("forces", Reduced.forces, FORCE_CHOICES),
        impact_columns=red.integer("impact_columns", Reduced.impact_columns, low=0),
        impact_columns_per=red.choice("impact_columns_per", Reduced.impact_columns_per,
                                      IMPACT_COLUMN_SETS),
    )


def _examples(top: _Table, ctx: _Context) -> Examples | None:
    if "examples" not in top.data:
        return None
    ex = top.subtable("examples", ("stiffness", "ramp", "pose"))
    value = ex.data.get("stiffness", Examples.AUTO)  # no number: set by the precompute
    if isinstance(value, str):
        if value != Examples.AUTO:
            raise ctx.error(f"'{ex.key('stiffness')}' must be a number >= 0 (1/s^2) or "
                            f"\"{Examples.AUTO}\", got {value!r}")
        stiffness = Examples.AUTO
    else:
        stiffness = ex.number("stiffness", low=0.0, unit="1/s^2")
    poses = tuple(_example_pose(t, ctx)
                  for t in ex.array_of_tables("pose", _POSE_KEYS, minimum=1))
    return Examples(stiffness, poses, ex.number("ramp", 0.0, low=0.0, unit="s"))


def _initial(top: _Table, ctx: _Context, fixed: Selection | None) -> Initial:
    if "initial" not in top.data:
        return Initial()
    if fixed is not None:
        raise ctx.error("'[initial]' applies to free bodies only; this object has '[fixed]'")
    init = top.subtable("initial", ("velocity", "angular_velocity"))
    return Initial(init.vector3("velocity", [0.0, 0.0, 0.0]),
                   init.vector3("angular_velocity", [0.0, 0.0, 0.0]))


def _fixed(top: _Table, ctx: _Context) -> Selection | None:
    if "fixed" not in top.data:
        return None
    return _selection(top.subtable("fixed", ("region", "group")), ctx, required=True)


def _regions(top: _Table, ctx: _Context, examples: Examples | None) -> tuple[LocalRegion, ...]:
    n_examples = 0 if examples is None else len(examples.poses)
    regions = tuple(_local_region(t, ctx, n_examples)
                    for t in top.array_of_tables("regions", _REGION_KEYS))
    names = [reg.name for reg in regions]
    if len(set(names)) != len(names):
        raise ctx.error(f"'regions' names must be unique, got {names}")
    return regions


def _simulation(top: _Table) -> Simulation:
    sim = top.subtable("simulation", ("dt", "steps", "integrator", "contact_dt",
                                          "flight_dt"))
    return Simulation(
        dt=sim.number("dt", Simulation.dt, low=0.0, open_low=True, unit="s"),
        steps=sim.integer("steps", Simulation.steps, low=1),
        integrator=sim.choice("integrator", Simulation.integrator, INTEGRATORS),
        contact_dt=sim.number("contact_dt", None, low=0.0, open_low=True, unit="s"),
        flight_dt=sim.number("flight_dt", None, low=0.0, open_low=True, unit="s"),
    )


def mesh_source(text: str | Path, *, size: float | None = None,
                base_dir: str | Path | None = None, units: str = "m",
                piece: int | str | None = None, fill_holes: bool = False) -> MeshSource:
    """The :class:`MeshSource` a command-line argument names: a built-in shape name, a
    user's gmsh script (``.py``) or a mesh file (any format of
    :func:`lbshape.geometry.mesh_files.read_mesh_file`), paths relative to
    ``base_dir`` (default: the current folder). The one resolver of ``lbshape mesh``,
    ``eigen`` and ``modes``; build the mesh with
    :func:`lbshape.pipeline.meshes.build_mesh`. ``units``, ``piece`` and
    ``fill_holes`` are the scene keys of a mesh file (docs/scenes.md).

    Raises:
        LbshapeError: an unknown name (listing the shapes), a missing file or script,
            a size that is not a finite positive length, an unknown unit, or a file
            option for a shape or script.
    """
    text = str(text)
    if units not in LENGTH_UNITS:
        raise LbshapeError(f"{text}: unknown units {units!r} (choose one of "
                           f"{', '.join(LENGTH_UNITS)})")
    options = {"units": units, "piece": piece, "fill_holes": fill_holes}
    if (text in SHAPES or is_script_path(Path(text))) and (
            units != "m" or piece is not None or fill_holes):
        raise LbshapeError(f"{text}: units, piece and fill holes apply to mesh files, not "
                           "to a built-in shape or gmsh script (which work in metres)")
    if size is not None and not (isinstance(size, int | float) and not isinstance(size, bool)
                                 and math.isfinite(size) and size > 0):
        raise LbshapeError(f"{text}: size must be a finite positive length in metres, "
                           f"got {size!r}")
    if text in SHAPES:
        return MeshSource(shape=text, size=size)
    path = Path(text).expanduser()
    if not path.is_absolute():
        path = Path(base_dir if base_dir is not None else Path.cwd()) / path
    if is_script_path(path):
        if not path.is_file():
            raise LbshapeError(f"gmsh script not found: {path}")
        return MeshSource(script=path.resolve(), size=size)
    if Path(text).suffix or path.exists():
        if not path.is_file():
            raise LbshapeError(f"mesh file not found: {path}")
        return MeshSource(mesh_file=path.resolve(), size=size, **options)
    raise LbshapeError(f"unknown shape '{text}' and no such file; give a built-in shape "
                       f"({', '.join(SHAPES)}), a gmsh script (.py) or a mesh file")


def _mesh_source(t: _Table, ctx: _Context) -> MeshSource:
    if ("shape" in t.data) == ("mesh" in t.data):
        raise ctx.error(f"'{t.path}' needs exactly one of 'shape' or 'mesh'")
    if isinstance(t.data.get("mesh"), TetMesh):  # a scene built in code
        if "size" in t.data:
            raise ctx.error(f"'{t.key('size')}' applies to built-in shapes and surface "
                            "files, not to a mesh in memory")
        _no_file_keys(t, ctx, "a mesh in memory (its points are already in metres)")
        return _memory_source(t, "mesh", ctx)
    if "shape" in t.data:
        _no_file_keys(t, ctx, "a built-in shape or gmsh script (which work in metres)")
        shape = t.string("shape")
        size = t.number("size", None, low=0.0, open_low=True, unit="m")
        if is_script_path(shape):
            return MeshSource(script=_existing_path(t, "shape", ctx, what="gmsh script"),
                              size=size)
        if shape not in SHAPES:
            raise ctx.error(
                f"'{t.key('shape')}': unknown shape '{shape}' (built-in shapes: "
                f"{', '.join(sorted(SHAPES))}; or a gmsh script ending in .py)"
            )
        return MeshSource(shape=shape, size=size)
    if is_script_path(t.string("mesh")):
        raise ctx.error(f"'{t.key('mesh')}': {t.string('mesh')} is a gmsh script; give it as "
                        f"'{t.key('shape')}'")
    path = _mesh_path(t, "mesh", ctx)
    size = t.number("size", None, low=0.0, open_low=True, unit="m")
    if size is not None and not takes_size(path) and not _rest_is_surface(t, ctx):
        raise ctx.error(f"'{t.key('size')}' applies to built-in shapes and surface files "
                        f"({', '.join(SURFACE_FORMATS)}) or CAD files "
                        f"({', '.join(CAD_FORMATS)}), not to the volume mesh {path.name}")
    return MeshSource(mesh_file=path, size=size if takes_size(path) else None,
                      **_file_options(t, ctx, path))


def _no_file_keys(t: _Table, ctx: _Context, what: str) -> None:
    for key in _FILE_KEYS:
        if key in t.data:
            raise ctx.error(f"'{t.key(key)}' applies to mesh files ('mesh'), not to {what}")


def _file_options(t: _Table, ctx: _Context, path: Path) -> dict:
    """``units``/``scale``, ``piece`` and ``fill_holes`` of a mesh file, checked."""
    if "units" in t.data and "scale" in t.data:
        raise ctx.error(f"'{t.path}' takes 'units' or 'scale' (metres per file unit), "
                        "not both")
    units = t.choice("units", "m", tuple(LENGTH_UNITS))
    scale = t.number("scale", None, low=0.0, open_low=True)
    piece = t.data.get("piece")
    if piece is not None:
        if not (is_surface_file(path) or is_cad_file(path)):
            raise ctx.error(f"'{t.key('piece')}' applies to surface and CAD files, not to "
                            f"the volume mesh {path.name}")
        if piece != "largest" and (isinstance(piece, bool) or not isinstance(piece, int)
                                   or piece < 0):
            raise ctx.error(f"'{t.key('piece')}' must be a piece number (>= 0) or "
                            f"\"largest\", got {piece!r}")
    fill_holes = t.data.get("fill_holes", False)
    if not isinstance(fill_holes, bool):
        raise ctx.error(f"'{t.key('fill_holes')}' must be true or false, got {fill_holes!r}")
    if fill_holes and not is_surface_file(path):
        raise ctx.error(f"'{t.key('fill_holes')}' applies to surface files "
                        f"({', '.join(SURFACE_FORMATS)}), not to {path.name}")
    return {"units": units, "scale": scale, "piece": piece, "fill_holes": fill_holes}


def _mesh_path(t: _Table, key: str, ctx: _Context) -> Path:
    return _existing_path(t, key, ctx, what="mesh file")


def _memory_source(t: _Table, key: str, ctx: _Context) -> MeshSource:
    """A mesh given in memory (a :class:`TetMesh` value, only from code: see
    :func:`lbshape.scene.build.scene_from_mesh`), checked as a file's mesh is."""
    try:
        return MeshSource(mesh=check_mesh(t.data[key], source=f"'{t.key(key)}'"))
    except LbshapeError as exc:
        raise ctx.error(str(exc)) from None


def _existing_path(t: _Table, key: str, ctx: _Context, *, what: str) -> Path:
    path = Path(t.string(key)).expanduser()
    path = path if path.is_absolute() else ctx.base_dir / path
    if not path.is_file():
        raise ctx.error(f"'{t.key(key)}': {what} not found: {path}")
    return path.resolve()


def _rest_is_surface(t: _Table, ctx: _Context) -> bool:
    return ("rest" in t.data and not isinstance(t.data["rest"], TetMesh)
            and is_surface_file(_mesh_path(t, "rest", ctx)))


def _example_pose(t: _Table, ctx: _Context) -> ExamplePose:
    source = _mesh_source(t, ctx)
    pose, parameters = _pose_and_parameters(t, ctx, required=False)
    landmarks = t.int_pairs("landmarks")
    rest = None
    if "rest" in t.data:
        if "mesh" not in t.data or pose is not None or "parts" in t.data:
            raise ctx.error(f"'{t.key('rest')}' is the rest shape of a posed mesh file: it "
                            "needs 'mesh' and no 'pose' or 'parts'")
    if "rest" in t.data and isinstance(t.data["rest"], TetMesh):
        rest = _memory_source(t, "rest", ctx)
    elif "rest" in t.data:
        path = _mesh_path(t, "rest", ctx)
        size = t.number("size", None) if takes_size(path) else None
        rest = MeshSource(mesh_file=path, size=size, **_file_options(t, ctx, path))
    parts = tuple(_posed_part(p, ctx) for p in t.array_of_tables("parts", _PART_KEYS))
    if parts and pose is not None:
        raise ctx.error(f"'{t.path}' takes 'pose' (the whole example) or 'parts' "
                        "(posed part by part), not both")
    hold = None
    if "hold" in t.data:
        if not parts:
            raise ctx.error(f"'{t.key('hold')}' keeps vertices at rest while parts are "
                            f"posed: it needs [[{t.key('parts')}]]")
        hold = _selection(t.subtable("hold", ("region", "group")), ctx, required=True)
    return ExamplePose(source, pose, MappingProxyType(parameters), landmarks, rest,
                       parts, hold)


def _posed_part(t: _Table, ctx: _Context) -> PosedPart:
    selection = _selection(t, ctx, required=True)
    pose, parameters = _pose_and_parameters(t, ctx, required=True)
    return PosedPart(selection, pose, MappingProxyType(parameters))


def _pose_and_parameters(t: _Table, ctx: _Context, *, required: bool
                         ) -> tuple[str | None, dict[str, PoseValue]]:
    """A table's ``pose`` (a key of POSES) and its ``parameters``, checked by name and type."""
    pose = t.choice("pose", _REQUIRED if required else None, tuple(POSES))
    parameters: dict[str, PoseValue] = {}
    if "parameters" in t.data:
        if pose is None:
            raise ctx.error(f"'{t.key('parameters')}' needs a 'pose'")
        names = POSE_PARAMETERS[pose]
        p = t.subtable("parameters", names)
        parameters[names[0]] = p.number(names[0])
        for other in names[1:]:
            if other in p.data:
                parameters[other] = p.choice(other, None, POSE_CHOICES[other])
    elif pose is not None:
        raise ctx.error(f"'{t.key('parameters')}' is required for pose '{pose}' "
                        f"(needs '{POSE_PARAMETERS[pose][0]}')")
    return pose, parameters


def _selection(t: _Table, ctx: _Context, *, required: bool) -> Selection | None:
    has_region, has_group = "region" in t.data, "group" in t.data
    if has_region and has_group:
        raise ctx.error(f"'{t.path}' takes 'region' or 'group', not both")
    if not (has_region or has_group):
        if required:
            raise ctx.error(f"'{t.path}' needs 'region' (an expression) or 'group'")
        return None
    if has_region:
        return Selection(region=t.region("region"))
    group = t.string("group")
    if not group.strip():
        raise ctx.error(f"'{t.key('group')}' must be a non-empty string")
    return Selection(group=group)


def _load(t: _Table, ctx: _Context) -> Load:
    kind = t.choice("type", None, LOAD_TYPES)
    vector = t.vector3("vector")
    if kind == "gravity":
        for key in ("region", "group"):
            if key in t.data:
                raise ctx.error(f"'{t.key(key)}' is not used by gravity loads")
        selection = None
    else:
        selection = _selection(t, ctx, required=True)
    profile_kind = t.choice("profile", "constant", PROFILES)
    start = t.number("start", 0.0, low=0.0, unit="s")
    duration = t.number("duration", 0.0, low=0.0, unit="s")
    if profile_kind != "constant" and duration <= 0.0:
        raise ctx.error(f"'{t.key('duration')}' must be > 0 s for a {profile_kind} profile")
    return Load(kind, vector, selection, TimeProfile(profile_kind, start, duration))


def _plane(t: _Table, ctx: _Context) -> ContactPlane:
    point = t.vector3("point")
    normal = np.array(t.vector3("normal"))
    length = float(np.linalg.norm(normal))
    if length == 0.0:
        raise ctx.error(f"'{t.key('normal')}' must be a non-zero vector")
    stiffness = t.number("stiffness", low=0.0, open_low=True, unit="N/m^3")
    friction = t.number("friction", 0.0, low=0.0)
    return ContactPlane(point, tuple(float(v) for v in normal / length), stiffness,
                        friction)


def _local_region(t: _Table, ctx: _Context, n_examples: int) -> LocalRegion:
    if n_examples == 0:
        raise ctx.error(f"'{t.path}': local regions need [examples] with at least one pose")
    name = t.string("name")
    if not name.strip():
        raise ctx.error(f"'{t.key('name')}' must be a non-empty string")
    selection = _selection(t, ctx, required=True)
    indices = t.int_list("examples", low=0, high=n_examples - 1)
    if not indices or len(set(indices)) != len(indices):
        raise ctx.error(f"'{t.key('examples')}' must list unique example indices, got {indices}")
    return LocalRegion(name, selection, indices)


# ---------------------------------------------------------------- validation
_REQUIRED = object()


def _describe(value) -> str:
    return repr(value) if isinstance(value, str) else f"{value!r} ({type(value).__name__})"


class _Context:
    def __init__(self, label: str, base_dir: Path):
        self.label = label
        self.base_dir = base_dir

    def error(self, message: str) -> LbshapeError:
        return LbshapeError(f"{self.label}: {message}")

    def table(self, data, path: str, allowed: tuple[str, ...]) -> _Table:
        return _Table(data, path, self, allowed)


class _Table:
    """A TOML table being validated: typed getters that name the key path."""

    def __init__(self, data, path: str, ctx: _Context, allowed: tuple[str, ...]):
        if not isinstance(data, dict):
            raise ctx.error(f"'{path}' must be a table, got {_describe(data)}")
        self.data, self.path, self.ctx = data, path, ctx
        for key in data:
            if key not in allowed:
                raise ctx.error(f"unknown key '{self.key(key)}' (allowed: {', '.join(allowed)})")

    def key(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def _get(self, key: str, default):
        if key in self.data:
            return self.data[key]
        if default is _REQUIRED:
            raise self.ctx.error(f"missing required key '{self.key(key)}'")
        return default

    def _type_error(self, key: str, expected: str, value) -> LbshapeError:
        return self.ctx.error(f"'{self.key(key)}' must be {expected}, got {_describe(value)}")

    def _check_number(self, key: str, value, expected: str = "a number") -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self._type_error(key, expected, value)
        if not math.isfinite(value):
            raise self.ctx.error(f"'{self.key(key)}' must be finite, got {value}")
        return value

    def number(self, key, default=_REQUIRED, *, low=None, high=None, open_low=False,
               open_high=False, unit="") -> float | None:
        if key not in self.data:
            return self._get(key, default)
        value = float(self._check_number(key, self.data[key]))
        self._check_range(key, value, low, high, open_low, open_high, unit)
        return value

    def integer(self, key, default=_REQUIRED, *, low=None, high=None) -> int:
        value = self._get(key, default)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self._type_error(key, "an integer", value)
        self._check_range(key, value, low, high, False, False, "")
        return value

    def _check_range(self, key, value, low, high, open_low, open_high, unit):
        unit = f" {unit}" if unit else ""
        too_low = low is not None and (value <= low if open_low else value < low)
        too_high = high is not None and (value >= high if open_high else value > high)
        if too_low or too_high:
            if low is not None and high is not None:
                left, right = "(" if open_low else "[", ")" if open_high else "]"
                interval = f"in {left}{low:g}, {high:g}{right}"
            elif low is not None:
                interval = f"{'>' if open_low else '>='} {low:g}{unit}"
            else:
                interval = f"{'<' if open_high else '<='} {high:g}{unit}"
            raise self.ctx.error(f"'{self.key(key)}' must be {interval}, got {value:g}")

    def string(self, key, default=_REQUIRED) -> str:
        value = self._get(key, default)
        if value is None and default is None:
            return None
        if not isinstance(value, str):
            raise self._type_error(key, "a string", value)
        return value

    def choice(self, key, default, choices: tuple[str, ...]) -> str | None:
        value = self.string(key, default)
        if value is not None and value not in choices:
            raise self.ctx.error(
                f"'{self.key(key)}' must be one of {', '.join(choices)}; got {value!r}"
            )
        return value

    def region(self, key) -> str:
        expression = self.string(key)
        try:
            parse_region(expression)
        except LbshapeError as exc:
            raise self.ctx.error(f"'{self.key(key)}': {exc}") from None
        return expression

    def vector3(self, key, default=_REQUIRED) -> tuple[float, float, float]:
        value = self._get(key, default)
        if not isinstance(value, list) or len(value) != 3:
            raise self._type_error(key, "a list of 3 numbers", value)
        for item in value:
            self._check_number(key, item, "a list of 3 numbers")
        return tuple(float(v) for v in value)

    def int_list(self, key, *, low=None, high=None) -> tuple[int, ...]:
        value = self._get(key, _REQUIRED)
        if not isinstance(value, list) or any(
            isinstance(v, bool) or not isinstance(v, int) for v in value
        ):
            raise self._type_error(key, "a list of integers", value)
        for item in value:
            self._check_range(key, item, low, high, False, False, "")
        return tuple(value)

    def int_pairs(self, key) -> tuple[tuple[int, int], ...]:
        value = self._get(key, [])
        expected = "a list of [object vertex, example vertex] integer pairs"
        if not isinstance(value, list):
            raise self._type_error(key, expected, value)
        pairs = []
        for pair in value:
            if (not isinstance(pair, list) or len(pair) != 2
                    or any(isinstance(v, bool) or not isinstance(v, int) or v < 0 for v in pair)):
                raise self._type_error(key, expected + " (>= 0)", pair)
            pairs.append((pair[0], pair[1]))
        return tuple(pairs)

    def subtable(self, key, allowed: tuple[str, ...], *, required: bool = False) -> _Table:
        if key not in self.data:
            if required:
                raise self.ctx.error(f"missing required table '[{self.key(key)}]'")
            return _Table({}, self.key(key), self.ctx, allowed)
        return _Table(self.data[key], self.key(key), self.ctx, allowed)

    def array_of_tables(self, key, allowed: tuple[str, ...], *, minimum: int = 0) -> list[_Table]:
        value = self._get(key, [] if minimum == 0 else _REQUIRED)
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            raise self._type_error(key, f"an array of tables ([[{self.key(key)}]])", value)
        if len(value) < minimum:
            raise self.ctx.error(f"'{self.key(key)}' needs at least {minimum} entries")
        return [_Table(item, f"{self.key(key)}[{i}]", self.ctx, allowed)
                for i, item in enumerate(value)]
