"""Scenes: the schema dataclasses (data only), the TOML reader, scenes built in code, the
built-in scenes and variants of a scene (:mod:`lbshape.scene.variants`)."""

from lbshape.scene.build import scene_from_mesh
from lbshape.scene.reader import builtin_scene_names, load_scene, mesh_source, scene_from_dict
from lbshape.scene.schema import Scene

# ``Scene.from_mesh``: the schema module holds data only and cannot import the reader's checks
# (they import the schema), so the constructor is bound here, where both are imported.
Scene.from_mesh = staticmethod(scene_from_mesh)

__all__ = [
    "Scene",
    "builtin_scene_names",
    "load_scene",
    "mesh_source",
    "scene_from_dict",
    "scene_from_mesh",
]
