"""Local examples by region: partition rules, forces, weights, and the global limit."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from lbshape.dynamics.full import FullSpaceSimulator
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.materials import Material
from lbshape.errors import LbshapeError
from lbshape.geometry.poses import twist
from lbshape.geometry.primitives import structured_box
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.routes import example_driver
from lbshape.pipeline.simulate import reduced_simulation
from lbshape.scene.reader import load_scene
from lbshape.scene.schema import LocalRegion, Selection
from lbshape.shapespace.local_build import RegionSpec, build_local_space
from lbshape.shapespace.local_driver import local_example_driver
from lbshape.shapespace.local_full_force import FullSpaceLocalForce
from lbshape.shapespace.local_regions import check_partition, region_cells, rigid_fields, submesh
from lbshape.shapespace.local_space import LocalShapeSpace, region_descriptor
from lbshape.shapespace.target_table import DEFAULT_TOLERANCE

MATERIAL = Material(model="stvk", young=1e5, poisson=0.3, density=1000.0)
BAR = (0.2, 0.2, 1.0)
M = 4


@pytest.fixture(autouse=True)
def _private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("LBSHAPE_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


def _basis(mesh, r: int, rng) -> np.ndarray:
    """A random (3n, r) basis with ``Uᵀ M U = I`` (M the elastic mass)."""
    mass = mass_matrix(mesh, MATERIAL.density).toarray()
    A = rng.normal(size=(3 * mesh.n_vertices, r))
    R = np.linalg.cholesky(A.T @ mass @ A)
    return np.linalg.solve(R, A.T).T


def _twisted_examples(angles):
    """example_part for a finer bar twisted by ``angles[k]`` about z (pose on the part)."""
    example = structured_box(BAR, (2, 2, 10))

    def part(k, spec):
        cells = region_cells(example, group=spec.group, region=spec.region)
        sub, _ = submesh(example, cells)
        return sub, twist(sub.points, angle=angles[k], axis="z", anchor="max")

    return part


def _local_space(specs, angles, *, seed=0, r=12, fixed=None):
    mesh = structured_box(BAR, (2, 2, 8))
    U = _basis(mesh, r, np.random.default_rng(seed))
    space = build_local_space(mesh, MATERIAL, U, specs, _twisted_examples(angles), m=M,
                              fixed_vertices=fixed)
    return mesh, U, space


def test_overlapping_regions_and_disconnected_regions_are_one_line_errors():
    mesh = structured_box(BAR, (2, 2, 8))
    a = region_cells(mesh, region="z < 0.6")
    b = region_cells(mesh, region="z > 0.4")
    with pytest.raises(LbshapeError, match="'low' and 'high' share .* tetrahedra") as info:
        check_partition(["low", "high"], [a, b], mesh.n_tets)
    assert "\n" not in str(info.value)
    ends = region_cells(mesh, region="(z < 0.2) | (z > 0.8)")
    with pytest.raises(LbshapeError, match="not connected"):
        submesh(mesh, ends, what="region 'ends'")
    with pytest.raises(LbshapeError, match="no volume group 'arm'"):
        region_cells(mesh, group="arm")


def test_rest_examples_exert_no_force():
    """Examples equal to the rest shape (another resolution): no force at rest, and
    none on a region that only moves rigidly; a posed neighbour still pulls."""
    specs = [RegionSpec("low", None, "z < 0.5", (0,)), RegionSpec("high", None, "z >= 0.5", (1,))]
    bottom = np.flatnonzero(structured_box(BAR, (2, 2, 8)).points[:, 2] < 1e-9)
    mesh, U, space = _local_space(specs, angles=(0.0, 0.8), fixed=bottom)
    low = space.regions[0]
    assert np.abs(low.example_coefficients).max() < 1e-12
    force = FullSpaceLocalForce(mesh, MATERIAL, space)
    k_ex = 100.0

    def example_force(u):
        u = u.reshape(-1)
        return k_ex * (force.pull(u) - force.mass @ u)

    rest = example_force(np.zeros(3 * mesh.n_vertices)).reshape(-1, 3)
    inside_low = np.setdiff1d(low.vertices, space.regions[1].vertices)
    assert np.abs(rest[inside_low]).max() < 1e-12
    assert np.abs(rest).max() > 1e-3  # the twisted region does pull
    # a rigid motion (translation and infinitesimal rotation) of the region
    part = low.submesh(mesh)
    rigid = rigid_fields(part.points, mass_matrix(part, 1.0)) @ np.array(
        [0.01, -0.02, 0.03, 0.02, -0.01, 0.03])
    shift = np.zeros((mesh.n_vertices, 3))
    shift[low.vertices] = rigid.reshape(-1, 3)
    only_low = FullSpaceLocalForce(mesh, MATERIAL, dataclasses.replace(
        space, regions=(low,)))
    f = k_ex * (only_low.pull(shift) - only_low.mass @ shift.reshape(-1))
    scale = k_ex * np.abs(only_low.mass @ shift.reshape(-1)).max()
    assert np.abs(f).max() < 1e-10 * scale


def test_region_force_leaves_outside_vertices_unpulled_in_full_space():
    specs = [RegionSpec("low", None, "z < 0.4", (0,))]
    mesh, U, space = _local_space(specs, angles=(1.0,))
    low = space.regions[0]
    sim = FullSpaceSimulator(mesh, MATERIAL, dt=1e-3, fixed_vertices=np.flatnonzero(
        mesh.points[:, 2] > 0.999), local_examples=(FullSpaceLocalForce(mesh, MATERIAL, space),
                                                   100.0))
    sim.run(3)
    u = sim.full_displacement().reshape(-1)
    force = 100.0 * (sim._local.pull(u) - sim._local.mass @ u)
    force = force.reshape(-1, 3)
    outside = np.setdiff1d(np.arange(mesh.n_vertices), low.vertices)
    assert outside.size > 0
    np.testing.assert_array_equal(force[outside], 0.0)
    assert np.linalg.norm(force[low.vertices], axis=1).max() > 1e-6


def test_per_region_weights_follow_eq5():
    """Two regions with a gap between them, each in a known state: the weights of each
    region solve paper eq. 5 on that region's own descriptors (checked by brute force)."""
    specs = [RegionSpec("low", None, "z < 0.35", (0, 1)),
             RegionSpec("high", None, "z > 0.65", (2, 0))]
    mesh, U, space = _local_space(specs, angles=(0.9, -0.6, 0.4))
    low, high = space.regions
    assert np.intersect1d(low.vertices, high.vertices).size == 0
    u = np.zeros((mesh.n_vertices, 3))
    c_low = 0.3 * low.example_coefficients[0] + 0.7 * low.example_coefficients[1]
    c_high = 1.6 * high.example_coefficients[0] - 0.6 * high.example_coefficients[1]
    u[low.vertices] = low.displacement(c_low)
    u[high.vertices] = high.displacement(c_high)
    force = FullSpaceLocalForce(mesh, MATERIAL, space)
    force.pull(u)
    np.testing.assert_allclose(force.weights["low"], [0.3, 0.7], atol=1e-8)
    for region in (low, high):
        d = region_descriptor(mesh, region, u)
        E = region.example_descriptors(MATERIAL.density)
        grid = np.linspace(0.0, 1.0, 2001)
        residual = [np.linalg.norm((1 - t) * E[0] + t * E[1] - d) for t in grid]
        best = grid[int(np.argmin(residual))]
        np.testing.assert_allclose(force.weights[region.name], [1 - best, best], atol=1e-3)
    np.testing.assert_allclose(force.weights["high"], [1.0, 0.0], atol=1e-12)
    # the reduced driver's descriptors are the full-space ones of U q
    q = np.random.default_rng(1).normal(size=U.shape[1]) * 1e-3
    driver = local_example_driver(mesh, MATERIAL, space, route="lb-exact")
    uq = (U @ q).reshape(-1, 3)
    force.pull(uq)
    for name, w in driver.region_weights(q).items():
        np.testing.assert_allclose(w, force.weights[name], atol=1e-10)


