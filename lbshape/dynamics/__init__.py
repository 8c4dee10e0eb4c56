"""Time stepping: implicit integrators, external loads, and the reduced and full-space engines."""

__all__ = [
    "full",
    "integrators",
    "loads",
    "reduced",
]
