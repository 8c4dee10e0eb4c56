"""The scene schema: frozen dataclasses that hold a validated scene, as plain data.

A scene is a TOML file read and validated by :mod:`lbshape.scene.reader`, or built in
code around a mesh in memory (``Scene.from_mesh``, :mod:`lbshape.scene.build`, through
the same checks); these classes only hold what it found. Nothing here builds meshes,
applies poses or selects vertices: that is :mod:`lbshape.pipeline.meshes`.

Schema (units SI; ``[a, b)`` are ranges; defaults in parentheses)::

    name = "bar-cuboid"        # str (file stem)
    description = "..."        # str ("")

    [object]                   # required; exactly one of shape / mesh
    shape = "bar-cuboid"       # built-in shape name (lbshape.geometry.shapes.SHAPES), or
                               # a gmsh script "my_part.py" (relative to the TOML file's
                               # folder) defining build(model, h) as the scripts in
                               # meshes/ do, and optionally DEFAULT_SIZE (m)
    mesh = "part.msh"          # mesh file, relative to the TOML file's folder: .msh, a
                               # meshio volume (.vtu .vtk .mesh …) or a closed surface
                               # (.stl .obj .ply .off) tetrahedralised by gmsh
    size = 0.07                # m, > 0; gmsh size: shape or script override (shape default,
                               # script's DEFAULT_SIZE) or the surface's remeshing size
                               # (surface kept as given)

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
                               # route of the reduced method (lbshape.shapespace.interpolation
                               # ROUTE_CHOICES); auto = lb-table ("auto")

    [examples]                 # optional; no LB work without it
    stiffness = "auto"         # k_ex, 1/s^2, >= 0, or "auto" ("auto"): force k_ex (q* - q)
                               # in mass-normalised reduced coordinates; "auto": set by
                               # the precompute from the examples' own stiffness and the
                               # loads (lbshape.shapespace.auto_stiffness)
    ramp = 0.0                 # s, >= 0, finite: k_ex rises as k_ex s(min(1, t/ramp)),
                               # s(x) = 3x^2 - 2x^3, in every method
                               # (lbshape.dynamics.example_ramp); 0 = none (0)
    [[examples.pose]]          # one table per example, at least one
    shape = "bar-cylinder"     # built-in shape or gmsh script (.py), OR
    mesh = "example.msh"       # a mesh file (relative to the TOML file), any format above
    size = 0.05                # m, > 0, shape or surface file (also used for 'rest')
    pose = "twist"             # a key of lbshape.geometry.poses.POSES; omit if the mesh is posed
    rest = "example-rest.stl"  # posed mesh file only: the same example un-posed (any
                               # format, any resolution); without it the posed shape
                               # is compared with the object's rest shape
    parameters = { angle = 1.57 }  # pose parameters (poses.POSE_PARAMETERS); pose only
    landmarks = [[0, 12]]      # optional (object vertex, example vertex) int pairs >= 0
    hold = { group = "back" }  # with parts only: vertices kept at rest (region or group)
    [[examples.pose.parts]]    # instead of pose: the example posed part by part, the rest
    group = "left_leg"         #   of its mesh following harmonically; region or group
    pose = "arc"               #   selects the part on the example's rest mesh; parts are
    parameters = { angle = 0.8, direction = "z", axis = "y", anchor = "max" }  # disjoint

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
    stiffness = 1e6            # N/m^3 per area of the surface (k A_i per vertex), > 0
    friction = 0.5             # Coulomb coefficient μ, >= 0 (0: frictionless); free
                               # bodies only (an error with [fixed] when > 0)

    [initial]                  # optional, free bodies only (an error with [fixed])
    velocity = [0, 0, 0]       # m/s, world: centre-of-mass velocity ([0, 0, 0])
    angular_velocity = [0, 0, 0]   # rad/s, world ([0, 0, 0])

    [[regions]]                # local examples, zero or more; need [examples]
    name = "left"              # unique non-empty str
    region = "x < -0.2"        # expression, OR
    group = "left"             #   a physical group
    examples = [0, 1]          # unique indices into [[examples.pose]], at least one

    [simulation]
    dt = 0.001                 # s, > 0 (0.001)
    steps = 1000               # int >= 1 (1000)
    integrator = "newmark"     # "newmark" | "backward-euler" ("newmark")

Pose parameters (:data:`lbshape.geometry.poses.POSE_PARAMETERS`, the keywords of the poses):
``twist(angle [rad], axis, profile, anchor)``, ``s-bend(amplitude [m], direction,
axis, anchor)``, ``arc(angle [rad], direction, axis, anchor)``; the first is required,
the others default in lbshape.geometry.poses. ``axis``, ``direction``: ``"x"``, ``"y"`` or
``"z"``; ``anchor``: ``"min"`` | ``"max"`` (the bar end kept in place); ``profile``:
``"linear"`` | ``"smooth"`` (:data:`lbshape.geometry.poses.POSE_CHOICES`).

:meth:`Scene.precompute_key_fields` holds exactly what determines the precompute
(object, material, m/r/s and the other ``[reduced]`` settings, examples without
k_ex, fixed region, local regions); :meth:`Scene.runtime_fields` holds the rest
(dt, steps, integrator, damping, loads, k_ex and its ramp, planes).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import ClassVar

from lbshape.dynamics.contact import ContactPlane
from lbshape.dynamics.loads import TimeProfile
from lbshape.elastic.materials import Material
from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.io.cache import cache_key, file_digest

__all__ = [
    "LOAD_TYPES",
    "Damping",
    "ExamplePose",
    "Examples",
    "Load",
    "LocalRegion",
    "MeshSource",
    "PoseValue",
    "PosedPart",
    "Reduced",
    "Scene",
    "Selection",
    "Simulation",
    "mesh_arrays_digest",
]

#: load types (patterns: :mod:`lbshape.dynamics.loads`)
LOAD_TYPES: tuple[str, ...] = ("gravity", "region_force", "region_torque")

#: a pose parameter's value: a number or one of its string choices
PoseValue = float | str


@dataclass(frozen=True)
class MeshSource:
    """Where a mesh comes from: a built-in shape, a user's gmsh script (each with an
    optional size), a mesh file, or a mesh held in memory (a scene built in code,
    :func:`lbshape.scene.build.scene_from_mesh`); exactly one of ``shape``, ``script``,
    ``mesh_file``, ``mesh``.

    Attributes:
        shape: built-in shape name, or ``None``.
        mesh_file: absolute path of a mesh file (any format of
            :func:`lbshape.geometry.mesh_files.read_mesh_file`), or ``None``.
        size: gmsh size (m): a shape's or script's override, or a surface file's
            remeshing size; ``None`` for the shape's (script's ``DEFAULT_SIZE``)
            default or the surface as given.
        script: absolute path of a user's gmsh Python script
            (:func:`lbshape.geometry.shapes.build_script`), or ``None``.
        mesh: a checked :class:`~lbshape.geometry.mesh.TetMesh` in memory, or ``None``;
            compared and keyed by :attr:`mesh_digest` (its arrays' SHA-256).
        units: a mesh file's length unit ("m", "mm", "cm", "in"; a STEP file converts
            from its own).
        scale: metres per number of a mesh file, instead of ``units`` (or ``None``).
        piece: which piece of a surface or CAD file of several to keep (index, or
            "largest"), or ``None`` (one piece required).
        fill_holes: close the holes of an open surface file.
    """

    shape: str | None = None
    mesh_file: Path | None = None
    size: float | None = None
    script: Path | None = None
    mesh: TetMesh | None = field(default=None, compare=False, repr=False)
    mesh_digest: str | None = field(default=None, init=False)
    units: str = "m"
    scale: float | None = None
    piece: int | str | None = None
    fill_holes: bool = False

    def __post_init__(self) -> None:
        if self.mesh is not None:
            object.__setattr__(self, "mesh_digest", mesh_arrays_digest(self.mesh))

    @property
    def in_memory(self) -> bool:
        """The mesh is held in memory (no file, shape or script behind it)."""
        return self.mesh is not None

    @property
    def label(self) -> str:
        """A short name for captions: the shape's name or the file's name."""
        if self.shape is not None:
            return self.shape
        if self.mesh is not None:
            return f"mesh in memory ({self.mesh.n_vertices} vertices)"
        return Path(self.script if self.script is not None else self.mesh_file).name

    def key(self) -> dict:
        """What identifies the mesh: shape and size, the script's or file's SHA-256, or an
        in-memory mesh's arrays' digest (:func:`mesh_arrays_digest`)."""
        if self.shape is not None:
            return {"shape": self.shape, "size": self.size}
        if self.mesh is not None:
            return {"mesh_arrays_sha256": self.mesh_digest}
        if self.script is not None:
            if not self.script.is_file():
                raise LbshapeError(f"gmsh script not found: {self.script}")
            return {"script_sha256": file_digest(self.script), "size": self.size}
        if not self.mesh_file.is_file():
            raise LbshapeError(f"mesh file not found: {self.mesh_file}")
        key = {"mesh_sha256": file_digest(self.mesh_file)}
        if self.size is not None:
            key["size"] = self.size
        for name, default in (("units", "m"), ("scale", None), ("piece", None),
                              ("fill_holes", False)):
            if getattr(self, name) != default:  # keys of existing caches stay as they were
                key[name] = getattr(self, name)
        return key

    @property
    def read_options(self) -> dict:
        """Keyword arguments of :func:`lbshape.geometry.mesh_files.read_mesh_file`."""
        return {"size": self.size, "units": self.units, "scale": self.scale,
                "piece": self.piece, "fill_holes": self.fill_holes}


def mesh_arrays_digest(mesh: TetMesh) -> str:
    """SHA-256 over what defines a mesh in memory: its points (n, 3), tets (t, 4) and
    named groups (vertex and cell indices), by value and dtype."""
    return cache_key("mesh", mesh.points, mesh.tets,
                     {name: idx for name, idx in mesh.vertex_groups.items()},
                     {name: idx for name, idx in mesh.cell_groups.items()})


@dataclass(frozen=True)
class Selection:
    """A set of vertices: a safe region expression or a physical group name.

    Resolved on a mesh by :func:`lbshape.pipeline.meshes.selected_vertices`.
    """

    region: str | None = None
    group: str | None = None

    def key(self) -> dict:
        return {"region": self.region} if self.region is not None else {"group": self.group}


@dataclass(frozen=True)
class Damping:
    """Rayleigh damping ``D = alpha M + beta K0``: alpha in 1/s, beta in s."""

    alpha: float = 0.0
    beta: float = 0.0


#: ``reduced.impact_columns_per``: one set for the body, one for each hull feature, or one
#: for each pair of neighbouring hull features
IMPACT_COLUMN_SETS = ("body", "feature", "feature-pair")


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
        forces: the reduced elastic force: ``"polynomial"`` (exact, StVK only: the
            energy over every element as a polynomial in q), ``"cubature"`` (s trained
            elements), or ``"auto"`` (polynomial for StVK unless its build is too large
            for the mesh, :func:`lbshape.elastic.polynomial_forces.resolve_force_model`).
        impact_columns: a free body's impact columns appended to its basis (0: none;
            free bodies with contact planes only; :mod:`lbshape.pipeline.impact_columns`).
        impact_columns_per: ``"body"``: one set of ``impact_columns`` columns for every
            impact; ``"feature"``: ``impact_columns`` for each convex-hull feature (side,
            crease, corner), the set of the feature that hits switched on
            (:mod:`lbshape.dynamics.impact_switch`); ``"feature-pair"``: one set of
            2 × ``impact_columns`` for each pair of neighbouring features (both
            features' columns), the pair nearest the hit switched on.
    """

    m: int = 10
    r: int = 30
    s: int = 60
    linear_modes: int = 0
    cubature_tolerance: float = 0.01
    interpolation: str = "auto"
    forces: str = "auto"
    impact_columns: int = 0
    impact_columns_per: str = "body"

    @property
    def sets_per_feature(self) -> bool:
        """The impact columns come in sets per hull feature or pair of features (not one
        set for the body)."""
        return self.impact_columns_per != "body"