@pytest.mark.parametrize("angles", [(0.9, -0.5), (0.9, -0.5, 0.3)])
def test_region_target_table_matches_newton_on_the_runtime_path(angles):
    """Two examples: Hermite in w₁; three: cubic triangles. Built with the local space
    (checked there), the step's in-place path looks it up already mapped to the pull and
    agrees with the Newton solve of the exact target at weights never tabulated."""
    k = len(angles)
    specs = [RegionSpec("low", None, "z < 0.5", tuple(range(k)))]
    mesh, U, space = _local_space(specs, angles=angles)
    region = space.regions[0]
    table = region.table
    assert table is not None and table.k == k
    assert table.check.max_error <= DEFAULT_TOLERANCE and table.check.checks >= 40
    tabulated = local_example_driver(mesh, MATERIAL, space, route="lb-exact")
    newton = local_example_driver(mesh, MATERIAL, space, route="lb-exact", tabulate=False,
                                  tolerance=1e-12, max_iterations=100)
    assert tabulated.drivers[0].solver.table is not table  # a mapped copy, the stored one kept
    offsets = region.example_coefficients.reshape(k, -1)
    separation = max(np.linalg.norm(a - b) for a in offsets for b in offsets)
    pull = region.pull_matrix()
    rng = np.random.default_rng(3)
    out = np.zeros(U.shape[1])
    for w in [*rng.dirichlet(np.ones(k), size=12), np.eye(k)[0]]:
        exact = newton.drivers[0].solver.solve(w).z
        looked_up = tabulated.drivers[0].solver.solve(w).z
        assert np.linalg.norm(looked_up - exact) <= 1e-2 * separation
        tabulated.drivers[0].w[:] = w
        tabulated.drivers[0].target_from_weights_into(out)
        np.testing.assert_allclose(out, pull @ looked_up, rtol=0,
                                   atol=1e-12 * np.abs(pull @ looked_up).max())


