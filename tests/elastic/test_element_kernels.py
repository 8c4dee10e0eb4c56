"""Numpy hyperelastic kernels against UFL/DOLFINx, finite differences and analytic truth."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import observed_rates, rel

from lbshape.elastic.element_kernels import (
    ElementKernel,
    FullSpaceElasticity,
    internal_force,
    mass_matrix,
    strain_energy,
    tangent_stiffness,
)
from lbshape.elastic.energy_densities import (
    energy_density,
    first_piola,
    first_piola_derivative,
    rest_energy_density,
)
from lbshape.elastic.materials import Material
from lbshape.errors import LbshapeError
from lbshape.geometry.primitives import structured_box

MODELS = ("stvk", "neohookean")
YOUNG, POISSON, RHO = 2.0e5, 0.35, 1100.0


def material(model: str) -> Material:
    return Material(model, young=YOUNG, poisson=POISSON, density=RHO)


def rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


@pytest.fixture(scope="module")
def small_mesh():
    return structured_box((0.3, 0.2, 0.25), (2, 2, 2))


def smooth_displacement(points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A random smooth field (n, 3) with displacement gradients of about 0.2-0.3."""
    L = np.ptp(points, axis=0).max()
    x = points / L
    A = 0.2 * rng.normal(size=(3, 3))
    Q = 0.15 * rng.normal(size=(3, 3))
    k = rng.uniform(1.0, 3.0, size=3)
    u = x @ A.T + (x**2) @ Q.T + 0.05 * np.sin(k * x[:, [1, 2, 0]])
    return L * u


def random_elements(rng: np.random.Generator, e: int = 8):
    """e unconnected tetrahedra of size ~1 m with random shapes; two are left-handed."""
    base = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    points = (base[None] + 0.25 * rng.normal(size=(e, 4, 3))).reshape(-1, 3)
    tets = np.arange(4 * e).reshape(e, 4)
    tets[:2] = tets[:2][:, [0, 2, 1, 3]]
    return points, tets


# -- UFL/DOLFINx vs numpy ------------------------------------------------------------------
@pytest.mark.parametrize("model", MODELS)
def test_numpy_kernels_match_ufl_assembly_to_round_off(small_mesh, model):
    import dolfinx.fem
    import dolfinx.fem.petsc
    import ufl

    from lbshape.elastic.materials import strain_energy_ufl
    from lbshape.fem.dolfinx_bridge import (
        input_order_to_dofs,
        p1_dof_vertices,
        petsc_to_scipy,
        petsc_vec_to_input_order,
        to_dolfinx,
    )

    mat = material(model)
    dmesh = to_dolfinx(small_mesh)
    V = dolfinx.fem.VectorFunctionSpace(dmesh, ("Lagrange", 1))
    dof_vertices = p1_dof_vertices(V)
    u = dolfinx.fem.Function(V)
    E = strain_energy_ufl(mat, u)
    R = ufl.derivative(E, u, ufl.TestFunction(V))
    K = ufl.derivative(R, u, ufl.TrialFunction(V))
    energy_form, force_form, tangent_form = (dolfinx.fem.form(a) for a in (E, R, K))

    def ufl_energy_force_tangent(values):
        u.x.array[:] = input_order_to_dofs(values, dof_vertices, 3)
        energy = dolfinx.fem.assemble_scalar(energy_form)
        b = dolfinx.fem.petsc.assemble_vector(force_form)
        force = petsc_vec_to_input_order(b.array.copy(), dof_vertices, 3)
        b.destroy()
        A = dolfinx.fem.petsc.assemble_matrix(tangent_form)
        A.assemble()
        tangent = petsc_to_scipy(A, dof_vertices, block_size=3)
        A.destroy()
        return energy, force, tangent

    full = FullSpaceElasticity(small_mesh, mat)
    rest_energy, _, _ = ufl_energy_force_tangent(np.zeros(full.n_dofs))
    # the numpy densities are zero at rest; the UFL stable-NH density may carry the
    # textbook constant Ψ(I) (then it is rest_energy_density), so compare E(u) − E(0)
    shifted = rest_energy_density(mat) * small_mesh.volume()
    tol = 1e-12 * YOUNG * small_mesh.volume()
    assert abs(rest_energy) <= tol or abs(rest_energy - shifted) <= tol, (rest_energy, shifted)
    rng = np.random.default_rng(11)
    for trial in range(2):
        values = smooth_displacement(small_mesh.points, rng).ravel()
        e_ufl, f_ufl, K_ufl = ufl_energy_force_tangent(values)
        e_np = full.energy(values)
        f_np, K_np = full.force_and_tangent(values)
        err_e = abs(e_np - (e_ufl - rest_energy)) / abs(e_ufl - rest_energy)
        err_f = rel(f_np, f_ufl)
        err_K = rel(K_np.toarray(), K_ufl.toarray())
        assert err_e < 1e-10, f"{model} trial {trial}: energy relative error {err_e:.2e}"
        assert err_f < 1e-12, f"{model} trial {trial}: force relative error {err_f:.2e}"
        assert err_K < 1e-12, f"{model} trial {trial}: tangent relative error {err_K:.2e}"
        # same sparsity, and the thin wrappers give the same numbers
        assert K_np.nnz == K_ufl.nnz, (K_np.nnz, K_ufl.nnz)
    assert strain_energy(small_mesh, mat, values) == pytest.approx(e_np, rel=1e-14)
    np.testing.assert_allclose(internal_force(small_mesh, mat, values), f_np, rtol=0, atol=0)
    assert abs(tangent_stiffness(small_mesh, mat, values) - K_np).max() == 0.0


