"""Time stepping: implicit integrators, loads, the reduced and full-space engines, run records."""

__all__ = [
    "full",
    "integrators",
    "loads",
    "record",
    "reduced",
]
