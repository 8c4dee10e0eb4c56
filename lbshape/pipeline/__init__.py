"""From a scene to results: its meshes, the cached precompute, target routes, running a method."""

__all__ = [
    "meshes",
    "precompute",
    "routes",
    "simulate",
]
