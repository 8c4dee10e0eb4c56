"""Loads on a free body reduced to small tensors (:class:`FreeLoad`) and stacked for the
compiled step (:class:`LoadStack`), as :class:`~lbshape.dynamics.free_body.FreeBodySimulation`
applies them: per step a total force, a torque about the centre of mass and a generalized
force, no n-sized work."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lbshape.dynamics.free_body_kernels import loads_into
from lbshape.dynamics.loads import TimeProfile


@dataclass(frozen=True)
class FreeLoad:
    """A load on a free body, reduced to small tensors (forces f_i are world vectors).

    Attributes:
        force: (3,) total force Σ f_i (N).
        P: (r, 3, 3) ``P[j, b, a] = Σ_i U_ibj f_ia``: ``Uᵀ Rᵀ f = Σ_ab R_ab P[:, b, a]``.
        Z0: (3, 3) ``Σ_i X̄_id f_ia`` (N·m), indices [d, a].
        Z1: (r, 3, 3) ``Σ_i U_idj f_ia``, indices [j, d, a].
        profile: time profile.
    """

    force: np.ndarray
    P: np.ndarray
    Z0: np.ndarray
    Z1: np.ndarray
    profile: TimeProfile

    @classmethod
    def from_pattern(cls, pattern: np.ndarray, U: np.ndarray, body_points: np.ndarray,
                     profile: TimeProfile) -> FreeLoad:
        """Reduce a world nodal force pattern (3n,) N; ``body_points`` (n, 3) = X̄."""
        f = np.asarray(pattern, dtype=float).reshape(-1, 3)
        n, r = f.shape[0], U.shape[1]
        Ur = np.asarray(U).reshape(n, 3, r)
        loaded = np.flatnonzero(np.abs(f).sum(axis=1))
        f, Ur, X = f[loaded], Ur[loaded], body_points[loaded]
        return cls(f.sum(axis=0), np.einsum("ibj,ia->jba", Ur, f), X.T @ f,
                   np.einsum("idj,ia->jda", Ur, f), profile)

    def evaluate(self, rotation: np.ndarray, q: np.ndarray, t: float):
        """``(force (3,) world, torque about c (3,) world, generalized (r,))`` at t."""
        stack = LoadStack([self])
        force, torque, generalized = np.zeros(3), np.zeros(3), np.zeros(self.P.shape[0])
        stack.evaluate_into(np.asarray(rotation, dtype=float), np.asarray(q, dtype=float), t,
                            force, torque, generalized)
        return force, torque, generalized


class LoadStack:
    """Several :class:`FreeLoad` as stacked arrays for :func:`loads_into` (no allocation
    per evaluation)."""

    def __init__(self, loads: Sequence[FreeLoad], r: int | None = None):
        loads = list(loads)
        r = loads[0].P.shape[0] if loads else int(r or 0)
        self.forces = np.array([load.force for load in loads], dtype=float).reshape(-1, 3)
        self.P = np.array([load.P for load in loads], dtype=float).reshape(-1, r, 3, 3)
        self.Z0 = np.array([load.Z0 for load in loads], dtype=float).reshape(-1, 3, 3)
        self.Z1 = np.array([load.Z1 for load in loads], dtype=float).reshape(-1, r, 3, 3)
        self.profiles = [load.profile for load in loads]
        self.scales = np.zeros(len(loads))
        self._work = np.zeros((2, 3, 3))

    def evaluate_into(self, rotation: np.ndarray, q: np.ndarray, t: float, force: np.ndarray,
                      torque: np.ndarray, generalized: np.ndarray) -> None:
        """Total force (3,) and torque about c (3,) (world) and generalized force (r,) at t."""
        for index, profile in enumerate(self.profiles):
            self.scales[index] = profile(t)
        loads_into(rotation, q, self.scales, self.forces, self.P, self.Z0, self.Z1, force,
                   torque, generalized, self._work)
