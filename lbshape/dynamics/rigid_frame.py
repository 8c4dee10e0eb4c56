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
leaves SO(3) only by round-off. The implicit ω is found by fixed-point iteration
(compiled: :func:`rotate_into`, which the free-body step calls with its own arrays).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lbshape._jit import njit
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
    out = np.zeros((3, 3))
    cayley_into(np.asarray(w, dtype=float), 1.0, out)
    return out


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
    R1, Pi1, omega, work = np.zeros((3, 3)), np.zeros(3), np.zeros(3), np.zeros((2, 3, 3))
    if not rotate_into(np.asarray(rotation, dtype=float), np.asarray(body_momentum, dtype=float),
                       np.asarray(inertia, dtype=float), np.asarray(relative, dtype=float),
                       float(dt), R1, Pi1, omega, work):
        raise rotation_error(dt, omega, step, time)
    return R1, Pi1, omega


def rotation_error(dt: float, omega: np.ndarray, step: int, time: float) -> SolverError:
    """The error of a midpoint iteration that did not converge (ω (3,) its last iterate)."""
    return SolverError(
        f"rigid rotation did not converge at step {step} (t = {time:.6g} s): "
        f"|omega| dt = {dt * float(np.linalg.norm(omega)):.3g} rad is too large"
    )


# ------------------------------------------------------------------ compiled kernels
@njit
def cayley_into(w, scale, out):
    """``out = cay(scale · w)`` (3, 3) (closed form of :func:`cayley`)."""
    x, y, z = scale * w[0], scale * w[1], scale * w[2]
    denominator = 1.0 + 0.25 * (x * x + y * y + z * z)
    # W = [w]×, W² = w wᵀ − |w|² I
    s2 = x * x + y * y + z * z
    out[0, 0] = 1.0 + 0.5 * (x * x - s2) / denominator
    out[1, 1] = 1.0 + 0.5 * (y * y - s2) / denominator
    out[2, 2] = 1.0 + 0.5 * (z * z - s2) / denominator
    out[0, 1] = (-z + 0.5 * x * y) / denominator
    out[1, 0] = (z + 0.5 * x * y) / denominator
    out[0, 2] = (y + 0.5 * x * z) / denominator
    out[2, 0] = (-y + 0.5 * x * z) / denominator
    out[1, 2] = (-x + 0.5 * y * z) / denominator
    out[2, 1] = (x + 0.5 * y * z) / denominator


@njit
def inverse3_into(A, out):
    """``out = A⁻¹`` (3, 3) by the adjugate; False if A is singular."""
    c00 = A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]
    c01 = A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]
    c02 = A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]
    det = A[0, 0] * c00 + A[0, 1] * c01 + A[0, 2] * c02
    if not (det != 0.0 and np.isfinite(det)):
        return False
    out[0, 0], out[1, 0], out[2, 0] = c00 / det, c01 / det, c02 / det
    out[0, 1] = (A[0, 2] * A[2, 1] - A[0, 1] * A[2, 2]) / det
    out[1, 1] = (A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0]) / det
    out[2, 1] = (A[0, 1] * A[2, 0] - A[0, 0] * A[2, 1]) / det
    out[0, 2] = (A[0, 1] * A[1, 2] - A[0, 2] * A[1, 1]) / det
    out[1, 2] = (A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2]) / det
    out[2, 2] = (A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]) / det
    return True


