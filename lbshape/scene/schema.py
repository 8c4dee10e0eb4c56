"""Scenes: the TOML schema, its validation, and the built-in scenes.

A scene is a TOML file. Built-in scenes ship in ``lbshape/scenes/*.toml`` and are
addressed by their stem (``load_scene("demo")``); anything else is a path.
Validation is strict: an unknown key at any level, a value of the wrong type
(``true`` is not a number; integers are accepted where floats are expected), a
non-finite or out-of-range number, an unsafe region expression or a missing mesh
file raises :class:`~lbshape.errors.LbshapeError` with a one-line message that
names the key path, e.g. ``scene bar.toml: unknown key 'material.yung'``.

Schema (units SI; ``[a, b)`` are ranges; defaults in parentheses)::

    name = "bar-cuboid"        # str (file stem)
    description = "..."        # str ("")

    [object]                   # required; exactly one of shape / mesh
    shape = "bar-cuboid"       # built-in shape name (lbshape.geometry.shapes.SHAPES)
    mesh = "part.msh"          # gmsh .msh file, relative to the TOML file's folder
    size = 0.07                # m, > 0; gmsh size override, shape only (shape default)

    [material]                 # lbshape.elastic.materials.Material
    model = "stvk"             # "stvk" | "neohookean" ("stvk")
    young = 1.0e6              # Pa, > 0 (1e5)
    poisson = 0.3              # (-1, 0.5) (0.3)
    density = 1000.0           # kg/m^3, > 0 (1000)

    [damping]                  # Rayleigh D = alpha M + beta K0 (lbshape.dynamics.integrators)
    alpha = 0.0                # 1/s, >= 0 (0)
    beta = 0.01                # s, >= 0 (0)

    [reduced]
    m = 10                     # int >= 1: LB eigenfunctions (10)
    r = 30                     # int >= 1: reduced basis size (30)
    s = 60                     # int >= 1: maximum cubature elements (60)
    linear_modes = 0           # int in [0, r]: linear modes in the basis, 0 = automatic (0)
    cubature_tolerance = 0.01  # (0, 1): relative cubature training error (0.01)
    interpolation = "auto"     # "auto" | "lb-table" | "lb-exact" | "lb" | "modal": target
                               # route of the reduced method (lbshape.pipeline.routes);
                               # auto = lb-table ("auto")

    [examples]                 # optional; no LB work without it
    stiffness = 200.0          # k_ex, 1/s^2, >= 0 (required): force k_ex (q* - q)
                               # in mass-normalised reduced coordinates
    [[examples.pose]]          # one table per example, at least one
    shape = "bar-cylinder"     # built-in shape, OR
    mesh = "example.msh"       # a mesh file (relative to the TOML file)
    size = 0.05                # m, > 0, shape only
    pose = "twist"             # "twist" | "s-bend" | "arc"; omit if the mesh is posed
    parameters = { angle = 1.57 }  # pose parameters (see POSE_PARAMETERS); pose only
    landmarks = [[0, 12]]      # optional (object vertex, example vertex) int pairs >= 0

    [fixed]                    # optional; without it the object is a free body
    region = "z > 0.999"       # safe expression in x, y, z (m), OR
    group = "top"              # a physical group of the object's mesh

    [[loads]]                  # zero or more
    type = "gravity"           # "gravity" | "region_force" | "region_torque"
    vector = [0, 0, -9.81]     # 3 numbers: m/s^2 (gravity), N total (region_force),
                               # N·m about the region's centre (region_torque)
    region = "z < 0.001"       # region loads only: expression, OR
    group = "bottom"           #   a physical group
    profile = "constant"       # "constant" | "ramp" | "pulse" ("constant")
    start = 0.0                # s, >= 0 (0)
    duration = 0.5             # s, >= 0; > 0 for ramp (length) and pulse (length)

    [[planes]]                 # contact planes, zero or more
    point = [0, 0, 0]          # m
    normal = [0, 0, 1]         # non-zero; stored normalised; points into the free side
    stiffness = 1e4            # N/m per surface vertex, > 0

    [[regions]]                # local examples, zero or more; need [examples]
    name = "left"              # unique non-empty str
    region = "x < -0.2"        # expression, OR
    group = "left"             #   a physical group
    examples = [0, 1]          # unique indices into [[examples.pose]], at least one

    [simulation]
    dt = 0.001                 # s, > 0 (0.001)
    steps = 1000               # int >= 1 (1000)
    integrator = "newmark"     # "newmark" | "backward-euler" ("newmark")

Pose parameters (:data:`POSE_PARAMETERS`, the keywords of lbshape.geometry.poses):
``twist(angle [rad], axis, profile, anchor)``, ``s-bend(amplitude [m], direction,
axis, anchor)``, ``arc(angle [rad], direction, axis, anchor)``; the first is required,
the others default in lbshape.geometry.poses. ``axis``, ``direction``: ``"x"``, ``"y"`` or
``"z"``; ``anchor``: ``"min"`` | ``"max"`` (the bar end kept in place); ``profile``:
``"linear"`` | ``"smooth"``.

:meth:`Scene.precompute_key_fields` holds exactly what determines the precompute
(object, material, m/r/s and the other ``[reduced]`` settings, examples without
k_ex, fixed region, local regions); :meth:`Scene.runtime_fields` holds the rest
(dt, steps, integrator, damping, loads, k_ex, planes).
"""

