"""The LB shape space: frames, basis alignment, projections, interpolation, example energies."""

__all__ = [
    "alignment",
    "euclidean_energy",
    "example_shapes",
    "example_driver",
    "frames",
    "interpolation",
    "local_examples",
    "projections",
]
