"""Reduced elastic energy, force and tangent evaluated with cubature (the real-time kernel).

For a basis U (3n, r) and reduced coordinates q (r,), the full displacement is
``u = U q``. With a cubature (elements ``e ∈ S``, weights ``w_e ≥ 0``, see
:mod:`lbshape.elastic.cubature`) the reduced quantities are approximated by

* ``E(q) ≈ Σ_e w_e V_e Ψ(F_e)``,
* ``f(q) = ∂E/∂q ≈ Σ_e w_e U_eᵀ f_e(U_e q)``,
* ``K(q) = ∂f/∂q ≈ Σ_e w_e U_eᵀ K_e(U_e q) U_e``,

with ``U_e`` (12, r) the rows of U of element e's vertices (node-major) and
``f_e``, ``K_e`` its internal force ``+∂E_e/∂u_e`` and tangent. With all elements and
unit weights these are the exact reduced quantities ``Uᵀ f(Uq)`` and ``Uᵀ K(Uq) U``.

Fast path: the element kernel's gradient operator B (``F = I + B u_e``) is folded
into the basis once, ``(BU)_e = B_e U_e`` (9, r), so a call costs one product for
all displacement gradients ``H = BU q``, the stress and its derivative of the s
elements (:mod:`lbshape.elastic.energy_densities`), one product for the force
``f = Σ_e w_e V_e (BU)_eᵀ P_e`` and, for the tangent, one batched (9×9)·(9×r)
product ``T_e = A_e (BU)_e`` and one ``r × 9s × r`` matrix product
``K = Σ_e w_e V_e (BU)_eᵀ T_e``. Nothing n-sized is touched at call time.
"""

from __future__ import annotations

import numpy as np

from lbshape._jit import njit
from lbshape.elastic.element_kernels import ElementKernel
from lbshape.elastic.energy_densities import density_model
from lbshape.elastic.jit_densities import density_parameters, stress, stress_and_tangent
from lbshape.elastic.materials import Material
from lbshape.errors import LbshapeError


