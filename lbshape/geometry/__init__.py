"""Geometry: tetrahedral meshes and checks, primitives, built-in shapes, regions, poses."""

__all__ = [
    "mesh",
    "poses",
    "primitives",
    "regions",
    "shapes",
]
