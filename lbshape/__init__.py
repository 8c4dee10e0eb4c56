"""lbshape: real-time example-based elastic materials in Laplace-Beltrami shape space.

The public API: the names in ``__all__`` (a scene, its precompute, a simulation, a run
with its error against the full reference); :mod:`lbshape.api` also holds the building
blocks the command line uses (meshes, modes, several scenes at once)::

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
    "RunRecord",
    "Scene",
    "Simulation",
    "SimulationOutput",
    "SolverError",
    "TetMesh",
    "compare",
    "lb_spectrum",
    "load_scene",
    "precompute",
    "read_mesh",
    "run_error",
    "simulate",
    "simulation",
]

if TYPE_CHECKING:
    from lbshape.api import (
        METHODS,
        LbshapeError,
        RunRecord,
        Scene,
        Simulation,
        SimulationOutput,
        SolverError,
        TetMesh,
        compare,
        lb_spectrum,
        load_scene,
        precompute,
        read_mesh,
        run_error,
        simulate,
        simulation,
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