def test_in_place_step_of_the_local_driver_equals_its_target_and_allocates_nothing():
    import tracemalloc

    specs = [RegionSpec("low", None, "z < 0.5", (0, 1)), RegionSpec("high", None, "z >= 0.5",
                                                                    (1, 2))]
    bottom = np.flatnonzero(structured_box(BAR, (2, 2, 8)).points[:, 2] < 1e-9)
    mesh, U, space = _local_space(specs, angles=(0.9, -0.5, 0.4), fixed=bottom)
    driver = local_example_driver(mesh, MATERIAL, space, route="lb-exact")
    assert all(d.solver.table is not None for d in driver.drivers)
    rng = np.random.default_rng(5)
    out = np.zeros(U.shape[1])
    states = [rng.normal(size=U.shape[1]) * 1e-2 for _ in range(20)]
    for q in states:
        driver.weights_into(q)
        driver.target_from_weights_into(out)
        np.testing.assert_allclose(out, driver.target(q).q_target, rtol=1e-12, atol=1e-15)
    tracemalloc.start()
    before = tracemalloc.take_snapshot()
    for q in states * 5:
        driver.weights_into(q)
        driver.target_from_weights_into(out)
    after = tracemalloc.take_snapshot()
    tracemalloc.stop()
    grown = sum(stat.size_diff for stat in after.compare_to(before, "filename")
                if stat.size_diff > 0 and "lbshape" in str(stat.traceback))
    assert grown == 0, grown


def test_region_tables_survive_the_precompute_artifact():
    specs = [RegionSpec("low", None, "z < 0.5", (0, 1)), RegionSpec("high", None, "z >= 0.5",
                                                                    (0, 1, 2, 3))]
    mesh, U, space = _local_space(specs, angles=(0.9, -0.5, 0.4, 0.2))
    low, high = space.regions
    assert low.table is not None and high.table is None  # four examples: solved at run time
    restored = LocalShapeSpace.from_arrays(["low", "high"], space.arrays(), {})
    np.testing.assert_array_equal(restored.regions[0].table.cells, low.table.cells)
    assert restored.regions[0].table.check == low.table.check
    assert restored.regions[1].table is None
    # each example's alignment method travels with the artifact (copies: the overlay)
    assert low.methods == ["overlay", "overlay"] and high.methods == ["overlay"] * 4
    assert restored.regions[0].methods == low.methods
    assert restored.regions[1].methods == high.methods
    untabulated = build_local_space(mesh, MATERIAL, U, specs[:1],
                                    _twisted_examples((0.9, -0.5)), m=M, tabulate=False)
    assert untabulated.regions[0].table is None
    # without a stored table the driver builds the same one at set-up
    driver = local_example_driver(mesh, MATERIAL, untabulated, route="lb-exact")
    np.testing.assert_allclose(driver.drivers[0].solver.table.cells, low.table.cells,
                               rtol=1e-9, atol=1e-12 * np.abs(low.table.cells).max())