class ReducedForceModel:
    """Cubature evaluation of the reduced elastic energy, force and tangent.

    The rest shape may be any shape on the object's connectivity (the object's rest
    mesh, or an example shape reconstructed on it): the element data are computed
    from ``points``.

    Args:
        points: (n, 3) rest vertex positions in metres.
        tets: (t, 4) vertex indices of all tetrahedra of the mesh.
        material: the hyperelastic material.
        U: (3n, r) basis, node-major rows (``U[3*i + c]``), mapping reduced
            coordinates to displacements in metres; any basis works (mass-orthonormal
            or not).
        elements: (s,) indices into ``tets`` of the cubature elements.
        weights: (s,) non-negative cubature weights (dimensionless).
        tangent: build the tangent's arrays (False: a model for forces only, e.g. the
            cubature training's passes over element chunks; about half the memory).

    Attributes:
        kernel: the :class:`~lbshape.elastic.element_kernels.ElementKernel` of the s elements.
        elements: (s,) int64 element indices.
        weights: (s,) float64 weights.
        element_basis: (s, 12, r) rows ``U_e`` of U gathered per element.
        n_coordinates: r.
        n_elements: s.

    Raises:
        LbshapeError: inconsistent shapes, indices out of range, negative or
            non-finite weights, or a non-finite basis (plus the kernel's checks on
            the rest shape).
    """

    def __init__(
        self,
        points: np.ndarray,
        tets: np.ndarray,
        material: Material,
        U: np.ndarray,
        elements: np.ndarray,
        weights: np.ndarray,
        *,
        tangent: bool = True,
    ):
        points = np.asarray(points, dtype=np.float64)
        tets = np.asarray(tets)
        U = np.asarray(U, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3:
            raise LbshapeError(f"rest points must have shape (n, 3), got {points.shape}")
        if tets.ndim != 2 or tets.shape[1] != 4:
            raise LbshapeError(f"tets must have shape (t, 4), got {tets.shape}")
        if U.ndim != 2 or U.shape[0] != 3 * points.shape[0] or U.shape[1] < 1:
            raise LbshapeError(
                f"basis U must have shape (3n, r) = ({3 * points.shape[0]}, r >= 1), "
                f"got {U.shape}"
            )
        if not np.isfinite(U).all():
            raise LbshapeError("basis U contains NaN or infinite entries")
        elements = np.asarray(elements)
        weights = np.asarray(weights, dtype=np.float64)
        if elements.ndim != 1 or elements.size == 0:
            raise LbshapeError(
                f"cubature elements must be a non-empty 1-D array, got shape {elements.shape}"
            )
        if not np.issubdtype(elements.dtype, np.integer):
            raise LbshapeError(f"cubature elements must be integers, got dtype {elements.dtype}")
        if elements.min() < 0 or elements.max() >= tets.shape[0]:
            raise LbshapeError(f"cubature element index out of range [0, {tets.shape[0]})")
        if weights.shape != elements.shape:
            raise LbshapeError(
                f"cubature weights must have shape {elements.shape} like the elements, "
                f"got {weights.shape}"
            )
        if not np.isfinite(weights).all() or (weights < 0).any():
            raise LbshapeError("cubature weights must be finite and >= 0")

        s, r = elements.size, U.shape[1]
        element_tets = tets[elements]
        self.kernel = ElementKernel(points, element_tets, material)
        self.material = material  # its model decides whether the engines check inversion
        self.elements = elements.astype(np.int64)
        self.weights = weights.copy()
        self.n_coordinates, self.n_elements = r, s
        dofs = (3 * element_tets[:, :, None].astype(np.int64) + np.arange(3)).reshape(s, 12)
        self.element_basis = np.ascontiguousarray(U[dofs])  # (s, 12, r)
        self._density = density_model(material)

        BU = gradient_basis(self.kernel.gradients, self.element_basis)  # (s, 9, r)
        volumes = self.kernel.volumes
        wv = self.weights * volumes
        # component-major (9s, r): H = BU_k @ q is the element-last gradient (3, 3, s)
        self._bu_k = np.ascontiguousarray(BU.transpose(1, 0, 2)).reshape(9 * s, r)
        # force: f = WBU_kᵀ @ P.ravel() with P element-last (9, s)
        self._wbu_k_t = np.ascontiguousarray(
            (wv[:, None, None] * BU).transpose(1, 0, 2).reshape(9 * s, r).T
        )  # (r, 9s)
        self._wv = wv
        self._jit = density_parameters(material)
        self.has_tangent = bool(tangent)
        if not tangent:
            return
        # tangent: K = WBU_eᵀ @ (A_e BU_e) stacked element-major (9s, r)
        self._bu_e = np.ascontiguousarray(BU)  # (s, 9, r)
        self._wbu_e_t = np.ascontiguousarray((wv[:, None, None] * BU).reshape(s * 9, r).T)
        # work arrays of the tangent
        self._a_work = np.empty((s, 9, 9))
        self._t_work = np.empty((s, 9, r))
        self._h_work = np.empty(9 * s)
        self._p_work = np.empty((9, s))
        # views made once: the run-time path creates no array objects
        self._h_view = self._h_work.reshape(9, s)
        self._p_flat = self._p_work.reshape(-1)
        self._t_view = self._t_work.reshape(9 * s, r)

    # -- helpers ---------------------------------------------------------------------
    def _gradients(self, q: np.ndarray) -> np.ndarray:
        """Element-last displacement gradients H = F − I, (3, 3, s), of q (r,)."""
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (self.n_coordinates,):
            raise LbshapeError(
                f"reduced coordinates must have shape ({self.n_coordinates},), got {q.shape}"
            )
        return (self._bu_k @ q).reshape(3, 3, self.n_elements)

    def element_displacements(self, q: np.ndarray) -> np.ndarray:
        """Displacements ``U_e q`` (s, 4, 3) in metres of the cubature elements."""
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (self.n_coordinates,):
            raise LbshapeError(
                f"reduced coordinates must have shape ({self.n_coordinates},), got {q.shape}"
            )
        return (self.element_basis @ q).reshape(self.n_elements, 4, 3)

    # -- reduced energy, force, tangent ------------------------------------------------
    def energy(self, q: np.ndarray) -> float:
        """Cubature strain energy ``Σ w_e E_e`` in J at reduced coordinates q (r,)."""
        return float(self._wv @ self._density.energy_t(self._gradients(q)))

    def force(self, q: np.ndarray) -> np.ndarray:
        """Reduced internal force ``∂E/∂q`` (r,) (N per unit of q) at q (r,)."""
        Pt = self._density.stress_t(self._gradients(q))
        return self._wbu_k_t @ Pt.reshape(-1)

    def tangent(self, q: np.ndarray) -> np.ndarray:
        """Reduced tangent stiffness ``∂f/∂q`` (r, r), symmetric, at q (r,)."""
        return self.force_and_tangent(q)[1]

    def force_and_tangent(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(force (r,), tangent (r, r)) at q (r,), sharing the element work."""
        if not self.has_tangent:
            raise LbshapeError("this reduced force model was built without its tangent")
        s = self.n_elements
        Pt, At = self._density.stress_and_derivative_t(self._gradients(q))
        f = self._wbu_k_t @ Pt.reshape(-1)
        A = self._a_work
        A[...] = At.reshape(81, s).T.reshape(s, 9, 9)
        T = np.matmul(A, self._bu_e, out=self._t_work)
        K = self._wbu_e_t @ T.reshape(9 * s, self.n_coordinates)
        return f, K

    def force_and_tangent_into(self, q: np.ndarray, f: np.ndarray, K: np.ndarray) -> None:
        """The run-time path of :meth:`force_and_tangent`: writes the force (r,) into ``f``
        and the tangent (r, r) into ``K``; compiled element kernel
        (:mod:`lbshape.elastic.jit_densities`), preallocated work arrays, no checks."""
        np.dot(self._bu_k, q, out=self._h_work)
        stress_and_tangent(self._jit[0], self._jit[1], self._h_view, self._p_work,
                           self._a_work)
        np.dot(self._wbu_k_t, self._p_flat, out=f)
        np.matmul(self._a_work, self._bu_e, out=self._t_work)
        np.dot(self._wbu_e_t, self._t_view, out=K)

    def min_jacobian(self, q: np.ndarray) -> float:
        """The smallest det F over the cubature elements at q (r,); ≤ 0: inverted."""
        return self.kernel.min_jacobian(self.element_displacements(q))

    def min_jacobian_into(self, q: np.ndarray) -> float:
        """:meth:`min_jacobian` for the run-time step: no allocation, no checks (s-sized)."""
        if not hasattr(self, "_h_check"):  # H (9s,) and its (9, s) view, made once
            self._h_check = np.empty(9 * self.n_elements)
            self._h_check_view = self._h_check.reshape(9, self.n_elements)
        np.dot(self._bu_k, q, out=self._h_check)
        return float(min_jacobian_of_gradients(self._h_check_view))

    # -- training support --------------------------------------------------------------
    def max_strain(self, Q: np.ndarray) -> np.ndarray:
        """Largest displacement-gradient norm ``max_e ‖F_e − I‖_F`` (P,) of poses Q (r, P).

        Zero (to round-off) for poses that translate the elements rigidly.
        """
        Q = np.asarray(Q, dtype=np.float64)
        r, s = self.n_coordinates, self.n_elements
        if Q.ndim != 2 or Q.shape[0] != r:
            raise LbshapeError(f"poses must have shape ({r}, P), got {Q.shape}")
        H = (self._bu_k @ Q).reshape(9, s, Q.shape[1])
        return np.sqrt(np.einsum("kep,kep->ep", H, H)).max(axis=0)

    def element_forces(self, Q: np.ndarray) -> np.ndarray:
        """Unweighted per-element reduced forces ``U_eᵀ f_e(U_e q_p)`` for many poses.

        Vectorised over poses and elements; memory is about ``(r + 40) · 9 · s · P``
        float64 values, so callers chunk the poses.

        Args:
            Q: (r, P) reduced coordinates of P poses (one per column).

        Returns:
            (P, r, s) array: entry ``[p, :, e]`` is element e's reduced force at pose p.
        """
        Q = np.asarray(Q, dtype=np.float64)
        r, s = self.n_coordinates, self.n_elements
        if Q.ndim != 2 or Q.shape[0] != r:
            raise LbshapeError(f"poses must have shape ({r}, P), got {Q.shape}")
        n_poses = Q.shape[1]
        # H[k, e, p] element-last over the combined (e, p) axis
        Ht = (self._bu_k @ Q).reshape(3, 3, s * n_poses)
        Pt = self._density.stress_t(Ht).reshape(9, s, n_poses)
        BU = self._bu_k.reshape(9, s, r).transpose(1, 0, 2)  # (s, 9, r) view
        vbu_t = (self.kernel.volumes[:, None, None] * BU).transpose(0, 2, 1)  # (s, r, 9)
        out = np.matmul(vbu_t, Pt.transpose(1, 0, 2))  # (s, r, P)
        return out.transpose(2, 1, 0)

    def pose_forces(self, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Weighted reduced forces of many poses and their largest strain.

        ``forces[p] = Σ_e w_e U_eᵀ f_e(U_e q_p)`` (the :meth:`force` of every pose; with
        all elements and unit weights the exact ``Uᵀ f(U q_p)``), and
        ``strains[p] = max_e ‖F_e − I‖_F`` (zero to round-off for a rigid pose). Two
        matrix products and the compiled stress
        (:func:`lbshape.elastic.jit_densities.stress`); temporary memory about
        ``20 · s · P`` float64 values.

        Args:
            Q: (r, P) reduced coordinates of P poses (one per column).

        Returns:
            (forces (P, r), strains (P,)).
        """
        Q = np.asarray(Q, dtype=np.float64)
        r, s = self.n_coordinates, self.n_elements
        if Q.ndim != 2 or Q.shape[0] != r:
            raise LbshapeError(f"poses must have shape ({r}, P), got {Q.shape}")
        n_poses = Q.shape[1]
        H = self._bu_k @ Q  # (9s, P): rows (component, element)
        Hk = H.reshape(9, s, n_poses)
        strains = np.sqrt(np.einsum("kep,kep->ep", Hk, Hk)).max(axis=0)
        H9 = H.reshape(9, s * n_poses)
        P9 = np.empty_like(H9)
        stress(self._jit[0], self._jit[1], H9, P9)
        return (self._wbu_k_t @ P9.reshape(9 * s, n_poses)).T, strains


def gradient_basis(gradients: np.ndarray, element_basis: np.ndarray) -> np.ndarray:
    """``(BU)_e`` (s, 9, r): displacement gradient of element e per reduced coordinate.

    ``(BU)_e[3i + j] = Σ_a ∂_j N_a · U[3 v_a + i]`` (row-major ``H = F − I``), from the
    shape-function gradients (s, 4, 3) in 1/m and the element rows ``U_e`` (s, 12, r)
    (node-major); four broadcast products instead of a (9 × 12)·(12 × r) product with
    the mostly-zero gradient operator.
    """
    s, r = element_basis.shape[0], element_basis.shape[2]
    rows = element_basis.reshape(s, 4, 3, r)
    BU = np.zeros((s, 3, 3, r))
    for a in range(4):
        BU += gradients[:, a, None, :, None] * rows[:, a, :, None, :]
    return BU.reshape(s, 9, r)


@njit
def min_jacobian_of_gradients(H):
    """The smallest det(I + H_e) over the columns of H (9, s) (H_e row-major; no
    allocation)."""
    smallest = np.inf
    for e in range(H.shape[1]):
        a, b, c = 1.0 + H[0, e], H[1, e], H[2, e]
        d, f, g = H[3, e], 1.0 + H[4, e], H[5, e]
        h, i, k = H[6, e], H[7, e], 1.0 + H[8, e]
        det = a * (f * k - g * i) - b * (d * k - g * h) + c * (d * i - f * h)
        if det < smallest:
            smallest = det
    return smallest
