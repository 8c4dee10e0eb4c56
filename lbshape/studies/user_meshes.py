"""A user's own mesh as a scene, for the studies and the tests.

:func:`user_mesh_scene` writes the ``l-beam`` shape to a ``.msh`` file and builds the
scene that reads it, as a user with a mesh of their own would: the object is a file,
not a built-in shape.
"""

from __future__ import annotations

from pathlib import Path

from lbshape.geometry.mesh_files import write_msh
from lbshape.geometry.shapes import build_shape
from lbshape.scene.reader import scene_from_dict
from lbshape.scene.schema import Scene

__all__ = ["user_mesh_scene"]


def user_mesh_scene(folder: Path) -> Scene:
    """A user's own mesh: the ``l-beam`` shape written to ``folder/l-beam.msh`` and a scene
    that reads it — fixed at the end of its arm (x = 1 m), sagging under gravity and pulled
    (k_ex = 2000 s⁻²) by a twisted and a bent copy of itself."""
    write_msh(build_shape("l-beam"), Path(folder) / "l-beam.msh")
    pose = {"mesh": "l-beam.msh"}
    return scene_from_dict({
        "object": {"mesh": "l-beam.msh"},
        "material": {"model": "stvk", "young": 1e6, "poisson": 0.3, "density": 1000.0},
        "damping": {"alpha": 0.5, "beta": 0.01},
        "reduced": {"m": 8, "r": 20, "s": 40},
        "examples": {"stiffness": 2000.0, "pose": [
            {**pose, "pose": "twist", "parameters": {"angle": 0.8, "axis": "x",
                                                      "anchor": "max"}},
            {**pose, "pose": "arc", "parameters": {"angle": 0.5, "axis": "x",
                                                    "anchor": "max", "direction": "z"}}]},
        "fixed": {"region": "x > 0.999"},
        "loads": [{"type": "gravity", "vector": [0.0, 0.0, -9.81]}],
        "simulation": {"dt": 0.001, "steps": 400},
    }, name="l-beam", base_dir=Path(folder))
