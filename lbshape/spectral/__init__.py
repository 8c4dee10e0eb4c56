"""The Laplace-Beltrami spectrum of a tetrahedral mesh (paper §4.1)."""

__all__ = [
    "spectrum",
]
