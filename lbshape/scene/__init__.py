"""Scenes: the schema dataclasses (data only), the TOML reader, the built-in scenes and
variants of a scene (:mod:`lbshape.scene.variants`)."""

from lbshape.scene.reader import builtin_scene_names, load_scene, mesh_source, scene_from_dict
from lbshape.scene.schema import Scene

__all__ = [
    "Scene",
    "builtin_scene_names",
    "load_scene",
    "mesh_source",
    "scene_from_dict",
]