def test_mass_matrix_matches_dolfinx_and_lumping(small_mesh):
    import dolfinx.fem
    import dolfinx.fem.petsc
    import ufl

    from lbshape.fem.dolfinx_bridge import p1_dof_vertices, petsc_to_scipy, to_dolfinx

    dmesh = to_dolfinx(small_mesh)
    V = dolfinx.fem.VectorFunctionSpace(dmesh, ("Lagrange", 1))
    a = RHO * ufl.inner(ufl.TrialFunction(V), ufl.TestFunction(V)) * ufl.dx
    A = dolfinx.fem.petsc.assemble_matrix(dolfinx.fem.form(a))
    A.assemble()
    M_ref = petsc_to_scipy(A, p1_dof_vertices(V), block_size=3).toarray()
    A.destroy()
    M = mass_matrix(small_mesh, RHO).toarray()
    err = rel(M, M_ref)
    assert err < 1e-13, f"consistent mass vs DOLFINx: relative error {err:.2e}"
    ML = mass_matrix(small_mesh, RHO, lumped=True).toarray()
    np.testing.assert_allclose(np.diag(ML), M.sum(axis=1), rtol=1e-13)
    assert np.count_nonzero(ML - np.diag(np.diag(ML))) == 0
    total = RHO * small_mesh.volume()
    ex = np.tile([1.0, 0.0, 0.0], small_mesh.n_vertices)
    for matrix in (M, ML):
        assert ex @ matrix @ ex == pytest.approx(total, rel=1e-13)


# -- finite differences ---------------------------------------------------------------------
def _fd_errors(kernel: ElementKernel, ue: np.ndarray, steps):
    """Relative errors of forces vs FD(energy) and tangents vs FD(forces) per step."""
    e = kernel.n_elements
    f, K = kernel.forces_and_tangents(ue)
    out = []
    for h in steps:
        f_fd = np.empty((e, 12))
        K_fd = np.empty((e, 12, 12))
        for d in range(12):  # every element is perturbed at once: they are independent
            du = np.zeros((e, 12))
            du[:, d] = h
            du = du.reshape(e, 4, 3)
            f_fd[:, d] = (kernel.energy(ue + du) - kernel.energy(ue - du)) / (2 * h)
            K_fd[:, :, d] = ((kernel.forces(ue + du) - kernel.forces(ue - du)) / (2 * h)).reshape(
                e, 12
            )
        out.append((rel(f_fd, f.reshape(e, 12)), rel(K_fd, K)))
    return np.array(out)


@pytest.mark.parametrize("model", MODELS)
def test_forces_and_tangents_match_central_differences_at_second_order(model):
    rng = np.random.default_rng(5)
    points, tets = random_elements(rng)
    kernel = ElementKernel(points, tets, material(model))
    ue = 0.2 * rng.normal(size=(kernel.n_elements, 4, 3))
    assert kernel.min_jacobian(ue) > 0.05, "want a deformed but non-inverted state"
    h = np.array([1e-3, 5e-4])
    errors = _fd_errors(kernel, ue, h)
    rates = observed_rates(errors, h)[0]
    msg = f"{model}: FD errors (force, tangent) at h={h}: {errors.tolist()}, rates {rates}"
    assert np.all(errors[1] < 1e-5), msg
    assert np.all(np.abs(rates - 2.0) < 0.15), msg
    # the tangent is the symmetric Hessian
    K = kernel.tangents(ue)
    assert rel(K, K.transpose(0, 2, 1)) < 1e-14


