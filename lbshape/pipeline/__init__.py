"""From a scene to results: its meshes, the cached precompute, target routes, running a method."""

__all__ = [
    "batch",
    "influence",
    "meshes",
    "precompute",
    "routes",
    "simulate",
]