from __future__ import annotations

import logging
import math
import os
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from lbshape.dynamics.integrators import INTEGRATORS
from lbshape.dynamics.loads import PROFILES, TimeProfile
from lbshape.elastic.materials import MODELS, Material
from lbshape.errors import LbshapeError
from lbshape.geometry.regions import parse_region, region_vertices
from lbshape.io.cache import file_digest

#: target routes selectable for the reduced method (see lbshape.shapespace.interpolation)
INTERPOLATION_ROUTES: tuple[str, ...] = ("auto", "lb-table", "lb-exact", "lb", "modal")

log = logging.getLogger(__name__)

#: analytic example poses known to scenes
POSES: tuple[str, ...] = ("twist", "s-bend", "arc")
#: keyword parameters per pose (as in lbshape.geometry.poses), the first one required
POSE_PARAMETERS: Mapping[str, tuple[str, ...]] = MappingProxyType({
    "twist": ("angle", "axis", "profile", "anchor"),
    "s-bend": ("amplitude", "direction", "axis", "anchor"),
    "arc": ("angle", "direction", "axis", "anchor"),
})
#: string-valued pose parameters and their choices; the others are numbers
_POSE_CHOICES: Mapping[str, tuple[str, ...]] = MappingProxyType({
    "axis": ("x", "y", "z"),
    "direction": ("x", "y", "z"),
    "anchor": ("min", "max"),
    "profile": ("linear", "smooth"),
})
#: load types
LOAD_TYPES: tuple[str, ...] = ("gravity", "region_force", "region_torque")

PoseValue = float | str


# ------------------------------------------------------------------ dataclasses
@dataclass(frozen=True)
class MeshSource:
    """Where a mesh comes from: a built-in shape (with optional size) or a file.

    Attributes:
        shape: built-in shape name, or ``None``.
        mesh_file: absolute path of a ``.msh`` file, or ``None``.
        size: gmsh size override (m) for a shape, or ``None`` for its default.
    """

    shape: str | None = None
    mesh_file: Path | None = None
    size: float | None = None

    def build(self):
        """The :class:`~lbshape.geometry.mesh.TetMesh` (gmsh script run or file loaded)."""
        if self.shape is not None:
            from lbshape.geometry.shapes import build_shape

            return build_shape(self.shape, size=self.size)
        from lbshape.geometry.mesh import load_mesh

        return load_mesh(self.mesh_file)

    def key(self) -> dict:
        """What identifies the mesh: shape and size, or the file's SHA-256."""
        if self.shape is not None:
            return {"shape": self.shape, "size": self.size}
        if not self.mesh_file.is_file():
            raise LbshapeError(f"mesh file not found: {self.mesh_file}")
        return {"mesh_sha256": file_digest(self.mesh_file)}


@dataclass(frozen=True)
class Selection:
    """A set of vertices: a safe region expression or a physical group name."""

    region: str | None = None
    group: str | None = None

    def vertices(self, mesh, *, what: str = "region") -> np.ndarray:
        """(k,) int64 indices of the selected vertices of ``mesh``; error if none."""
        if self.region is not None:
            return region_vertices(self.region, mesh.points, what=what)
        if self.group not in mesh.vertex_groups:
            raise LbshapeError(
                f"{what}: mesh has no physical group '{self.group}' "
                f"(groups: {', '.join(sorted(mesh.vertex_groups)) or 'none'})"
            )
        idx = np.asarray(mesh.vertex_groups[self.group], dtype=np.int64)
        if idx.size == 0:
            raise LbshapeError(f"{what}: physical group '{self.group}' has no vertex")
        return idx

    def key(self) -> dict:
        return {"region": self.region} if self.region is not None else {"group": self.group}


@dataclass(frozen=True)
class Damping:
    """Rayleigh damping ``D = alpha M + beta K0``: alpha in 1/s, beta in s."""

    alpha: float = 0.0
    beta: float = 0.0


