"""A user's drag: a spring of stiffness k (N/m) pulling one vertex i of the object
towards a point (the cursor, world coordinates, m).

Everything is reduced through the vertex's three rows ``U_i`` (3, r) of the basis: no
n-sized work per step.

* **Fixed object** (world = object frame, ``x_i = X_i + U_i q``): the spring's energy
  ``½ k |X_i + U_i q − x_c|²`` is split, as the example force is in
  :mod:`lbshape.dynamics.reduced`, into a potential ``½ k |U_i q|²`` (force
  ``k U_iᵀ U_i q``, tangent ``k U_iᵀ U_i``: implicit in the step, stable for any k) and
  a pull ``k U_iᵀ (x_c − X_i)`` held constant within the step and counted as external
  work by the energy monitor.
* **Free body** (``x_i = c + R (X̄_i + U_i q)``): the world point force
  ``f = k (x_c − x_i)`` at the body point, evaluated at the start of each step and held
  over it, enters the engine as one more load (its total force, its torque about the
  centre of mass and its generalized force ``U_iᵀ Rᵀ f``, the arrays of
  :class:`~lbshape.dynamics.free_body.FreeLoad`). Explicit in the state, so its
  stiffness is capped by :func:`explicit_stiffness_limit`.
"""

from __future__ import annotations

import numpy as np

#: an explicit spring is kept at ``k λ Δt² ≤`` this (λ: the point's largest mobility)
EXPLICIT_SAFETY = 0.25


class DragSpring:
    """A spring pulling vertex ``vertex`` towards ``target``.

    Args:
        vertex: the vertex's index in the object's mesh.
        rows: (3, r) its rows of the basis U (``U[3i:3i+3]``).
        anchor: (3,) the vertex's rest position X_i (fixed object) or body point X̄_i
            (free body: rest position minus the centre of mass), m.
        stiffness: k in N/m (> 0).
        target: (3,) the point it is pulled towards (world, m).

    Attributes:
        gram: (r, r) ``k U_iᵀ U_i``, the spring's reduced stiffness.
        pull: (r,) ``k U_iᵀ (target − anchor)``, a fixed object's constant pull.
    """

    def __init__(self, vertex: int, rows: np.ndarray, anchor: np.ndarray, stiffness: float,
                 target: np.ndarray):
        rows = np.ascontiguousarray(rows, dtype=float)
        if rows.ndim != 2 or rows.shape[0] != 3:
            raise ValueError(f"rows must have shape (3, r), got {rows.shape}")
        if not stiffness > 0:
            raise ValueError(f"drag stiffness must be > 0 N/m, got {stiffness}")
        self.vertex = int(vertex)
        self.rows = rows
        self.anchor = np.array(anchor, dtype=float).reshape(3)
        self.stiffness = float(stiffness)
        self.gram = self.stiffness * (rows.T @ rows)
        self.target = np.zeros(3)
        self.pull = np.zeros(rows.shape[1])
        self._work = np.zeros(rows.shape[1])
        self.move(target)

    def move(self, target: np.ndarray) -> None:
        """Pull towards ``target`` (3,) from now on."""
        self.target[:] = np.asarray(target, dtype=float).reshape(3)
        np.dot(self.rows.T, self.stiffness * (self.target - self.anchor), out=self.pull)

    # ------------------------------------------------------------ fixed object
    def spring_into(self, q: np.ndarray, force: np.ndarray, tangent: np.ndarray) -> None:
        """Add the potential part's force ``k U_iᵀ U_i q`` to ``force`` (r,) and its
        tangent to ``tangent`` (r, r) (internal-force sign: ``+∂E/∂q``)."""
        np.dot(self.gram, q, out=self._work)
        force += self._work
        tangent += self.gram

    def pull_into(self, out: np.ndarray) -> None:
        """Add the constant pull ``k U_iᵀ (x_c − X_i)`` (r,) to the external force ``out``."""
        out += self.pull

    def energy(self, q: np.ndarray) -> float:
        """The potential part ``½ k |U_i q|²`` (J) at q (r,)."""
        return 0.5 * float(q @ (self.gram @ q))

    def position(self, q: np.ndarray, center: np.ndarray | None = None,
                 rotation: np.ndarray | None = None) -> np.ndarray:
        """(3,) the vertex's world position: ``X_i + U_i q``, or for a free body
        ``c + R (X̄_i + U_i q)``."""
        local = self.anchor + self.rows @ q
        if rotation is None:
            return local
        return np.asarray(center) + np.asarray(rotation) @ local

    # --------------------------------------------------------------- free body
    def point_force(self, center: np.ndarray, rotation: np.ndarray, q: np.ndarray
                    ) -> np.ndarray:
        """(3,) the world force ``k (x_c − x_i)`` (N) at the body pose (c, R) and q."""
        return self.stiffness * (self.target - self.position(q, center, rotation))

    def load_arrays(self, force: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The arrays of a world force ``force`` (3,) at the vertex as a free-body load:
        ``(P, Z0, Z1)`` with ``P = Z1`` (r, 3, 3) ``[j, d, a] = U_idj f_a`` and ``Z0``
        (3, 3) ``X̄_i ⊗ f`` (the fields of :class:`~lbshape.dynamics.free_body.FreeLoad`)."""
        P = np.einsum("dj,a->jda", self.rows, force)
        return P, np.outer(self.anchor, force), P


def explicit_stiffness_limit(rows: np.ndarray, dt: float, *, mass: float | None = None,
                             arm: float = 0.0, inertia: float | None = None) -> float:
    """The largest stiffness (N/m) a spring on one point may have when it is evaluated at
    the start of each step of length ``dt`` (s) and held over it:
    ``EXPLICIT_SAFETY / (λ Δt²)`` with λ the point's largest mobility (1/kg): the
    deformation's ``λ_max(U_iᵀ U_i)`` (U mass-orthonormal) plus, for a free body, the rigid
    body's ``1/m + arm² / I_min`` (``mass`` kg, ``arm`` the point's distance to the centre
    of mass in m, ``inertia`` the smallest principal moment in kg·m²)."""
    rows = np.asarray(rows, dtype=float)
    mobility = float(np.linalg.eigvalsh(rows.T @ rows)[-1]) if rows.size else 0.0
    if mass:
        mobility += 1.0 / mass
    if inertia:
        mobility += arm**2 / inertia
    return EXPLICIT_SAFETY / (mobility * dt**2) if mobility > 0 else np.inf
