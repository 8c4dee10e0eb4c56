"""Modal derivatives (exact cubic-force identities, symmetry, rigid-free solutions) and
the mass-PCA nonlinear basis (orthonormality, span, agreement with a dense PCA)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from conftest import rel

from lbshape.elastic.basis import default_linear_modes, nonlinear_basis
from lbshape.elastic.materials import Material, strain_energy_ufl
from lbshape.elastic.modal_derivatives import (
    ForceHessian,
    all_pairs,
    force_hessians,
    modal_derivatives,
)
from lbshape.elastic.modes import linear_modes
from lbshape.errors import LbshapeError
from lbshape.fem.dolfinx_bridge import (
    input_order_to_dofs,
    p1_dof_vertices,
    petsc_vec_to_input_order,
    to_dolfinx,
)
from lbshape.geometry.primitives import structured_box

MATERIAL = Material(young=2.0e5, poisson=0.3, density=1100.0)
K_MODES = 5


def m_subspace_angles(A: np.ndarray, B: np.ndarray, M) -> np.ndarray:
    L = np.linalg.cholesky(M.toarray())
    return scipy.linalg.subspace_angles(L.T @ A, L.T @ B)


class InternalForce:
    """f(u) = ∂E/∂u (3n,) of the StVK energy, assembled with UFL (the test's truth)."""

    def __init__(self, mesh, material):
        import dolfinx.fem
        import ufl
        from mpi4py import MPI

        V = dolfinx.fem.VectorFunctionSpace(to_dolfinx(mesh, MPI.COMM_SELF), ("Lagrange", 1))
        self.u = dolfinx.fem.Function(V)
        energy = strain_energy_ufl(material, self.u)
        self.form = dolfinx.fem.form(ufl.derivative(energy, self.u, ufl.TestFunction(V)))
        self.dofs = p1_dof_vertices(V)

    def __call__(self, u: np.ndarray) -> np.ndarray:
        import dolfinx.fem

        self.u.x.array[:] = input_order_to_dofs(u, self.dofs, 3)
        values = np.array(dolfinx.fem.assemble_vector(self.form).array)
        return petsc_vec_to_input_order(values, self.dofs, 3)


@pytest.fixture(scope="module")
def clamped():
    mesh = structured_box((0.1, 0.1, 0.6), (2, 2, 10))
    fixed = np.flatnonzero(mesh.points[:, 2] < 1e-12)
    modes = linear_modes(mesh, MATERIAL, K_MODES, fixed_vertices=fixed)
    return mesh, modes, modal_derivatives(mesh, MATERIAL, modes)


@pytest.fixture(scope="module")
def free():
    mesh = structured_box((0.1, 0.15, 0.5), (2, 2, 8))
    modes = linear_modes(mesh, MATERIAL, K_MODES)
    return mesh, modes, modal_derivatives(mesh, MATERIAL, modes)


# ---------------------------------------------------------------- H and Ψ


def test_hessian_matches_the_exact_cubic_force_identities(clamped):
    mesh, modes, _ = clamped
    hessian, force = ForceHessian(mesh, MATERIAL), InternalForce(mesh, MATERIAL)
    a, b = modes.vectors[:, 0], modes.vectors[:, 2]
    size = np.abs(a).max()
    H_aa, H_ab = hessian(a, a), hessian(a, b)
    for eps in (1e-3 / size, 3e-2 / size):  # displacements of 1 mm and 3 cm on a 0.6 m bar
        # f is cubic for StVK: f(εa) + f(−εa) = ε² H(a, a) for every ε
        fd = (force(eps * a) + force(-eps * a)) / eps**2
        assert rel(fd, H_aa) < 1e-8, f"eps={eps:.2e}: {rel(fd, H_aa):.2e}"
        # polarisation: H(a, b) = [H(a+b, a+b) − H(a−b, a−b)] / 4
        s, d = a + b, a - b
        fd = (force(eps * s) + force(-eps * s) - force(eps * d) - force(-eps * d)) / (4 * eps**2)
        assert rel(fd, H_ab) < 1e-8, f"eps={eps:.2e}: {rel(fd, H_ab):.2e}"
    assert rel(hessian(b, a), H_ab) < 1e-13


def test_derivatives_solve_the_clamped_system_and_are_symmetric(clamped):
    mesh, modes, derivatives = clamped
    p = K_MODES * (K_MODES + 1) // 2
    assert derivatives.vectors.shape == (3 * mesh.n_vertices, p)
    np.testing.assert_array_equal(derivatives.pairs, all_pairs(K_MODES))
    assert derivatives.residuals.max() < 1e-10
    hessian = ForceHessian(mesh, MATERIAL)
    fixed = (3 * modes.fixed_vertices[:, None] + np.arange(3)).ravel()
    free = np.setdiff1d(np.arange(3 * mesh.n_vertices), fixed)
    K = modes.stiffness
    for q, (i, j) in enumerate(derivatives.pairs):
        psi = derivatives.vectors[:, q]
        h = hessian(modes.vectors[:, i], modes.vectors[:, j])
        assert np.all(psi[fixed] == 0.0)
        assert rel((K @ psi)[free], -h[free]) < 1e-9, f"pair {(i, j)}"
    swapped = modal_derivatives(mesh, MATERIAL, modes, pairs=np.array([[1, 3], [3, 1]]))
    a, b = swapped.vectors.T
    assert rel(a, b) < 1e-12, f"Psi_13 vs Psi_31: {rel(a, b):.2e}"
    q13 = int(np.flatnonzero((derivatives.pairs == [1, 3]).all(axis=1))[0])
    assert rel(a, derivatives.vectors[:, q13]) < 1e-12


def test_free_derivatives_are_the_rigid_free_solution(free):
    mesh, modes, derivatives = free
    M, K, R = modes.mass, modes.stiffness, modes.rigid
    Psi = derivatives.vectors
    m_norm = np.sqrt(np.einsum("ij,ij->j", Psi, M @ Psi))
    leak = np.abs(R.T @ (M @ Psi)).max(axis=0) / m_norm
    assert leak.max() < 1e-10, f"rigid components of the derivatives (relative): {leak.max():.2e}"
    # the unique solution of K x = −(I − MRRᵀ) h with RᵀMx = 0 from the dense bordered system
    hessian = ForceHessian(mesh, MATERIAL)
    C = M @ R
    bordered = np.block([[K.toarray(), C], [C.T, np.zeros((6, 6))]])
    for q in (0, 4, 9):
        i, j = derivatives.pairs[q]
        h = hessian(modes.vectors[:, i], modes.vectors[:, j])
        x = np.linalg.solve(bordered, np.concatenate([-h, np.zeros(6)]))[: 3 * mesh.n_vertices]
        assert rel(Psi[:, q], x) < 1e-8, f"pair {(i, j)}: {rel(Psi[:, q], x):.2e}"


def test_bad_pairs_and_foreign_modes_raise(clamped, free):
    mesh, modes, _ = clamped
    with pytest.raises(LbshapeError, match="pair index out of range"):
        modal_derivatives(mesh, MATERIAL, modes, pairs=np.array([[0, K_MODES]]))
    with pytest.raises(LbshapeError, match=r"shape \(p, 2\)"):
        modal_derivatives(mesh, MATERIAL, modes, pairs=np.array([0, 1]))
    with pytest.raises(LbshapeError, match="do not belong to this mesh"):
        modal_derivatives(free[0], MATERIAL, modes)


# ---------------------------------------------------------------- basis


@pytest.mark.parametrize("case", ["clamped", "free"])
@pytest.mark.parametrize("keep_linear", [True, False])
def test_basis_is_mass_orthonormal(case, keep_linear, request):
    mesh, modes, derivatives = request.getfixturevalue(case)
    basis = nonlinear_basis(modes, derivatives, modes.mass, 12, keep_linear=keep_linear)
    assert basis.U.shape == (3 * mesh.n_vertices, 12) and basis.r == 12
    error = np.abs(basis.U.T @ (modes.mass @ basis.U) - np.eye(12)).max()
    assert error < 1e-10, f"max |U^T M U - I| = {error:.2e}"
    rayleigh = np.einsum("ij,ij->j", basis.U, modes.stiffness @ basis.U)
    np.testing.assert_allclose(basis.omega2, rayleigh, rtol=1e-12)
    if case == "free":
        leak = np.abs(modes.rigid.T @ (modes.mass @ basis.U)).max()
        assert leak < 1e-10, f"rigid component of U: {leak:.2e}"


def test_kept_linear_modes_are_spanned_exactly(clamped):
    _, modes, derivatives = clamped
    basis = nonlinear_basis(modes, derivatives, modes.mass, 12)
    angles = m_subspace_angles(basis.U, modes.vectors, modes.mass)
    assert angles.max() < 1e-8, f"principal angles to the linear modes {angles}"
    np.testing.assert_allclose(basis.omega2[:K_MODES], modes.omega2, rtol=1e-8)
    small = nonlinear_basis(modes, derivatives, modes.mass, 3)  # r < k: the lowest modes
    assert np.abs(small.U - modes.vectors[:, :3]).max() < 1e-12


def test_joint_pca_matches_a_dense_svd(clamped):
    _, modes, derivatives = clamped
    omega2 = modes.omega2
    i, j = derivatives.pairs.T
    X = np.hstack([modes.vectors * (omega2[0] / omega2),
                   derivatives.vectors * (omega2[0] ** 2 / (omega2[i] * omega2[j]))])
    L = np.linalg.cholesky(modes.mass.toarray())  # ⟨x, y⟩_M = (Lᵀx)·(Lᵀy)
    W, s, _ = np.linalg.svd(L.T @ X, full_matrices=False)
    r = 10
    basis = nonlinear_basis(modes, derivatives, modes.mass, r, keep_linear=False)
    np.testing.assert_allclose(basis.singular_values[:r], s[:r], rtol=1e-8)
    U_ref = np.linalg.solve(L.T, W[:, :r])
    angles = m_subspace_angles(basis.U, U_ref, modes.mass)
    gap = s[r - 1] / s[r]
    assert angles.max() < 1e-7, f"angles to the dense PCA subspace {angles} (gap {gap:.3f})"


def test_basis_size_errors_say_what_is_available(clamped):
    _, modes, derivatives = clamped
    p = derivatives.pairs.shape[0]
    with pytest.raises(LbshapeError, match=rf"{K_MODES + p} vectors available "
                                           rf"\({K_MODES} linear modes \+ {p} modal"):
        nonlinear_basis(modes, derivatives, modes.mass, K_MODES + p + 1)
    with pytest.raises(LbshapeError, match="r must be an integer >= 1"):
        nonlinear_basis(modes, derivatives, modes.mass, 0)
    # three copies of one derivative: rank k + 1 although k + 3 vectors are offered
    twice = modal_derivatives(clamped[0], MATERIAL, modes, pairs=np.array([[0, 0]] * 3))
    with pytest.raises(LbshapeError, match=rf"numerical rank {K_MODES + 1} of the {K_MODES + 3}"):
        nonlinear_basis(modes, twice, modes.mass, K_MODES + 2)
    basis = nonlinear_basis(modes, twice, modes.mass, K_MODES + 1)
    assert basis.r == K_MODES + 1



def test_default_linear_modes_rule():
    # smallest k with k + k(k+1)/2 ≥ 2r: the paper's r = 30 takes 10 modes + 55 derivatives
    assert [default_linear_modes(r) for r in (1, 2, 10, 20, 30, 42)] == [1, 2, 5, 8, 10, 12]
    for r in (5, 30, 42):
        k = default_linear_modes(r)
        assert k + k * (k + 1) // 2 >= 2 * r > (k - 1) + (k - 1) * k // 2


def test_rigid_pinning_accepts_a_free_car_body():
    """Regression: the pinning check read a wrong entry of the QR factor and refused
    bodies such as the car; it must pin exactly 6 well-conditioned DOFs."""
    from lbshape.elastic.element_kernels import mass_matrix
    from lbshape.elastic.modal_derivatives import _unpinned_dofs
    from lbshape.elastic.modes import rigid_body_modes
    from lbshape.geometry.shapes import build_shape

    car = build_shape("car")
    rigid = rigid_body_modes(car.points, mass_matrix(car, 1000.0))
    kept = _unpinned_dofs(rigid)
    assert kept.size == 3 * car.n_vertices - 6
    pinned = np.setdiff1d(np.arange(3 * car.n_vertices), kept)
    assert np.linalg.matrix_rank(rigid[pinned]) == 6


def test_compiled_hessians_equal_the_ufl_form_for_every_pair(clamped):
    mesh, modes, _ = clamped
    hessian = ForceHessian(mesh, MATERIAL)
    pairs = all_pairs(K_MODES)
    compiled = force_hessians(mesh, MATERIAL, modes.vectors, pairs)
    assert compiled.shape == (3 * mesh.n_vertices, pairs.shape[0])
    for q, (i, j) in enumerate(pairs):
        reference = hessian(modes.vectors[:, i], modes.vectors[:, j])
        assert rel(compiled[:, q], reference) < 1e-12, f"pair {(i, j)}"
