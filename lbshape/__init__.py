"""lbshape: real-time example-based elastic materials in Laplace-Beltrami shape space.

The public API (:mod:`lbshape.api`, names in ``__all__``)::

    import lbshape
    scene = lbshape.load_scene("bar-cuboid")            # or lbshape.Scene.from_mesh(mesh, ...)
    pre = lbshape.precompute(scene)                     # cached
    sim = lbshape.simulation(scene, pre, method="reduced")   # "reduced" | "euclidean" | "full"
    for _ in range(300):
        sim.step()
    u = sim.displacement()                              # (n, 3) world displacement, m

``import lbshape`` is light: the API's modules (numerics, FEM) load on the first use of
one of its names.

Conventions used throughout the package:

* SI units (metres, kilograms, seconds, pascals).
* A mesh is a :class:`lbshape.geometry.mesh.TetMesh`: linear tetrahedra, positively oriented.
* Nodal fields are stored in the mesh's *input vertex order*. A vector field on n
  vertices is a ``(n, 3)`` array, or flattened node-major as ``(3n,)`` with
  ``u[3*i + c]`` the component ``c`` of vertex ``i``.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

__version__ = "0.1.0"

__all__ = [
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

if TYPE_CHECKING:
    from lbshape.api import (
        METHODS,
        RUN_FILES,
        SHAPES,
        SURFACE_FORMATS,
        WARMUP_STEPS,
        LbshapeError,
        Material,
        RunRecord,
        Scene,
        Simulation,
        SimulationOutput,
        SolverError,
        TetMesh,
        build_mesh,
        compare,
        expand_scenes,
        get_shape,
        lb_spectrum,
        linear_modes,
        load_scene,
        mesh_source,
        precompute,
        read_mesh,
        region_vertices,
        run_collectively,
        run_error,
        run_jobs,
        simulate,
        simulation,
        summary_table,
        write_mesh,
        write_outputs,
    )


def __getattr__(name: str):
    """The API's names, loaded from :mod:`lbshape.api` on first use (PEP 562)."""
    if name in __all__:
        value = getattr(importlib.import_module("lbshape.api"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'lbshape' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