@dataclass(frozen=True)
class Reduced:
    """Sizes of the reduced model.

    Attributes:
        m: LB eigenfunctions.
        r: reduced basis size.
        s: maximum number of cubature elements.
        linear_modes: linear modes in the basis (0: automatic).
        cubature_tolerance: relative training error at which cubature stops.
        interpolation: target route of the ``reduced`` method: ``"lb-table"`` (the
            exact target tabulated over the weight simplex, with its own fallback),
            ``"lb-exact"`` (exact polynomial StVK energy in LB space), ``"lb"``
            (cubature on the LB displacement subspace), ``"modal"`` (the paper's:
            nonlinear modal basis and direct projection), or ``"auto"``
            (``lb-table``). Run time only.
    """

    m: int = 10
    r: int = 30
    s: int = 60
    linear_modes: int = 0
    cubature_tolerance: float = 0.01
    interpolation: str = "auto"

    def route(self, material_model: str) -> str:
        """The interpolation route to use with a material model (resolves ``auto``)."""
        if self.interpolation == "auto":
            return "lb-table"
        return self.interpolation


@dataclass(frozen=True)
class ExamplePose:
    """One example: a mesh and an optional analytic pose applied to it.

    Attributes:
        source: the example's mesh.
        pose: one of :data:`POSES`, or ``None`` if the mesh is already posed.
        parameters: pose parameters (read-only mapping; see :data:`POSE_PARAMETERS`).
        landmarks: (object vertex, example vertex) correspondences.
    """

    source: MeshSource
    pose: str | None = None
    parameters: Mapping[str, PoseValue] = field(default_factory=lambda: MappingProxyType({}))
    landmarks: tuple[tuple[int, int], ...] = ()

    def posed(self, rest):
        """The example's rest mesh (a :class:`~lbshape.geometry.mesh.TetMesh`), posed."""
        if self.pose is None:
            return rest
        from lbshape.geometry.poses import apply_pose

        return apply_pose(rest, self.pose, **dict(self.parameters))

    def key(self) -> dict:
        return {
            "source": self.source.key(),
            "pose": self.pose,
            "parameters": dict(self.parameters),
            "landmarks": [list(pair) for pair in self.landmarks],
        }


@dataclass(frozen=True)
class Examples:
    """The example poses and the example-force stiffness k_ex (1/s²)."""

    stiffness: float
    poses: tuple[ExamplePose, ...]


@dataclass(frozen=True)
class Load:
    """An external load: pattern kind, vector, region and time profile.

    Attributes:
        type: one of :data:`LOAD_TYPES`.
        vector: (3,) m/s² (gravity), N (region_force) or N·m (region_torque).
        selection: the loaded vertices (region loads), ``None`` for gravity.
        profile: time profile (:class:`lbshape.dynamics.loads.TimeProfile`).
    """

    type: str
    vector: tuple[float, float, float]
    selection: Selection | None
    profile: TimeProfile

    def key(self) -> dict:
        return {
            "type": self.type,
            "vector": list(self.vector),
            "selection": None if self.selection is None else self.selection.key(),
            "profile": [self.profile.kind, self.profile.start, self.profile.duration],
        }


@dataclass(frozen=True)
class Plane:
    """A contact plane: a point (m), a unit normal, a penalty stiffness (N/m)."""

    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    stiffness: float


@dataclass(frozen=True)
class LocalRegion:
    """A region of the object with its own examples (indices into the example list)."""

    name: str
    selection: Selection
    examples: tuple[int, ...]


@dataclass(frozen=True)
class Simulation:
    """Time stepping: dt (s), number of steps, integrator name."""

    dt: float = 0.001
    steps: int = 1000
    integrator: str = "newmark"