@dataclass(frozen=True)
class PosedPart:
    """One part of an example posed on its own (:attr:`ExamplePose.parts`).

    Attributes:
        selection: the part's vertices on the example's rest mesh.
        pose: a key of :data:`lbshape.geometry.poses.POSES`, applied to the part's
            own points (its extent along the pose axis, its anchor end).
        parameters: the pose's parameters (read-only mapping).
    """

    selection: Selection
    pose: str
    parameters: Mapping[str, PoseValue] = field(default_factory=lambda: MappingProxyType({}))

    def key(self) -> dict:
        return {**self.selection.key(), "pose": self.pose, "parameters": dict(self.parameters)}


@dataclass(frozen=True)
class ExamplePose:
    """One example: a mesh and an optional analytic pose applied to it.

    An example given as a mesh file without a pose is a posed shape (a built-in
    shape without a pose is the shape at rest). With ``rest`` (its un-posed
    shape, any mesh or topology) its displacement is the posed shape's LB
    coefficients minus the rest's, each in its own basis mapped to the object's;
    without ``rest`` the object's rest coefficients are subtracted instead
    (:mod:`lbshape.shapespace.projections`).

    Attributes:
        source: the example's mesh.
        pose: a key of :data:`lbshape.geometry.poses.POSES`, or ``None`` if the mesh
            is already posed.
        rest: the un-posed example mesh of a posed one, or ``None``.
        parameters: pose parameters (read-only mapping; see
            :data:`lbshape.geometry.poses.POSE_PARAMETERS`).
        landmarks: (object vertex, example vertex) correspondences.
        parts: instead of ``pose``, the example posed part by part
            (:func:`lbshape.geometry.poses.pose_parts`): each part by its own pose,
            the rest of the mesh following harmonically.
        hold: with ``parts``, vertices kept at rest, or ``None``.
    """

    source: MeshSource
    pose: str | None = None
    parameters: Mapping[str, PoseValue] = field(default_factory=lambda: MappingProxyType({}))
    landmarks: tuple[tuple[int, int], ...] = ()
    rest: MeshSource | None = None
    parts: tuple[PosedPart, ...] = ()
    hold: Selection | None = None

    @property
    def is_posed_file(self) -> bool:
        """A mesh file (or a mesh in memory) without analytic pose: it holds the posed
        shape."""
        return self.pose is None and not self.parts and (
            self.source.mesh_file is not None or self.source.mesh is not None)

    def key(self) -> dict:
        key = {} if self.rest is None else {"rest": self.rest.key()}
        if self.parts:
            key["parts"] = [part.key() for part in self.parts]
            key["hold"] = None if self.hold is None else self.hold.key()
        return {
            **key,
            "source": self.source.key(),
            "pose": self.pose,
            "parameters": dict(self.parameters),
            "landmarks": [list(pair) for pair in self.landmarks],
        }


