"""The public API: a scene, its precompute and a simulation, in a few calls.

The names of the first two groups below are re-exported by :mod:`lbshape`
(``lbshape.load_scene``, …); the building blocks of the third are reached as
``lbshape.api.<name>``. Units are SI throughout
(m, kg, s, Pa); a vector field on the object's n vertices is an (n, 3) array in the
mesh's vertex order::

    import lbshape

    scene = lbshape.load_scene("bar-cuboid")          # a built-in name or a .toml path
    # or a scene built in code, no file: a TetMesh or (points, tets) arrays
    scene = lbshape.Scene.from_mesh(mesh, name="clip", fixed="z < 0.01",
                                    material={"young": 2e5, "density": 1000},
                                    examples=[{"pose": "twist", "parameters": {"angle": 1.0}}],
                                    example_stiffness=100.0, dt=0.005)
    pre = lbshape.precompute(scene)                   # cached as the CLI does
    sim = lbshape.simulation(scene, pre, method="reduced")  # "reduced" | "euclidean" | "full"
    for _ in range(300):
        sim.step()
    u = sim.displacement()                            # (n, 3) world displacement, m
    sim.time                                          # s
    sim.set_examples(False); sim.grab(vertex, target); sim.release(); sim.reset()
    record = sim.run(100)                             # RunRecord: times (f,), states

What each name is:

* :func:`load_scene` — a built-in scene (:func:`lbshape.scene.builtin_scene_names`) or a
  scene file, validated (:mod:`lbshape.scene.schema` is the file format).
* :class:`Scene` — a validated scene (frozen data); :meth:`Scene.from_mesh` builds one in
  code from a mesh in memory, with example poses in code (analytic ``twist``, ``arc``,
  ``s-bend`` of :mod:`lbshape.geometry.poses` on the object's mesh, or posed copies of it).
* :func:`precompute` — the scene's precompute (LB spectrum, basis U (3n, r), forces,
  examples), read from the cache (``$LBSHAPE_CACHE``, else ``~/.cache/lbshape``) or
  computed and stored there; nothing else is written.
* :func:`simulation` / :class:`Simulation` — the running scene, one handle for the three
  methods: ``step()``, ``run(steps)``, ``time``, ``displacement()``, ``state`` /
  ``reset()``, ``set_examples(on)``, ``grab`` / ``move`` / ``release``.
* :class:`RunRecord` — what ``run`` returns: sample ``times`` (f,) s, the engine's
  ``states``, per-step timings and Newton iterations, ``stable`` and ``message``.
* :class:`TetMesh` — a linear tetrahedral mesh: ``points`` (n, 3) m, ``tets`` (t, 4).
* :func:`read_mesh` — a mesh file (``.msh``, a meshio volume, or a closed surface
  tetrahedralised by gmsh at ``size`` m) as a checked :class:`TetMesh`.
* :func:`lb_spectrum` — the m smallest non-zero Laplace-Beltrami eigenpairs of a mesh
  (eigenvalues in 1/m², eigenvectors (n, m)).
* :class:`LbshapeError` — every error of bad input, one line; :class:`SolverError` (a
  subclass) — a solver that failed (a step, an eigenproblem).

A run with its outputs, and its error against the full-space reference (what
``lbshape simulate`` does)::

    out = lbshape.simulate(scene, pre, method="reduced", out="runs/bar",
                           compare="full")   # stats.json, states.npz, trajectory
    out.stats["error_vs_full"], out.stats["speed_up"]
    error = lbshape.compare(scene, pre, out)  # or afterwards: the same keys as a dict

* :func:`simulate` — run a scene for its steps (or ``steps``) with one of
  :data:`METHODS`; returns a :class:`SimulationOutput` (``stats``, sampled ``times``
  (k,) s and ``displacements`` (k, n, 3) m, ``message`` of a stopped run). With ``out``
  the folder is written (:func:`write_outputs`: ``stats.json``, ``states.npz``, the
  ParaView trajectory; only :data:`RUN_FILES`, a folder holding anything else is
  refused); ``influence=True`` adds the example influence; ``compare="full"`` runs the
  full reference once and adds its error and speed-up (:func:`compare`).
* :func:`compare` — the ``full`` reference of a run, run once, and the run's error
  against it: ``{"error_vs_full", "final_error_vs_full", "full_t_total_ms",
  "speed_up", "compare_message"}`` (+ a free body's centre / rotation / deformation
  split); a reference that stops gives ``None`` values and the reason, never an error.
* :func:`run_error` — the error of one run's trajectory against a reference's (the one
  computation behind :func:`compare` and the benchmark's ``error_vs_full``).
* :data:`WARMUP_STEPS` — steps left out of the per-step timing means.

Building blocks the command line uses (meshes, modes, several scenes at once; in
``lbshape.api`` only):

* :func:`mesh_source` — what a mesh argument names (a built-in shape in :data:`SHAPES`,
  a gmsh script, a mesh file, a surface in :data:`SURFACE_FORMATS`, a CAD solid in
  :data:`CAD_FORMATS`, coordinates in one of :data:`LENGTH_UNITS`); :func:`build_mesh`
  makes its :class:`TetMesh`, :func:`write_mesh` writes it as ``.msh``;
  :func:`get_shape` a built-in shape's description (unknown names list the shapes).
* :func:`linear_modes` — the lowest linear elastic vibration modes of a mesh for a
  :class:`Material` (Pa, kg/m³), a region clamped by :func:`region_vertices`.
* :func:`run_collectively` — read inputs on MPI rank 0 and solve on every rank.
* :func:`expand_scenes`, :func:`run_jobs`, :func:`summary_table` — several scenes (names,
  TOML paths, globs) as jobs in worker processes, and their summary table.
"""

from __future__ import annotations

from lbshape.dynamics.record import RunRecord
from lbshape.elastic.materials import Material
from lbshape.elastic.modes import linear_modes
from lbshape.errors import LbshapeError, SolverError
from lbshape.fem.mpi import run_collectively
from lbshape.geometry.mesh import TetMesh
from lbshape.geometry.mesh_files import CAD_FORMATS, LENGTH_UNITS, SURFACE_FORMATS
from lbshape.geometry.mesh_files import read_mesh_file as read_mesh
from lbshape.geometry.regions import region_vertices
from lbshape.geometry.shapes import SHAPES, get_shape
from lbshape.pipeline.batch import expand_scenes, run_jobs, summary_table
from lbshape.pipeline.meshes import build_mesh, write_mesh
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import (
    METHODS,
    RUN_FILES,
    WARMUP_STEPS,
    SimulationOutput,
    compare,
    run_error,
    simulate,
    write_outputs,
)
from lbshape.pipeline.simulation import Simulation, simulation
from lbshape.scene import Scene, load_scene, mesh_source
from lbshape.spectral.spectrum import lb_spectrum

__all__ = [
    "CAD_FORMATS",
    "LENGTH_UNITS",
    "LbshapeError",
    "METHODS",
    "Material",
    "RUN_FILES",
    "RunRecord",
    "SHAPES",
    "SURFACE_FORMATS",
    "Scene",
    "Simulation",
    "SimulationOutput",
    "SolverError",
    "TetMesh",
    "WARMUP_STEPS",
    "build_mesh",
    "compare",
    "expand_scenes",
    "get_shape",
    "lb_spectrum",
    "linear_modes",
    "load_scene",
    "mesh_source",
    "precompute",
    "read_mesh",
    "region_vertices",
    "run_collectively",
    "run_error",
    "run_jobs",
    "simulate",
    "simulation",
    "summary_table",
    "write_mesh",
    "write_outputs",
]
