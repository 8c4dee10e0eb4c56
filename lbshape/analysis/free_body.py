"""A free body's error against the full reference, split into rigid motion and deformation.

The whole-field error ``max_t ‖u − u_full‖_M / max_t ‖u_full‖_M`` of a free body is
dominated by its rigid motion: where it flies and how it turns. Beside it the
benchmark reports, from the same two trajectories sampled at the same times:

* ``com_path_error = max_t |c(t) − c_full(t)| / max_t |c_full(t) − c_full(0)|``: the
  path of the mass-weighted centre of the deformed mesh, over how far the
  reference's centre travels (``c_full(0)``: its first sample, the initial state);
* ``rotation_error_deg = max_t angle(R(t) R_full(t)ᵀ)`` in degrees: the largest
  rotation between the two best rigid fits;
* ``body_deformation_error = max_t ‖d − d_full‖_M / max_t ‖d_full‖_M``: the
  body-frame displacement after the best rigid fit (the deformation), normalised
  like the whole-field error.

The best rigid fit of each sample is the mass-weighted Kabsch fit of
:func:`lbshape.dynamics.rigid_frame.best_rigid_frame`, the same one that
:func:`body_deformations` removes for the example
influence of a free body, so the deformation here is the one measured there. A
rigid-motion difference of the two runs leaves ``body_deformation_error`` at 0.

A ratio is 0 when its numerator is below round-off
(:data:`lbshape.analysis.norms.ROUNDOFF` of the object's size) and ``None`` when
only its denominator is (the reference never travels, or never deforms).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lbshape.analysis.norms import ROUNDOFF, m_norms, ratio
from lbshape.dynamics.rigid_frame import best_rigid_frame
from lbshape.errors import LbshapeError

#: the keys :meth:`FreeBodyError.stats` adds to a benchmark row
KEYS: tuple[str, ...] = ("com_path_error", "rotation_error_deg", "body_deformation_error")


@dataclass(frozen=True)
class FreeBodyError:
    """A free body's error against its reference, rigid motion and deformation apart.

    Attributes:
        com_path: ``max_t |c − c_full| / max_t |c_full(t) − c_full(0)|`` (dimensionless;
            None if the reference's centre never moves).
        rotation_deg: ``max_t angle(R R_fullᵀ)`` of the best rigid fits (degrees, in
            [0, 180]).
        deformation: ``max_t ‖d − d_full‖_M / max_t ‖d_full‖_M`` of the body-frame
            deformations (dimensionless; None if the reference never deforms).
    """

    com_path: float | None
    rotation_deg: float
    deformation: float | None

    def stats(self) -> dict:
        """``{"com_path_error", "rotation_error_deg", "body_deformation_error"}`` (:data:`KEYS`)."""
        return dict(zip(KEYS, (self.com_path, self.rotation_deg, self.deformation), strict=True))


def rotation_angle_deg(R: np.ndarray) -> float:
    """The angle (degrees, in [0, 180]) of a rotation matrix R (3, 3).

    ``atan2(|axial(R − Rᵀ)/2|, (tr R − 1)/2)``: ``sin θ`` and ``cos θ`` both, exact to
    round-off also for small and near-180° angles.
    """
    R = np.asarray(R, dtype=float)
    skew = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return math.degrees(math.atan2(float(np.linalg.norm(skew)), 0.5 * (np.trace(R) - 1.0)))


def body_deformations(scalar_mass, rest: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(k, n, 3) deformations of displacements u (k, n, 3) (m): each sample's displacement
    after its mass-weighted best rigid fit (``Rᵀ(X + u − c) − X̄``, body frame, m).

    Args:
        scalar_mass: (n, n) scalar mass M₁ (kg).
        rest: (n, 3) rest positions X (m).
        u: (k, n, 3) world displacements (m).
    """
    rest = np.asarray(rest, dtype=float)
    u = np.asarray(u, dtype=float).reshape(len(u), -1, 3)
    if u.shape[1:] != rest.shape:
        raise LbshapeError(f"displacements of shape {u.shape[1:]} for {rest.shape} rest points")
    return np.stack([best_rigid_frame(scalar_mass, rest, rest + sample)[2] for sample in u])



def _frames(scalar_mass, rest: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(k, 3) centres and (k, 3, 3) rotations of the best rigid fits of u (k, n, 3)."""
    fits = [best_rigid_frame(scalar_mass, rest, rest + sample)[:2] for sample in u]
    return np.array([c for c, _ in fits]), np.array([R for _, R in fits])


def free_body_error(u: np.ndarray, u_full: np.ndarray, rest: np.ndarray, mass
                    ) -> FreeBodyError:
    """The rigid-motion and deformation errors of a free body's run (module docstring).

    Args:
        u: (k, 3n) or (k, n, 3) world displacements of the run (m, node-major).
        u_full: the reference's, same shape and the same k sample times.
        rest: (n, 3) rest positions (m).
        mass: (3n, 3n) consistent mass (kg), sparse or dense; its scalar block
            ``mass[0::3, 0::3]`` weights the rigid fits.

    Returns:
        The :class:`FreeBodyError` (centre path and deformation dimensionless, the
        rotation in degrees).

    Raises:
        LbshapeError: trajectories of different or empty shapes, or not matching the
            rest points or the mass.
    """
    rest = np.asarray(rest, dtype=float)
    n = rest.shape[0]
    u, u_full = np.asarray(u, dtype=float), np.asarray(u_full, dtype=float)
    if u.shape != u_full.shape or u.ndim not in (2, 3) or u.shape[0] == 0:
        raise LbshapeError(f"trajectories must have the same non-empty (k, 3n) or (k, n, 3) "
                           f"shape, got {u.shape} and {u_full.shape}")
    if rest.ndim != 2 or rest.shape[1] != 3 or u[0].size != 3 * n or mass.shape != (3 * n, 3 * n):
        raise LbshapeError(f"displacements of {u[0].size} components, {rest.shape} rest points "
                           f"and a {mass.shape} mass do not match")
    u, u_full = u.reshape(len(u), n, 3), u_full.reshape(len(u), n, 3)
    scalar_mass = mass[0::3, 0::3]
    size = float(np.linalg.norm(rest.max(axis=0) - rest.min(axis=0)))
    atol_length = ROUNDOFF * size
    atol_norm = atol_length * math.sqrt(float(mass.sum()) / 3.0)

    centers, rotations = _frames(scalar_mass, rest, u)
    centers_full, rotations_full = _frames(scalar_mass, rest, u_full)
    com_path = ratio(float(np.linalg.norm(centers - centers_full, axis=1).max()),
                     float(np.linalg.norm(centers_full - centers_full[0], axis=1).max()),
                     atol_length)
    rotation = max(rotation_angle_deg(R @ R_full.T)
                   for R, R_full in zip(rotations, rotations_full, strict=True))

    d = body_deformations(scalar_mass, rest, u)
    d_full = body_deformations(scalar_mass, rest, u_full)
    deformation = ratio(float(m_norms(d - d_full, mass).max()),
                        float(m_norms(d_full, mass).max()), atol_norm)
    return FreeBodyError(com_path, float(rotation), deformation)