@dataclass(frozen=True)
class Examples:
    """The example poses and the example-force stiffness k_ex (1/s²), or ``"auto"``
    (:data:`AUTO_STIFFNESS`: the precompute sets it, :mod:`lbshape.shapespace.auto_stiffness`)."""

    stiffness: float | str
    poses: tuple[ExamplePose, ...]
    #: seconds over which k_ex rises from 0 (:mod:`lbshape.dynamics.example_ramp`); 0: none
    ramp: float = 0.0

    #: the ``stiffness`` that lets the precompute set k_ex (:data:`AUTO_STIFFNESS`)
    AUTO: ClassVar[str] = "auto"

    @property
    def auto(self) -> bool:
        """k_ex is set by the precompute (``stiffness = "auto"``)."""
        return isinstance(self.stiffness, str) and self.stiffness == AUTO_STIFFNESS

    @property
    def acts(self) -> bool:
        """The example force can act: ``"auto"`` or k_ex > 0."""
        return self.auto or self.stiffness > 0


#: ``[examples] stiffness = "auto"`` (the default of scenes that give no number)
AUTO_STIFFNESS = Examples.AUTO


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
class Initial:
    """Initial rigid motion of a free body (world frame): m/s and rad/s."""

    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    angular_velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class LocalRegion:
    """A region of the object with its own examples (indices into the example list)."""

    name: str
    selection: Selection
    examples: tuple[int, ...]