def test_one_region_covering_the_object_reproduces_the_global_path():
    scene = load_scene("demo")
    whole = dataclasses.replace(scene, name="demo-one-region", regions=(
        LocalRegion("all", Selection(region="z > -1"), (0, 1)),))
    pre_global, pre_local = precompute(scene), precompute(whole)
    np.testing.assert_allclose(pre_local.U, pre_global.U, rtol=0, atol=1e-12)
    region = pre_local.local.regions[0]
    assert region.cells.size == pre_local.mesh.n_tets
    np.testing.assert_allclose(pre_local.local.spring, np.eye(pre_local.r), atol=1e-12)
    scale = np.abs(pre_global.examples.example_coefficients).max()
    np.testing.assert_allclose(region.example_coefficients,
                               pre_global.examples.example_coefficients, rtol=0,
                               atol=1e-9 * scale)
    steps = 40
    # the global path with the same exact target (the default tabulates it) and basis
    reference = reduced_simulation(scene, pre_global)
    reference.driver = example_driver(pre_global, route="lb-exact", boundary="free")
    reference = reference.run(steps)
    sim = reduced_simulation(whole, pre_local)
    sim.driver = local_example_driver(pre_local.mesh, pre_local.material, pre_local.local,
                                      route="lb-exact", tabulate=False, free_rigid=False)
    local = sim.run(steps)
    a, b = np.array(reference.states), np.array(local.states)
    assert np.abs(a).max() > 1e-3
    np.testing.assert_allclose(b, a, rtol=0, atol=1e-8 * np.abs(a).max())


def test_reduced_pull_is_the_projection_of_the_region_target():
    """At rest a one-example region's pull is ``Uᵀ M^(R) u*_R``: its example placed on
    the region's vertices and attached at the region's anchor (rigidly moved so that
    it fits the resting anchor), weighted by the region's mass only."""
    specs = [RegionSpec("low", None, "z < 0.5", (0,))]
    mesh, U, space = _local_space(specs, angles=(0.8,), r=20)
    low = space.regions[0]
    part = low.submesh(mesh)
    part_mass = mass_matrix(part, MATERIAL.density)
    Q = rigid_fields(part.points, part_mass)
    shape = low.displacement(low.example_coefficients[0]).reshape(-1)
    anchor = np.repeat(low.anchor, 3)
    assert anchor.any() and not anchor.all()
    # the rigid motion that best fits -shape on the anchor (lumped-mass least squares)
    w = np.asarray(part_mass.sum(axis=1)).ravel()[anchor]
    g, *_ = np.linalg.lstsq(Q[anchor] * np.sqrt(w)[:, None], -shape[anchor] * np.sqrt(w),
                            rcond=None)
    anchored = shape + Q @ g
    np.testing.assert_allclose(np.abs(anchored[anchor]).max() < np.abs(shape[anchor]).max(),
                               True)
    region_mass = FullSpaceLocalForce(mesh, MATERIAL, space).mass
    for free_rigid, target in ((False, shape), (True, anchored)):
        info = local_example_driver(mesh, MATERIAL, space, route="lb-exact",
                                    free_rigid=free_rigid).target(np.zeros(U.shape[1]))
        placed = np.zeros((mesh.n_vertices, 3))
        placed[low.vertices] = target.reshape(-1, 3)
        expected = U.T @ (region_mass @ placed.reshape(-1))
        np.testing.assert_allclose(info.q_target, expected, rtol=0,
                                   atol=1e-9 * np.abs(expected).max())
    np.testing.assert_allclose(space.spring, U.T @ (region_mass @ U), atol=1e-12)


def test_scene_regions_must_be_disjoint(tmp_path):
    lines = (load_scene("demo").source.read_text() + "\n"
             + "\n".join(itertools.chain.from_iterable(
                 ("[[regions]]", f'name = "{n}"', f'region = "{e}"', "examples = [0]")
                 for n, e in (("a", "z < 0.6"), ("b", "z > 0.4")))))
    path = tmp_path / "overlap.toml"
    path.write_text(lines)
    with pytest.raises(LbshapeError, match="share"):
        precompute(load_scene(path))


@pytest.mark.parametrize("name, m, r, s, regions, example_shape", [
    ("cross", 10, 42, 21, ("left", "right", "middle"), "cross-example"),
    # teddy-local: r = 24 before its example responses, teddy-global r = 40 (measured
    # in the scene files); Table 2's paper setting runs the paper's r = 30
    ("teddy-local", 6, 24, 30, ("left_leg", "right_leg", "left_arm", "right_arm"),
     "teddy-example"),
    ("teddy-global", 6, 40, 30, (), "teddy-example"),
])
def test_paper_local_scenes_load_with_table2_sizes(name, m, r, s, regions, example_shape):
    scene = load_scene(name)
    assert (scene.reduced.m, scene.reduced.r, scene.reduced.s) == (m, r, s)
    assert tuple(reg.name for reg in scene.regions) == regions
    assert {p.source.shape for p in scene.examples.poses} == {example_shape}
    assert not scene.is_free and scene.loads
    used = {k for reg in scene.regions for k in reg.examples}
    assert not regions or used == set(range(len(scene.examples.poses)))