@pytest.mark.parametrize("model", MODELS)
def test_density_stress_and_derivative_match_differences_also_when_inverted(model):
    rng = np.random.default_rng(9)
    F = np.eye(3) + 0.4 * rng.normal(size=(12, 3, 3))
    F[:4, 0] *= -1.0  # some inverted
    F[4:6] *= 0.05  # some nearly collapsed
    assert (np.linalg.det(F) < 0).any()
    mat = material(model)
    F_in = F.copy()
    P, A = first_piola(mat, F), first_piola_derivative(mat, F)
    single = energy_density(mat, F[:1])  # a single element must not be modified in place
    np.testing.assert_array_equal(F, F_in)
    assert single[0] == energy_density(mat, F)[0]
    errors, steps = [], (1e-3, 5e-4)
    for h in steps:
        P_fd, A_fd = np.empty_like(P), np.empty_like(A)
        for k in range(3):
            for m in range(3):
                dF = np.zeros((3, 3))
                dF[k, m] = h
                P_fd[:, k, m] = (energy_density(mat, F + dF) - energy_density(mat, F - dF)) / (
                    2 * h
                )
                A_fd[..., k, m] = (first_piola(mat, F + dF) - first_piola(mat, F - dF)) / (2 * h)
        errors.append((rel(P_fd, P), rel(A_fd, A)))
    errors = np.array(errors)
    rates = observed_rates(errors, steps)[0]
    msg = f"{model}: errors {errors.tolist()}, rates {rates}"
    assert np.all(errors[1] < 1e-6) and np.all(np.abs(rates - 2.0) < 0.15), msg
    # major symmetry of the stress derivative
    assert rel(A, A.transpose(0, 3, 4, 1, 2)) < 1e-14


# -- rest state and rigid motion --------------------------------------------------------------
def linear_elastic_stiffness(kernel: ElementKernel, young: float, poisson: float) -> np.ndarray:
    """Textbook V Bᵀ D B from the Voigt (engineering-shear) matrix D(E, ν), (e, 12, 12)."""
    c = young / ((1 + poisson) * (1 - 2 * poisson))
    D = np.zeros((6, 6))
    D[:3, :3] = c * poisson
    D[np.arange(3), np.arange(3)] = c * (1 - poisson)
    D[np.arange(3, 6), np.arange(3, 6)] = c * (1 - 2 * poisson) / 2
    e = kernel.n_elements
    B = np.zeros((e, 6, 12))
    g = kernel.gradients
    for a in range(4):
        x, y, z = g[:, a, 0], g[:, a, 1], g[:, a, 2]
        B[:, 0, 3 * a], B[:, 1, 3 * a + 1], B[:, 2, 3 * a + 2] = x, y, z
        B[:, 3, 3 * a + 1], B[:, 3, 3 * a + 2] = z, y  # γ_yz
        B[:, 4, 3 * a], B[:, 4, 3 * a + 2] = z, x  # γ_xz
        B[:, 5, 3 * a], B[:, 5, 3 * a + 1] = y, x  # γ_xy
    return kernel.volumes[:, None, None] * np.einsum("eij,jk,ekl->eil", B.transpose(0, 2, 1), D, B)


@pytest.mark.parametrize("model", MODELS)
def test_rest_state_is_stress_free_and_linearises_to_linear_elasticity(model):
    rng = np.random.default_rng(2)
    points, tets = random_elements(rng)
    kernel = ElementKernel(points, tets, material(model))
    zero = np.zeros((kernel.n_elements, 4, 3))
    f, K = kernel.forces_and_tangents(zero)
    scale = kernel.material.mu * kernel.volumes.max()
    assert np.abs(kernel.energy(zero)).max() <= 1e-14 * scale
    assert np.abs(f).max() <= 1e-13 * scale, f"rest force {np.abs(f).max():.2e}"
    K_lin = linear_elastic_stiffness(kernel, YOUNG, POISSON)
    err = rel(K, K_lin)
    assert err < 1e-13, f"{model}: rest tangent vs linear elasticity, relative error {err:.2e}"
    assert kernel.min_jacobian(zero) == pytest.approx(1.0, abs=1e-14)