@dataclass(frozen=True)
class Scene:
    """A validated scene (see the module docstring for the schema).

    Attributes:
        name: scene name.
        description: free text.
        object: the object's mesh.
        material: its material.
        damping: Rayleigh coefficients.
        reduced: m, r, s and cubature settings.
        examples: examples and k_ex, or ``None``.
        fixed: fixed vertices, or ``None`` (free body).
        loads: external loads.
        planes: contact planes.
        regions: local-example regions.
        simulation: dt, steps, integrator.
        source: the TOML file the scene was read from, if any.
    """

    name: str
    object: MeshSource
    material: Material = field(default_factory=Material)
    damping: Damping = field(default_factory=Damping)
    reduced: Reduced = field(default_factory=Reduced)
    examples: Examples | None = None
    fixed: Selection | None = None
    loads: tuple[Load, ...] = ()
    planes: tuple[Plane, ...] = ()
    regions: tuple[LocalRegion, ...] = ()
    simulation: Simulation = field(default_factory=Simulation)
    description: str = ""
    source: Path | None = None

    @property
    def is_free(self) -> bool:
        """No fixed vertices: the object needs a rigid frame."""
        return self.fixed is None

    @property
    def has_examples(self) -> bool:
        return self.examples is not None

    @property
    def has_contact(self) -> bool:
        return bool(self.planes)

    @property
    def has_local_examples(self) -> bool:
        return bool(self.regions)

    def precompute_key_fields(self) -> dict:
        """Exactly the fields that determine the precompute (JSON-compatible).

        The object and example meshes (by shape and size or file digest), the
        material, the ``[reduced]`` settings, the examples (without k_ex), the fixed
        region and the local regions. Feed it to :func:`lbshape.io.cache.cache_key`.
        """
        m = self.material
        return {
            "object": self.object.key(),
            "material": {"model": m.model, "young": m.young, "poisson": m.poisson,
                         "density": m.density},
            "reduced": {"m": self.reduced.m, "r": self.reduced.r, "s": self.reduced.s,
                        "linear_modes": self.reduced.linear_modes,
                        "cubature_tolerance": self.reduced.cubature_tolerance},
            "examples": None if self.examples is None
            else [pose.key() for pose in self.examples.poses],
            "fixed": None if self.fixed is None else self.fixed.key(),
            "regions": [{"name": reg.name, "selection": reg.selection.key(),
                         "examples": list(reg.examples)} for reg in self.regions],
        }

    def runtime_fields(self) -> dict:
        """The fields that only matter at run time (JSON-compatible)."""
        return {
            "dt": self.simulation.dt,
            "steps": self.simulation.steps,
            "integrator": self.simulation.integrator,
            "interpolation": self.reduced.interpolation,
            "damping": {"alpha": self.damping.alpha, "beta": self.damping.beta},
            "loads": [load.key() for load in self.loads],
            "k_ex": None if self.examples is None else self.examples.stiffness,
            "planes": [{"point": list(p.point), "normal": list(p.normal),
                        "stiffness": p.stiffness} for p in self.planes],
        }


