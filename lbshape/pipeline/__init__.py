"""From a scene to results: the cached precompute, the interpolation routes and running a method."""

__all__ = [
    "meshes",
    "precompute",
    "routes",
    "simulate",
]