@dataclass(frozen=True)
class Simulation:
    """Time stepping: dt (s), number of steps, integrator name, ``contact_dt`` (s):
    the reduced free body's longest pass while a plane touches it (``None``: the
    default, :data:`lbshape.dynamics.free_body_passes.CONTACT_DT`), and ``flight_dt``
    (s): its longest pass in flight (``None``: the pass that resolves its highest
    frequency, :func:`lbshape.dynamics.free_body_passes.resolved_pass`)."""

    dt: float = 0.001
    steps: int = 1000
    integrator: str = "newmark"
    contact_dt: float | None = None
    flight_dt: float | None = None


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
        initial: initial rigid motion of a free body (``Initial()`` = at rest).
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
    planes: tuple[ContactPlane, ...] = ()
    regions: tuple[LocalRegion, ...] = ()
    simulation: Simulation = field(default_factory=Simulation)
    description: str = ""
    initial: Initial = field(default_factory=Initial)
    source: Path | None = None

    #: ``Scene.from_mesh(mesh, *, name, fixed, material, examples, loads, dt, steps, ...)``:
    #: a scene built in code from a mesh in memory, no file needed
    #: (:func:`lbshape.scene.build.scene_from_mesh`, validated by the reader's checks; bound
    #: by :mod:`lbshape.scene`, which is imported with this module)
    from_mesh: ClassVar[Callable[..., Scene]]

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
                        "cubature_tolerance": self.reduced.cubature_tolerance,
                        "forces": self.reduced.forces,
                        **({"impact_columns": self.reduced.impact_columns}
                           if self.reduced.impact_columns else {}),
                        **({"impact_columns_per": self.reduced.impact_columns_per}
                           if self.reduced.sets_per_feature else {})},
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
            **({"contact_dt": self.simulation.contact_dt}
               if self.simulation.contact_dt is not None else {}),
            **({"flight_dt": self.simulation.flight_dt}
               if self.simulation.flight_dt is not None else {}),
            "interpolation": self.reduced.interpolation,
            "damping": {"alpha": self.damping.alpha, "beta": self.damping.beta},
            "loads": [load.key() for load in self.loads],
            "k_ex": None if self.examples is None else self.examples.stiffness,
            **({"example_ramp": self.examples.ramp}
               if self.examples is not None and self.examples.ramp else {}),
            "planes": [{"point": list(p.point), "normal": list(p.normal),
                        "stiffness": p.stiffness, "friction": p.friction}
                       for p in self.planes],
            "initial": {"velocity": list(self.initial.velocity),
                        "angular_velocity": list(self.initial.angular_velocity)},
        }