# ------------------------------------------------------------------ loading
def builtin_scene_names() -> tuple[str, ...]:
    """Names of the scenes shipped in ``lbshape/scenes/``, sorted."""
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

    Args:
        data: the document.
        name: default scene name (the file stem) if the document has none.
        base_dir: folder that relative mesh paths are resolved against.
        label: prefix of error messages (default ``scene <name>``).
        source: recorded in :attr:`Scene.source`.
    """
    ctx = _Context(label or f"scene {name}", Path(base_dir))
    top = ctx.table(data, "", (
        "name", "description", "object", "material", "damping", "reduced", "examples",
        "fixed", "loads", "planes", "regions", "simulation",
    ))
    scene_name = top.string("name", name)
    if not scene_name.strip():
        raise ctx.error("'name' must be a non-empty string")
    description = top.string("description", "")

    obj = _mesh_source(top.subtable("object", ("shape", "mesh", "size"), required=True), ctx)

    mat = top.subtable("material", ("model", "young", "poisson", "density"))
    defaults = Material()
    values = {
        "model": mat.choice("model", defaults.model, MODELS),
        "young": mat.number("young", defaults.young),
        "poisson": mat.number("poisson", defaults.poisson),
        "density": mat.number("density", defaults.density),
    }
    try:  # Material owns the ranges
        material = Material(**values)
    except LbshapeError as exc:
        raise ctx.error(str(exc)) from None

    damp = top.subtable("damping", ("alpha", "beta"))
    damping = Damping(alpha=damp.number("alpha", 0.0, low=0.0, unit="1/s"),
                      beta=damp.number("beta", 0.0, low=0.0, unit="s"))

    red = top.subtable("reduced", ("m", "r", "s", "linear_modes", "cubature_tolerance",
                                   "interpolation"))
    r = red.integer("r", Reduced.r, low=1)
    reduced = Reduced(
        m=red.integer("m", Reduced.m, low=1),
        r=r,
        s=red.integer("s", Reduced.s, low=1),
        linear_modes=red.integer("linear_modes", 0, low=0, high=r),
        cubature_tolerance=red.number("cubature_tolerance", Reduced.cubature_tolerance,
                                      low=0.0, high=1.0, open_low=True, open_high=True),
        interpolation=red.choice("interpolation", Reduced.interpolation, INTERPOLATION_ROUTES),
    )

    examples = None
    if "examples" in top.data:
        ex = top.subtable("examples", ("stiffness", "pose"))
        stiffness = ex.number("stiffness", low=0.0, unit="1/s^2")
        poses = tuple(_example_pose(t, ctx) for t in ex.array_of_tables(
            "pose", ("shape", "mesh", "size", "pose", "parameters", "landmarks"), minimum=1))
        examples = Examples(stiffness, poses)

    fixed = None
    if "fixed" in top.data:
        fixed = _selection(top.subtable("fixed", ("region", "group")), ctx, required=True)

    loads = tuple(_load(t, ctx) for t in top.array_of_tables(
        "loads", ("type", "vector", "region", "group", "profile", "start", "duration")))
    planes = tuple(_plane(t, ctx) for t in top.array_of_tables(
        "planes", ("point", "normal", "stiffness")))
    n_examples = 0 if examples is None else len(examples.poses)
    regions = tuple(_local_region(t, ctx, n_examples) for t in top.array_of_tables(
        "regions", ("name", "region", "group", "examples")))
    names = [reg.name for reg in regions]
    if len(set(names)) != len(names):
        raise ctx.error(f"'regions' names must be unique, got {names}")

    sim = top.subtable("simulation", ("dt", "steps", "integrator"))
    simulation = Simulation(
        dt=sim.number("dt", Simulation.dt, low=0.0, open_low=True, unit="s"),
        steps=sim.integer("steps", Simulation.steps, low=1),
        integrator=sim.choice("integrator", Simulation.integrator, INTEGRATORS),
    )
    return Scene(
        name=scene_name, description=description, object=obj, material=material,
        damping=damping, reduced=reduced, examples=examples, fixed=fixed, loads=loads,
        planes=planes, regions=regions, simulation=simulation, source=source,
    )


# ---------------------------------------------------------------- sub-parsers
def _mesh_source(t: _Table, ctx: _Context) -> MeshSource:
    if ("shape" in t.data) == ("mesh" in t.data):
        raise ctx.error(f"'{t.path}' needs exactly one of 'shape' or 'mesh'")
    if "shape" in t.data:
        shape = t.string("shape")
        known = _known_shapes()
        if known is not None and shape not in known:
            raise ctx.error(
                f"'{t.key('shape')}': unknown shape '{shape}' (built-in shapes: "
                f"{', '.join(sorted(known))})"
            )
        size = t.number("size", None, low=0.0, open_low=True, unit="m")
        return MeshSource(shape=shape, size=size)
    if "size" in t.data:
        raise ctx.error(f"'{t.key('size')}' applies to built-in shapes only, not to 'mesh'")
    raw = t.string("mesh")
    path = Path(raw).expanduser()
    path = path if path.is_absolute() else ctx.base_dir / path
    if not path.is_file():
        raise ctx.error(f"'{t.key('mesh')}': mesh file not found: {path}")
    return MeshSource(mesh_file=path.resolve())


def _example_pose(t: _Table, ctx: _Context) -> ExamplePose:
    source = _mesh_source(t, ctx)
    pose = t.choice("pose", None, POSES)
    parameters: dict[str, PoseValue] = {}
    if "parameters" in t.data:
        if pose is None:
            raise ctx.error(f"'{t.key('parameters')}' needs a 'pose'")
        names = POSE_PARAMETERS[pose]
        p = t.subtable("parameters", names)
        parameters[names[0]] = p.number(names[0])
        for other in names[1:]:
            if other in p.data:
                parameters[other] = p.choice(other, None, _POSE_CHOICES[other])
    elif pose is not None:
        raise ctx.error(f"'{t.key('parameters')}' is required for pose '{pose}' "
                        f"(needs '{POSE_PARAMETERS[pose][0]}')")
    landmarks = t.int_pairs("landmarks")
    return ExamplePose(source, pose, MappingProxyType(parameters), landmarks)


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


def _plane(t: _Table, ctx: _Context) -> Plane:
    point = t.vector3("point")
    normal = np.array(t.vector3("normal"))
    length = float(np.linalg.norm(normal))
    if length == 0.0:
        raise ctx.error(f"'{t.key('normal')}' must be a non-zero vector")
    stiffness = t.number("stiffness", low=0.0, open_low=True, unit="N/m")
    return Plane(point, tuple(float(v) for v in normal / length), stiffness)


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


def _known_shapes():
    """``lbshape.geometry.shapes.SHAPES`` if that module exists yet, else ``None``."""
    try:
        from lbshape.geometry.shapes import SHAPES
    except ModuleNotFoundError as exc:
        if exc.name != "lbshape.geometry.shapes":
            raise
        log.debug("lbshape.geometry.shapes is not available: shape names are not checked")
        return None
    return SHAPES


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
