"""The bound a physical state stays within: the deformation against the object's size.

A reduced state q (r,) in mass-orthonormal coordinates (``UᵀMU = I``) measures its
displacement in the mass norm, ``‖q‖ = ‖U q‖_M``, so ``‖q‖ / √mass`` is the
mass-weighted RMS displacement in m — an r-sized check, no n-sized work. An elastic
object whose RMS displacement exceeds its own bounding-box diagonal has left the
physics a scene models (a twist, a bend or a sag moves it by a fraction of its size;
even a bar stretched to 2.7 times its length stays below it): the engines stop there
with the step named instead of reporting a finished run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lbshape.errors import LbshapeError, SolverError


@dataclass(frozen=True)
class DeformationBound:
    """Largest RMS displacement a state may reach before the run stops.

    Attributes:
        mass: the object's mass in kg.
        size: its bounding-box diagonal at rest in m (the largest RMS displacement allowed).
    """

    mass: float
    size: float

    def __post_init__(self):
        if not (self.mass > 0 and self.size > 0 and math.isfinite(self.mass * self.size)):
            raise LbshapeError(f"deformation bound needs a positive mass and size, got "
                               f"{self.mass} kg and {self.size} m")

    @classmethod
    def for_object(cls, points: np.ndarray, mass: float) -> DeformationBound:
        """The bound of an object with rest positions ``points`` (n, 3) in m and mass in kg."""
        points = np.asarray(points, dtype=float)
        return cls(float(mass), float(np.linalg.norm(points.max(axis=0) - points.min(axis=0))))

    @property
    def q_norm_limit(self) -> float:
        """The bound as a limit on ‖q‖ (kg^½ m)."""
        return self.size * math.sqrt(self.mass)

    def check(self, q: np.ndarray, index: int, t: float) -> None:
        """Raise :class:`~lbshape.errors.SolverError` naming step ``index`` (time t in s)
        when the state q (r,) lies outside the bound (no array is allocated)."""
        norm = math.sqrt(float(np.dot(q, q)))
        if norm > self.q_norm_limit:
            raise SolverError(
                f"the state left the physics at step {index} (t = {t:.6g} s): RMS "
                f"displacement {norm / math.sqrt(self.mass):.3g} m exceeds the object's size "
                f"{self.size:.3g} m (its bounding-box diagonal); lower dt")
