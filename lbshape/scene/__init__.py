"""Scenes: the schema dataclasses (data only), the TOML reader and the built-in scenes."""

from lbshape.scene.reader import builtin_scene_names, load_scene, mesh_source, scene_from_dict
from lbshape.scene.schema import Scene

__all__ = [
    "Scene",
    "builtin_scene_names",
    "load_scene",
    "mesh_source",
    "scene_from_dict",
]
