"""The LB shape space: frames, basis alignment, projections, interpolation, example energies."""

__all__ = [
    "alignment",
    "euclidean_energy",
    "example_shapes",
    "example_driver",
    "frames",
    "interpolation",
    "local_build",
    "local_driver",
    "local_full_force",
    "local_regions",
    "local_space",
    "projections",
]