@njit
def rotate_into(rotation, body_momentum, inertia, relative, dt, R1, Pi1, omega, work):
    """Compiled :func:`rotate`: writes R₁, Π₁ and the midpoint ω; False if the midpoint
    iteration did not converge (or I is singular). ``work`` (2, 3, 3) scratch."""
    inverse, F = work[0], work[1]
    if not inverse3_into(inertia, inverse):
        return False
    for a in range(3):
        value = 0.0
        for b in range(3):
            value += inverse[a, b] * (body_momentum[b] - relative[b])
        omega[a] = value
    converged = False
    for _ in range(ROTATION_MAX_ITERATIONS):
        cayley_into(omega, dt, F)
        for a in range(3):  # Π₁ = Fᵀ Π₀
            Pi1[a] = F[0, a] * body_momentum[0] + F[1, a] * body_momentum[1] + \
                F[2, a] * body_momentum[2]
        change = 0.0
        largest = 0.0
        for a in range(3):
            value = 0.0
            for b in range(3):
                value += inverse[a, b] * (0.5 * (body_momentum[b] + Pi1[b]) - relative[b])
            change = max(change, abs(value - omega[a]))
            R1[0, a] = value  # the new iterate, parked in R1's first row
        for a in range(3):
            omega[a] = R1[0, a]
            largest = max(largest, abs(omega[a]))
        if change <= ROTATION_TOLERANCE * max(largest, 1e-300):
            converged = True
            break
    if not converged:
        return False
    cayley_into(omega, dt, F)
    for a in range(3):
        Pi1[a] = F[0, a] * body_momentum[0] + F[1, a] * body_momentum[1] + \
            F[2, a] * body_momentum[2]
        for b in range(3):
            R1[a, b] = rotation[a, 0] * F[0, b] + rotation[a, 1] * F[1, b] + \
                rotation[a, 2] * F[2, b]
    return True


class KabschFit:
    """The mass-weighted best rigid placement of one shape onto positions (a Kabsch fit),
    the shape's parts computed once.

    Args:
        scalar_mass: (n, n) scalar mass M₁ (kg), sparse or dense.
        shape: (n, 3) the shape placed (m).

    Attributes:
        weights: (n,) the mass fractions ``M₁ 1 / m``.
        centered: (n, 3) the shape about its centre of mass, X̄ (m).
    """

    def __init__(self, scalar_mass, shape: np.ndarray):
        weights = np.asarray(scalar_mass.sum(axis=1)).ravel()
        self.weights = weights / weights.sum()
        self.centered = shape - self.weights @ shape
        self._mass_centered = np.ascontiguousarray(scalar_mass @ self.centered,
                                                   dtype=np.float64)

    def __call__(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(c (3,), R (3, 3))``: the centre of mass of ``positions`` (n, 3) m and the
        rotation of the polar decomposition of ``Σ M₁ (x − c) X̄ᵀ`` (det R = +1)."""
        center, R = np.empty(3), np.empty((3, 3))
        _kabsch(self.weights, np.ascontiguousarray(positions, dtype=np.float64),
                self._mass_centered, center, R)
        return center, R


@njit
def _kabsch(weights, positions, mass_centered, center, R):
    """:class:`KabschFit`'s centre (3,) and rotation (3, 3) into ``center`` and ``R``."""
    for a in range(3):
        center[a] = 0.0
        for i in range(positions.shape[0]):
            center[a] += weights[i] * positions[i, a]
    A = np.zeros((3, 3))
    for i in range(positions.shape[0]):
        for a in range(3):
            offset = positions[i, a] - center[a]
            for b in range(3):
                A[a, b] += offset * mass_centered[i, b]
    left, _, right = np.linalg.svd(A)
    if np.linalg.det(left @ right) < 0.0:  # a reflection: turn the least axis
        left[:, 2] *= -1.0
    R[:, :] = left @ right


def best_rigid_frame(scalar_mass, rest: np.ndarray,
                     positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mass-weighted best-fitting rigid frame of a deformed shape (:class:`KabschFit`).

    Args:
        scalar_mass: (n, n) scalar mass M₁ (kg), sparse or dense.
        rest: (n, 3) rest positions X (m).
        positions: (n, 3) current positions x (m, world).

    Returns:
        ``(c (3,), R (3, 3), u_body (n, 3))``: the centre of mass ``Σ M₁ x / m``, the
        rotation of the polar decomposition of ``Σ M₁ (x − c) X̄ᵀ`` (X̄ = X − X_cm,
        det R = +1) and the body-frame displacement ``Rᵀ (x − c) − X̄``.
    """
    fit = KabschFit(scalar_mass, rest)
    center, R = fit(positions)
    return center, R, (positions - center) @ R - fit.centered
