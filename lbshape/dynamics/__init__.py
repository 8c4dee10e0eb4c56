"""Time stepping: implicit integrators, loads, the reduced and full-space engines (one
protocol: :mod:`lbshape.dynamics.engine`), run records."""

__all__ = [
    "engine",
    "full",
    "integrators",
    "loads",
    "record",
    "reduced",
]
