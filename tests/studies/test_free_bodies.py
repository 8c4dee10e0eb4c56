"""The free bodies' evaluation (:mod:`lbshape.studies.free_bodies`): the designed impact
scenes, the synchronised restart of the reduced body from the full run's state, a
designed impact through both methods, and the Table 2 keys of ``bench --free-eval``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lbshape.analysis.free_body_eval import ImpactMeasures, project_state
from lbshape.analysis.norms import trajectory_error
from lbshape.cli import main
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.io.machine import machine_description
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import simulate
from lbshape.pipeline.simulation import Simulation
from lbshape.scene.reader import load_scene
from lbshape.scene.variants import (
    impact_scene,
    with_contact_stiffness,
    with_mesh_size,
    with_throw,
    without_examples,
)
from lbshape.studies.bench import ROW_FREE_EVAL_KEYS, bench_scene
from lbshape.studies.free_bodies import (
    IMPACT_DESIGNS,
    IMPACT_NORMALS,
    ImpactComparison,
    designed_impact,
    impact_jobs,
    perturbed,
    refinement_change,
    restart_reduced,
    write_free_bodies,
)
from lbshape.studies.tables import table2_markdown


@pytest.fixture(scope="module")
def bar():
    scene = load_scene("bar-s-cuboid")
    return scene, precompute(scene)


@pytest.mark.slow
def test_the_designed_impact_scene_throws_the_body_at_its_plane(bar):
    scene, pre = bar
    normal = np.array(IMPACT_NORMALS["corner"]) / np.sqrt(3.0)
    variant = impact_scene(scene, pre.mesh.points, IMPACT_NORMALS["corner"], 2.0, 0.02, "x")
    plane = variant.planes[0]
    np.testing.assert_allclose(plane.normal, normal)
    gaps = (pre.mesh.points - np.asarray(plane.point)) @ normal
    assert gaps.min() == pytest.approx(0.02, abs=1e-12)
    np.testing.assert_allclose(variant.initial.velocity, -2.0 * normal)
    assert variant.loads == () and variant.initial.angular_velocity == (0.0, 0.0, 0.0)
    assert plane.stiffness == scene.planes[0].stiffness
    with pytest.raises(LbshapeError):
        impact_scene(scene, pre.mesh.points, (0.0, 0.0, 1.0), 0.0, 0.02, "x")


@pytest.mark.slow
def test_the_noise_floor_perturbations_change_what_they_name(bar):
    scene, _ = bar
    assert with_throw(scene, 1.01).initial.angular_velocity[1] == pytest.approx(1.5 * 1.01)
    assert with_contact_stiffness(scene, 0.9).planes[0].stiffness == pytest.approx(
        0.9 * scene.planes[0].stiffness)
    half = perturbed(scene, "step", 0.5)
    assert half.simulation.dt == pytest.approx(5e-4)
    assert half.simulation.steps == 2 * scene.simulation.steps


@pytest.mark.slow
@pytest.mark.parametrize("examples", [False, True])
def test_the_restart_reproduces_the_full_pre_impact_state(bar, examples):
    scene, pre = bar
    variant = impact_scene(scene, pre.mesh.points, IMPACT_NORMALS["edge"], 1.5, 0.03, "edge")
    if not examples:
        variant = without_examples(variant)
    mass = mass_matrix(pre.mesh, pre.material.density)
    rest, dt, start = pre.mesh.points, variant.simulation.dt, 8
    full = Simulation(variant, pre, method="full")
    points = rest + full.displacements(full.run(start + 4))
    reduced = Simulation(variant, pre, method="reduced")
    restart_reduced(reduced, project_state(points[start - 1:start + 2], dt, rest, mass, pre.U),
                    start * dt, start)
    assert reduced.time == pytest.approx(start * dt)
    tolerance = 1e-3 if examples else 1e-9  # the examples bend the full body off span U
    assert trajectory_error(reduced.displacement()[None], points[start][None] - rest,
                            mass) < tolerance
    later = reduced.displacements(reduced.run(3))[-1]  # still in flight: the same motion
    assert trajectory_error(later[None], points[start + 3][None] - rest, mass) < 1e-3


@pytest.mark.slow
def test_a_designed_face_hit_bounces_both_bodies(bar):
    scene, pre = bar
    impact = designed_impact(scene, pre, "face", 1.5, examples=False)
    assert impact.message == ""
    stats = impact.stats()
    assert 0.1 < stats["restitution_full"] < 1.0 and 0.1 < stats["restitution_reduced"] < 1.0
    assert stats["delta_p_full"] > 1.5 * 40.0  # more than the body's 40 kg stopped
    assert stats["depth_full_mm"] > 0.0 and stats["depth_reduced_mm"] > 0.0
    assert impact.restart_error < 1e-9


@pytest.mark.slow
def test_the_cars_designed_front_hit_bounces_within_its_target():
    """The car's own design: its front face into a plane at half its throw speed; the
    reduced car (with its impact columns) within 5 % of full in restitution, Δp and ΔL
    (measured 1.9, 1.5 and 0.6 %)."""
    car = load_scene("car")
    impact = designed_impact(car, precompute(car), "face", IMPACT_DESIGNS["car"].speeds[0],
                             examples=False)
    assert impact.message == "" and impact.body == "car"
    stats = impact.stats()
    assert 0.5 < stats["restitution_full"] < 1.0
    assert max(stats["restitution_error"], stats["delta_p_error"],
               stats["delta_L_error"]) < 0.05


def _measures(restitution: float) -> ImpactMeasures:
    return ImpactMeasures(restitution, np.array([1.0, 0.0, 0.0]), np.zeros(3), 0.5, 1e-3)


def test_the_report_has_one_designed_impact_section_per_body(tmp_path):
    """Each body's rows under its own heading, counted against its targets."""
    assert impact_jobs() == ["@impacts:bar-s-cuboid", "@impacts:car"]
    impacts = [ImpactComparison("face", 1.5, False, _measures(0.5), _measures(0.51),
                                body="bar-s-cuboid"),
               ImpactComparison("edge", 3.0, True, _measures(0.5), _measures(0.6),
                                body="bar-s-cuboid"),
               ImpactComparison("face", 5.0, False, _measures(0.5), _measures(0.6),
                                body="car"),
               ImpactComparison("corner", 5.0, True, message="no contact after the flight",
                                body="car")]
    md, js = write_free_bodies([], impacts, tmp_path, command="x")
    text = md.read_text()
    assert ("### bar-s-cuboid: 1 of 1 within 5 % without examples, 0 of 1 within 10 % with"
            in text)
    assert "### car: 0 of 1 within 5 % without examples, 0 of 1 within 10 % with" in text
    car_section = text.split("### car:", 1)[1]
    assert "The car (length along x" in car_section and "| corner | 5 | yes |" in car_section
    assert [row["body"] for row in json.loads(js.read_text())["impacts"]] == [
        "bar-s-cuboid", "bar-s-cuboid", "car", "car"]


