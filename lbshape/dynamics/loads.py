"""External loads: nodal force vectors and their time profiles.

A load (:class:`TimedLoad`) is a fixed spatial pattern ``f (3n,)`` in newtons times
a scalar time profile. Patterns are built once (n-sized, precompute); the reduced runtime only
uses ``Uᵀ f`` (r,). Distribution over a region is by lumped (row-sum) mass, so a
coarse or graded mesh carries the same resultant.

* gravity: ``f = M g`` with the consistent mass (exact for a uniform field);
* region force: total force F (N) spread over the region: ``f_i = F m_i / Σ m``;
* region torque: torque τ (N·m) about the region's centre c as tangential forces
  ``f_i = m_i τ × (x_i − c) / Σ_j m_j |(x_j − c)_⊥|²`` (⊥: normal to τ), whose
  moment about c along τ equals |τ| and whose resultant is zero.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from lbshape.errors import LbshapeError

PROFILES = ("constant", "ramp", "pulse")


@dataclass(frozen=True)
class TimeProfile:
    """Scalar multiplier of a load over time (s).

    ``constant``: 1 from ``start`` on; ``ramp``: linear from 0 at ``start`` to 1 at
    ``start + duration``, then 1; ``pulse``: 1 during ``[start, start + duration)``.
    """

    kind: str = "constant"
    start: float = 0.0
    duration: float = 0.0

    def __post_init__(self):
        if self.kind not in PROFILES:
            raise LbshapeError(f"load profile must be one of {PROFILES}, got {self.kind!r}")
        if self.kind != "constant" and not self.duration > 0:
            raise LbshapeError(f"load profile {self.kind!r} needs duration > 0 s")

    def __call__(self, t: float) -> float:
        if t < self.start:
            return 0.0
        if self.kind == "constant":
            return 1.0
        if self.kind == "ramp":
            return min(1.0, (t - self.start) / self.duration)
        return 1.0 if t < self.start + self.duration else 0.0


@dataclass(frozen=True)
class TimedLoad:
    """An external load ``profile(t) · pattern`` in an engine's coordinates.

    Attributes:
        pattern: (p,) generalized forces: nodal forces (3n,) in N, node-major, for the
            full-space engine; their projection ``Uᵀ f`` (r,) for the reduced engine.
        profile: its time profile.
    """

    pattern: np.ndarray
    profile: TimeProfile


def gravity_pattern(mass: sp.spmatrix, acceleration: np.ndarray) -> np.ndarray:
    """(3n,) ``M g`` for a node-major consistent mass (3n,3n) and g (3,) in m/s²."""
    n3 = mass.shape[0]
    field = np.tile(np.asarray(acceleration, dtype=float), n3 // 3)
    return mass @ field


def lumped_masses(mass: sp.spmatrix) -> np.ndarray:
    """(n,) nodal masses (row sums of the x-component rows of a node-major mass)."""
    return np.asarray(mass.sum(axis=1)).ravel()[0::3]


def region_force_pattern(mass: sp.spmatrix, vertices: np.ndarray, force: np.ndarray) -> np.ndarray:
    """(3n,) total ``force`` (3,) N spread over ``vertices`` by lumped mass."""
    m = lumped_masses(mass)
    out = np.zeros((m.size, 3))
    share = m[vertices] / m[vertices].sum()
    out[vertices] = share[:, None] * np.asarray(force, dtype=float)[None, :]
    return out.ravel()


def region_torque_pattern(
    mass: sp.spmatrix, points: np.ndarray, vertices: np.ndarray, torque: np.ndarray
) -> np.ndarray:
    """(3n,) tangential forces on ``vertices`` with moment ``torque`` (3,) N·m about
    the region's mass centre."""
    torque = np.asarray(torque, dtype=float)
    norm = np.linalg.norm(torque)
    out = np.zeros_like(points)
    if norm == 0.0:
        return out.ravel()
    m = lumped_masses(mass)[vertices]
    x = points[vertices]
    arm = x - (m[:, None] * x).sum(axis=0) / m.sum()
    axis = torque / norm
    perpendicular = arm - np.outer(arm @ axis, axis)
    inertia = float(np.sum(m * np.einsum("ij,ij->i", perpendicular, perpendicular)))
    if inertia <= 0.0:
        raise LbshapeError("a region torque needs a region with extent across the torque axis")
    out[vertices] = m[:, None] * np.cross(torque, arm) / inertia
    return out.ravel()
