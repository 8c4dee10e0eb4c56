"""What a free-body run produced (:class:`FreeBodyRecord`), collected step by step by
:class:`FreeBodyRecorder`, and the world displacements of a free body
(:func:`world_displacements`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lbshape.dynamics.record import RunRecord
from lbshape.errors import LbshapeError


@dataclass(frozen=True)
class FreeBodyRecord(RunRecord):
    """What a free-body run produced: the common record plus the rigid frame.

    ``states`` are the body-frame reduced coordinates q; every sampled array below
    is taken at ``times`` (f,), every per-step array has one entry per step (k,).
    The split of each step's time into :data:`PHASES` is the simulation's
    :attr:`FreeBodySimulation.phase_seconds`.

    Attributes:
        centers: (f, 3) centre of mass (m, world).
        rotations: (f, 3, 3) body-to-world rotations.
        momenta: (f, 3) linear momentum (kg·m/s, world).
        angular_momenta: (f, 3) angular momentum about c (kg·m²/s, world).
        energies: (f,) total energy (J) without the gravity potential.
        contact_depth: (k,) largest penetration per step (m).
        rest_points: (n, 3) rest positions X (m); ``body_points`` (n, 3) X̄ = X − X_cm.
    """

    centers: np.ndarray | None = None
    rotations: np.ndarray | None = None
    momenta: np.ndarray | None = None
    angular_momenta: np.ndarray | None = None
    energies: np.ndarray | None = None
    contact_depth: np.ndarray | None = None
    rest_points: np.ndarray | None = None
    body_points: np.ndarray | None = None

    def displacements(self, basis: np.ndarray | None = None) -> np.ndarray:
        """(f, n, 3) world displacements ``x − X = c + R (X̄ + U q) − X`` (m); basis = U."""
        return world_displacements(self.centers, self.rotations, self.states, basis,
                                   self.rest_points, self.body_points)


def world_displacements(centers: np.ndarray, rotations: np.ndarray, states: np.ndarray,
                        basis: np.ndarray | None, rest_points: np.ndarray | None,
                        body_points: np.ndarray | None) -> np.ndarray:
    """(f, n, 3) world displacements ``x − X = c + R (X̄ + U q) − X`` (m) of a free body at
    f instants: centres (f, 3) m, rotations (f, 3, 3), deformations q (f, r), the basis U
    (3n, r), the rest points X (n, 3) m and the body points X̄ = X − X_cm (n, 3) m."""
    if basis is None or rest_points is None:
        raise LbshapeError("free-body displacements need the basis U and the rest points")
    n = rest_points.shape[0]
    local = body_points[None] + (states @ np.asarray(basis).T).reshape(-1, n, 3)
    world = np.einsum("fij,fnj->fni", rotations, local) + centers[:, None, :]
    return world - rest_points[None]


class FreeBodyRecorder:
    """Collects a free-body run step by step (the states every ``stride``-th step, the
    per-step timings); :meth:`record` freezes it into a :class:`FreeBodyRecord`.

    Args:
        sim: the :class:`~lbshape.dynamics.free_body.FreeBodySimulation`.
        steps: the steps planned (sizes the per-step arrays).
        stride: keep the initial state and every ``stride``-th state, ≥ 1.
    """

    _KEYS = ("times", "states", "centers", "rotations", "momenta", "angular_momenta",
             "energies")

    def __init__(self, sim, steps: int, stride: int):
        self.sim, self.stride = sim, int(stride)
        self.sampled: dict[str, list] = {key: [] for key in self._KEYS}
        self.interp, self.total = np.zeros(steps), np.zeros(steps)
        self.iterations, self.depth = np.zeros(steps, dtype=np.int64), np.zeros(steps)
        self.done = 0
        self.sample()

    def sample(self) -> None:
        """The engine's current state into the sampled arrays."""
        sim = self.sim
        rigid = sim.rigid
        for key, value in zip(self._KEYS, (sim.time, sim.q, rigid.center, rigid.rotation,
                                           rigid.momentum, rigid.angular_momentum,
                                           sim.energy()), strict=True):
            self.sampled[key].append(np.array(value, dtype=float))

    def step(self, iterations: int, interp_seconds: float, total_seconds: float,
             depth: float) -> None:
        """A completed step: its Newton iterations, wall times (s) and contact depth (m)."""
        index = self.done
        self.iterations[index] = iterations
        self.interp[index], self.total[index] = interp_seconds, total_seconds
        self.depth[index] = depth
        self.done = index + 1
        if self.done % self.stride == 0:
            self.sample()

    def record(self, *, stable: bool = True, message: str = "") -> FreeBodyRecord:
        """The frozen record of what was collected so far."""
        done, sim = self.done, self.sim
        arrays = {key: np.asarray(value) for key, value in self.sampled.items()}
        return FreeBodyRecord(
            times=arrays["times"], states=arrays["states"],
            t_interp_ms=1e3 * self.interp[:done], t_total_ms=1e3 * self.total[:done],
            newton_iterations=self.iterations[:done], stable=stable, message=message,
            centers=arrays["centers"], rotations=arrays["rotations"],
            momenta=arrays["momenta"], angular_momenta=arrays["angular_momenta"],
            energies=arrays["energies"], contact_depth=self.depth[:done],
            rest_points=sim.rest_points,
            body_points=(None if sim.rest_points is None
                         else sim.rest_points - sim.frame.center),
        )