@pytest.mark.slow
def test_bench_free_eval_fills_the_free_body_keys(bar):
    scene, pre = bar
    scene = without_examples(scene)
    result = bench_scene(scene, steps=20, repeats=1, pre=pre, methods=("full", "reduced"),
                         influence=False, free_eval=True)
    reduced, full = result.row("reduced"), result.row("full")
    assert all(key in reduced for key in ROW_FREE_EVAL_KEYS)
    assert reduced["noise_floor"] > 0.0 and full["noise_floor"] == reduced["noise_floor"]
    assert reduced["first_contact_s"] is None  # 20 steps: still falling
    assert reduced["error_pre_contact"] == pytest.approx(reduced["error_vs_full"])
    assert reduced["error_pre_contact"] < 1e-3  # the flight matches
    assert reduced["rest_pose_chamfer"] < 1e-6
    assert reduced["error_over_floor"] == pytest.approx(
        reduced["error_vs_full"] / reduced["noise_floor"])
    text = table2_markdown([result], machine_description())
    section = text.split("beside the reference's noise floor", 1)[1]
    assert f"| bar-s-cuboid | reduced | {100 * reduced['error_vs_full']:.2f}% | " in section


@pytest.mark.parametrize("argv", [["--free-bodies", "bar-cuboid"],
                                  ["--free-bodies", "--sweep"],
                                  ["--free-eval", "--scaling"]])
def test_free_body_options_refuse_what_they_do_not_measure(argv, capsys):
    assert main(["bench", *argv]) == 2
    assert capsys.readouterr().err.count("\n") == 1


def test_with_mesh_size_refines_the_object_and_its_same_shape_examples(bar):
    scene, _ = bar
    fine = with_mesh_size(scene, 0.5)
    assert fine.object.shape == scene.object.shape and fine.object.size == pytest.approx(
        0.5 * 0.0665)
    assert all(pose.source == fine.object for pose in fine.examples.poses)
    car = load_scene("car")
    assert with_mesh_size(car, 0.5).examples.poses == car.examples.poses  # its own shape
    with pytest.raises(LbshapeError, match="> 0"):
        with_mesh_size(scene, 0.0)


@pytest.mark.slow
def test_the_refined_reference_in_flight_matches_through_the_transfer(bar):
    """Before contact the bar only falls and spins: the full reference on the mesh at half
    the size, interpolated onto this mesh's vertices, stays within 0.1 % of this one's
    (1.2e-5 measured over 40 steps; its stiffness differs a little)."""
    scene, pre = bar
    scene = without_examples(scene)
    mass = mass_matrix(pre.mesh, pre.material.density)
    full = simulate(scene, pre, method="full", steps=40)
    change, pose = refinement_change(scene, pre, full, mass, steps=40)
    assert change is not None and 0.0 < change < 1e-3, change
    assert pose is not None and pose < 1e-3
