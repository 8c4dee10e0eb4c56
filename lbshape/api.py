"""The public API: a scene, its precompute and a simulation, in a few calls.

Re-exported by :mod:`lbshape` (``lbshape.load_scene``, …). Units are SI throughout
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
"""

from __future__ import annotations

from lbshape.dynamics.record import RunRecord
from lbshape.errors import LbshapeError, SolverError
from lbshape.geometry.mesh import TetMesh
from lbshape.geometry.mesh_files import read_mesh_file as read_mesh
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulation import Simulation, simulation
from lbshape.scene import Scene, load_scene
from lbshape.spectral.spectrum import lb_spectrum

__all__ = [
    "LbshapeError",
    "RunRecord",
    "Scene",
    "Simulation",
    "SolverError",
    "TetMesh",
    "lb_spectrum",
    "load_scene",
    "precompute",
    "read_mesh",
    "simulation",
]