@pytest.mark.parametrize("model", MODELS)
def test_small_deformations_keep_their_digits(model):
    """E(u) = ½ uᵀK₀u + O(|u|³): the relative gap must shrink like |u| down to 1e-8 m."""
    rng = np.random.default_rng(3)
    points, tets = random_elements(rng)
    kernel = ElementKernel(points, tets, material(model))
    e = kernel.n_elements
    K0 = kernel.tangents(np.zeros((e, 4, 3)))
    direction = rng.normal(size=(e, 12))
    for size in (1e-5, 1e-8):
        ue = size * direction
        quadratic = 0.5 * np.einsum("ei,eij,ej->e", ue, K0, ue)
        gap = np.abs(kernel.energy(ue.reshape(e, 4, 3)) - quadratic).max() / quadratic.max()
        assert gap < 20 * size, f"{model}: |u| ~ {size:g} m, relative gap {gap:.2e}"


@pytest.mark.parametrize("model", MODELS)
def test_rigid_motion_has_no_energy_or_force_and_rotates_the_tangent(small_mesh, model):
    rng = np.random.default_rng(4)
    full = FullSpaceElasticity(small_mesh, material(model))
    K0 = full.tangent(np.zeros(full.n_dofs)).toarray()
    X = small_mesh.points
    scale = full.kernel.material.mu * small_mesh.volume()
    for _ in range(3):
        R = rotation(rng)
        u = (X @ R.T - X + rng.normal(size=3)).ravel()
        f, K = full.force_and_tangent(u)
        assert abs(full.energy(u)) <= 1e-13 * scale, full.energy(u)
        assert np.abs(f).max() <= 1e-13 * scale, np.abs(f).max()
        Rb = np.kron(np.eye(small_mesh.n_vertices), R)
        err = rel(K.toarray(), Rb @ K0 @ Rb.T)
        assert err < 1e-13, f"{model}: K(R) vs R K(0) Rᵀ, relative error {err:.2e}"


# -- compression and inversion ------------------------------------------------------------------
def uniaxial(stretch: np.ndarray) -> np.ndarray:
    F = np.tile(np.eye(3), (len(stretch), 1, 1))
    F[:, 0, 0] = stretch
    return F


def test_stvk_softens_past_one_over_sqrt3_and_has_an_inverted_rest_state():
    mat = material("stvk")
    k = 2 * mat.mu + mat.lam
    s = np.linspace(-1.2, 1.5, 271)
    F = uniaxial(s)
    P11 = first_piola(mat, F)[:, 0, 0]
    dP11 = first_piola_derivative(mat, F)[:, 0, 0, 0, 0]
    np.testing.assert_allclose(P11, k * s * (s**2 - 1) / 2, rtol=1e-12, atol=1e-9 * k)
    np.testing.assert_allclose(dP11, k * (3 * s**2 - 1) / 2, rtol=1e-12, atol=1e-9 * k)
    soft = (s > 0) & (s < 1 / math.sqrt(3) - 1e-9)
    assert soft.sum() > 50
    # dP/dλ < 0: further compression lowers the resisting stress
    assert np.all(dP11[soft] < 0), dP11[soft].max()
    assert np.all(dP11[s > 1 / math.sqrt(3) + 1e-9] > 0)
    # at full collapse the element stops resisting, and the mirror image (J = −1)
    # is a stress-free zero-energy state: StVK is not a usable model there
    collapsed = uniaxial(np.array([0.0, -1.0]))
    assert np.abs(first_piola(mat, collapsed)[0, 0, 0]) <= 1e-12 * k
    assert np.abs(energy_density(mat, collapsed[1:])).max() <= 1e-12 * k
    assert np.abs(first_piola(mat, collapsed[1:])).max() <= 1e-12 * k
    assert np.isfinite(energy_density(mat, F)).all()


