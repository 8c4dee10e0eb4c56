"""Rigid frame of a free body: state, momenta and a rotation update that stays on SO(3).

**Frame convention** (as in :mod:`lbshape.dynamics.fictitious`): world position of a
vertex ``x_i = c + R (X̄_i + U_i q)``; ``c`` (3,) the centre of mass (m, world),
``R`` (3, 3) the body-to-world rotation, ω the angular velocity in the **body**
frame (``Ṙ = R [ω]×``, rad/s), ``v = ċ`` (m/s, world). The state keeps the world
linear momentum ``p = m v`` and the world angular momentum about the centre of mass

``L = R Π``,  ``Π = I(q) ω + h(q, q̇)`` (body angular momentum, kg·m²/s),

so ω is derived from L, R and the deformation: ``ω = I(q)⁻¹ (Rᵀ L − h)``. Forces
change p and L by impulses, so without loads and contact both are conserved to
round-off whatever the deformation does.

**Rotation update** (:func:`rotate`): the body momentum is advanced by the implicit
midpoint rule of Euler's equations ``Π̇ = Π × ω`` and R by the Cayley map of the
same midpoint velocity, ``R₁ = R₀ cay(Δt ω)``, ``Π₁ = cay(Δt ω)ᵀ Π₀``,
``ω = I⁻¹ (½(Π₀ + Π₁) − h)``. The pair is consistent (``R₁ Π₁ = R₀ Π₀ = L``
exactly), keeps ``|Π|`` and, for fixed I and h, the rotational kinetic energy
``½ (Π − h)ᵀ I⁻¹ (Π − h)`` exactly (both are quadratic invariants of the midpoint
rule), is second order, and ``cay`` maps skew matrices to exact rotations, so R
leaves SO(3) only by round-off. The implicit ω is found by fixed-point iteration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lbshape.errors import SolverError

#: fixed-point iterations of the midpoint angular velocity before giving up
ROTATION_MAX_ITERATIONS = 100
#: relative tolerance of the midpoint angular velocity
ROTATION_TOLERANCE = 1e-14


def skew(w: np.ndarray) -> np.ndarray:
    """(3, 3) ``[w]×`` with ``[w]× a = w × a``."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def cayley(w: np.ndarray) -> np.ndarray:
    """(3, 3) rotation ``(I − ½[w]×)⁻¹ (I + ½[w]×)`` of the rotation vector-like w (3,).

    Closed form: with ``W = [w]×`` and ``s = ¼|w|²``, ``cay = I + (W + ½ W²) / (1 + s)``.
    It rotates by ``2 atan(|w|/2)`` about ``w`` (≈ exp([w]×) to third order).
    """
    W = skew(w)
    return np.eye(3) + (W + 0.5 * W @ W) / (1.0 + 0.25 * float(w @ w))


def orthonormality_error(R: np.ndarray) -> float:
    """``max |RᵀR − I|`` (dimensionless)."""
    return float(np.abs(R.T @ R - np.eye(3)).max())


@dataclass
class RigidState:
    """The rigid part of a free body's state (see the module docstring).

    Attributes:
        center: (3,) centre of mass in m (world).
        momentum: (3,) linear momentum in kg·m/s (world).
        rotation: (3, 3) body-to-world rotation.
        angular_momentum: (3,) angular momentum about the centre of mass in
            kg·m²/s (world), deformation included.
    """

    center: np.ndarray
    momentum: np.ndarray
    rotation: np.ndarray
    angular_momentum: np.ndarray

    def copy(self) -> RigidState:
        return RigidState(self.center.copy(), self.momentum.copy(), self.rotation.copy(),
                          self.angular_momentum.copy())


def body_angular_velocity(state: RigidState, inertia: np.ndarray,
                          relative: np.ndarray) -> np.ndarray:
    """(3,) body ω (rad/s) from L, R, the body inertia (3, 3) and h (3,)."""
    return np.linalg.solve(inertia, state.rotation.T @ state.angular_momentum - relative)


def rotate(rotation: np.ndarray, body_momentum: np.ndarray, inertia: np.ndarray,
           relative: np.ndarray, dt: float, *, step: int = 0,
           time: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One torque-free Cayley–midpoint rotation step (see the module docstring).

    Args:
        rotation: (3, 3) R at the start of the step.
        body_momentum: (3,) Π = Rᵀ L at the start of the step (kg·m²/s).
        inertia: (3, 3) body inertia I (kg·m²), held fixed in the step.
        relative: (3,) relative angular momentum h (kg·m²/s), held fixed.
        dt: time step (s).
        step, time: named in the error message.

    Returns:
        ``(R₁ (3, 3), Π₁ (3,), ω (3,))`` with ω the midpoint body angular velocity.

    Raises:
        SolverError: the midpoint iteration did not converge (step too large for
            the spin rate), naming the step.
    """
    inverse = np.linalg.inv(inertia)
    omega = inverse @ (body_momentum - relative)
    for _ in range(ROTATION_MAX_ITERATIONS):
        F = cayley(dt * omega)
        after = F.T @ body_momentum
        new = inverse @ (0.5 * (body_momentum + after) - relative)
        change = float(np.abs(new - omega).max())
        omega = new
        if change <= ROTATION_TOLERANCE * max(float(np.abs(omega).max()), 1e-300):
            break
    else:
        raise SolverError(
            f"rigid rotation did not converge at step {step} (t = {time:.6g} s): "
            f"|omega| dt = {dt * float(np.linalg.norm(omega)):.3g} rad is too large"
        )
    F = cayley(dt * omega)
    return rotation @ F, F.T @ body_momentum, omega


def best_rigid_frame(scalar_mass, rest: np.ndarray,
                     positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mass-weighted best-fitting rigid frame of a deformed shape (Kabsch fit).

    Args:
        scalar_mass: (n, n) scalar mass M₁ (kg), sparse or dense.
        rest: (n, 3) rest positions X (m).
        positions: (n, 3) current positions x (m, world).

    Returns:
        ``(c (3,), R (3, 3), u_body (n, 3))``: the centre of mass ``Σ M₁ x / m``, the
        rotation of the polar decomposition of ``Σ M₁ (x − c) X̄ᵀ`` (X̄ = X − X_cm,
        det R = +1) and the body-frame displacement ``Rᵀ (x − c) − X̄``.
    """
    weights = np.asarray(scalar_mass.sum(axis=1)).ravel()
    weights = weights / weights.sum()
    Xbar = rest - weights @ rest
    center = weights @ positions
    A = (positions - center).T @ np.asarray(scalar_mass @ Xbar)
    left, _, right = np.linalg.svd(A)
    R = left @ np.diag([1.0, 1.0, np.sign(np.linalg.det(left @ right))]) @ right
    return center, R, (positions - center) @ R - Xbar