def test_stable_neohookean_resists_compression_and_inversion_monotonically():
    mat = material("neohookean")
    mu, lam, alpha = mat.stable_nh_parameters
    s = np.linspace(-1.2, 1.5, 271)
    F = uniaxial(s)
    psi = energy_density(mat, F)
    P11 = first_piola(mat, F)[:, 0, 0]
    dP11 = first_piola_derivative(mat, F)[:, 0, 0, 0, 0]
    ic = s**2 + 2
    np.testing.assert_allclose(
        P11, mu * s * (1 - 1 / (ic + 1)) + lam * (s - alpha), rtol=1e-12, atol=1e-12 * lam
    )
    expected = mu * (1 - 1 / (ic + 1) + 2 * s**2 / (ic + 1) ** 2) + lam
    np.testing.assert_allclose(dP11, expected, rtol=1e-12)
    assert np.all(dP11 > 0) and np.all(np.diff(P11) > 0), "stress must be monotone in stretch"
    assert np.isfinite(psi).all() and np.isfinite(P11).all() and np.isfinite(dP11).all()
    # energy rises all the way from rest, through J = 0, into inversion (J < 0)
    compress = s <= 1.0
    assert np.all(np.diff(psi[compress]) < 0), "energy must grow as J decreases"
    assert psi[np.argmin(np.abs(s))] > 0.1 * lam
    assert psi[0] > psi[np.argmin(np.abs(s))]


@pytest.mark.parametrize("model", MODELS)
def test_inverted_elements_are_reported_and_stay_finite(model):
    rng = np.random.default_rng(8)
    points, tets = random_elements(rng, e=4)
    kernel = ElementKernel(points, tets, material(model))
    ue = np.zeros((4, 4, 3))
    X = points[tets]
    # push the last vertex of element 1 through its opposite face, twice the distance
    centroid = X[1, :3].mean(axis=0)
    ue[1, 3] = 2.0 * (centroid - X[1, 3])
    J = kernel.jacobians(ue)
    assert J[1] == pytest.approx(-1.0, abs=1e-12), J
    np.testing.assert_allclose(J[[0, 2, 3]], 1.0, atol=1e-14)
    np.testing.assert_allclose(J, np.linalg.det(kernel.deformation_gradient(ue)), atol=1e-13)
    assert kernel.min_jacobian(ue) == pytest.approx(-1.0, abs=1e-12)
    energy = kernel.energy(ue)
    f, K = kernel.forces_and_tangents(ue)
    assert np.isfinite(energy).all() and np.isfinite(f).all() and np.isfinite(K).all()
    if model == "neohookean":
        assert energy[1] > 0.1 * kernel.material.mu * kernel.volumes[1]


# -- bad input ------------------------------------------------------------------------------------
def test_bad_parameters_and_shapes_raise_clear_errors():
    for kwargs in (
        {"poisson": 0.5},
        {"poisson": 0.7},
        {"young": 0.0},
        {"young": -1.0},
        {"density": 0.0},
        {"density": -5.0},
    ):
        with pytest.raises(LbshapeError):
            Material("stvk", **kwargs)
    points = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    with pytest.raises(LbshapeError, match="degenerate"):
        ElementKernel(points, np.array([[0, 1, 2, 3]]), material("stvk"))
    points[3] = [0, 0, 1]
    kernel = ElementKernel(points, np.array([[0, 1, 2, 3]]), material("stvk"))
    with pytest.raises(LbshapeError, match="shape"):
        kernel.forces(np.zeros((4, 3)))
    with pytest.raises(LbshapeError, match="out of range"):
        ElementKernel(points, np.array([[0, 1, 2, 4]]), material("stvk"))
    mesh = structured_box(divisions=(1, 1, 1))
    with pytest.raises(LbshapeError, match="density"):
        mass_matrix(mesh, 0.0)
    with pytest.raises(LbshapeError, match="node-major"):
        FullSpaceElasticity(mesh, material("stvk")).force(np.zeros(5))
    with pytest.raises(LbshapeError, match=r"\(e, 3, 3\)"):
        energy_density(material("stvk"), np.eye(3))


def test_benchmark_script_smoke(tmp_path, load_script):
    import json
    from pathlib import Path

    module = load_script("bench_element_kernels")
    out = module.main(
        ["--elements", "7", "--number", "2", "--repeats", "2", "-o", str(tmp_path / "bench.json")]
    )
    result = json.loads(Path(out).read_text())
    assert result["n_elements"] == 7 and len(result["rows"]) == 6
    assert all(0 < row["min_us"] <= row["median_us"] <= row["max_us"] for row in result["rows"])
