"""The runs behind the scene-level pictures (``lbshape render``), drawn by
:mod:`lbshape.report.figures`.

* :func:`examples_comparison` — rest | no examples | examples, final frames, for any
  scene whose examples act on the whole object (``comparison.png``; the built-in bars
  also get Figure 3, the demo its own comparison, local examples ``local_result.png``);
* :func:`local_examples_figures` — scenes with local examples (the paper's Figures
  6 and 7): the regions, each example as the regions it guides see it, and the
  final frame without and with the examples;
* :func:`figure3` — the paper's Figure 3: rest; no examples, same-topology examples
  and other-topology examples in full space; other-topology examples reduced — the
  final frame of each, with the end twist and the examples' influence;
* :func:`figure5` — the paper's Figures 4 and 5: a free body with no example and with
  each example alone, the runs in rows, a few times in columns (``runs_by_example.png``),
  and close up each run's final shape in the body frame beside its example
  (``runs_by_example_shapes.png``);
* :func:`figure6` — the paper's Figure 6: one dragged object without examples, with
  global and with local examples, from the side, and the local run coloured by its
  distance to the global one (``figure6.png``, ``figure6_difference.png``);
* :func:`render_scene` — all of the pictures that a scene supports, into one folder.

Numbers behind each composite picture go to a JSON file next to it.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lbshape.analysis.free_body import body_deformations
from lbshape.analysis.influence import visible_change
from lbshape.analysis.norms import m_norms
from lbshape.analysis.twist import end_twist_degrees
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError, SolverError
from lbshape.io.atomic import write_json_atomic
from lbshape.io.paths import output_root
from lbshape.pipeline.influence import closest_example, compare_runs, has_example_force
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import example_influence, simulate
from lbshape.report.figures import (
    TRAJECTORY_ZOOM,
    closest_caption,
    comparison_figure,
    deformed,
    eigenfunctions_figure,
    example_caption,
    examples_figures,
    figure5_pictures,
    figure6_pictures,
    local_pictures,
    local_result_figure,
    simulation_figure,
)
from lbshape.report.render import render_shapes, scene_planes
from lbshape.scene.variants import without_examples
from lbshape.shapespace.local_space import region_example_distance

log = logging.getLogger(__name__)

#: built-in scenes for the Figure 3 comparison: (same-topology, other-topology examples)
FIGURE3_SCENES: tuple[str, str] = ("bar-cuboid", "bar-cylinder")
#: steps of the Figure 3 runs (0.4 s at dt = 1 ms: the 0.3 s torque ramp is over)
FIGURE3_STEPS = 400
#: built-in scenes of Figure 6: (global examples, local examples), one teddy, one drag
FIGURE6_SCENES: tuple[str, str] = ("teddy-global", "teddy-local")
#: what Figure 6's two scenes must share, so that only their examples differ
FIGURE6_SHARED = ("material", "damping", "fixed", "loads", "planes", "simulation", "initial")


def default_out(scene_name: str) -> Path:
    """The default folder of a scene's pictures: ``figures/SCENE`` under
    :func:`lbshape.io.paths.output_root` (``results/`` in the repository's root,
    else ``./lbshape-results/``)."""
    return output_root() / "figures" / scene_name


@dataclass(frozen=True)
class Figure3:
    """The Figure 3 comparison.

    Attributes:
        path: the PNG.
        labels: (5,) panel captions.
        final_max_displacement: (5,) largest vertex displacement of each final frame (m).
        reduced_vs_full_final: relative mass-norm difference of the final frames of
            the other-topology runs, ``‖u_red − u_full‖_M / ‖u_full‖_M``.
        steps: steps per run.
    """

    path: Path
    labels: tuple[str, ...]
    final_max_displacement: tuple[float, ...]
    reduced_vs_full_final: float
    steps: int


@dataclass(frozen=True)
class RenderedScene:
    """What :func:`render_scene` wrote.

    Attributes:
        scene: scene name.
        paths: the PNGs written, in order.
        summary: the JSON summary file.
        message: the run's solver failure message ('' if it finished).
    """

    scene: str
    paths: tuple[Path, ...]
    summary: Path
    message: str = ""


def local_examples_figures(scene, pre, output, out_dir: str | Path) -> tuple[Path, ...]:
    """``local_regions.png``, ``local_examples.png``, ``local_result.png`` and
    ``local_examples.json``.

    The regions picture colours the object at rest by region; the examples picture
    shows the rest shape and each example as the regions it guides see it
    (reconstructed on the object's mesh from the region's m coefficients), coloured
    by the example's displacement; the result picture the rest shape, the final
    frame of the same run without examples (k_ex = 0) and ``output``'s final frame,
    coloured by |u|. The JSON holds the example influence ``‖u_ex − u_none‖_M / ‖u_none‖_M``
    and, per region, the distance to its examples (eq. 5's residual, relative to
    the largest example) and weights, without and with the examples. The examples and
    result pictures draw the rest shape as a faint wireframe in every panel.
    """
    if not pre.has_local_examples:
        raise LbshapeError(f"scene {scene.name} has no local examples to draw")
    out_dir = Path(out_dir)
    regions_png, examples_png, view = local_pictures(scene, pre, out_dir)
    method = output.stats.get("method", "reduced")
    effect, none = example_influence(scene, pre, output, method=method,
                                     steps=output.stats["steps"])
    u_none, u_ex = none.displacements[-1], output.displacements[-1]
    influence = effect.final
    t = output.times[-1]
    result_png = local_result_figure(pre, output, none, effect, out_dir / "local_result.png",
                                     method=method, view=view)
    regions = {}
    for region in pre.local.regions:
        d_none, w_none = region_example_distance(pre.mesh, region, u_none,
                                                 density=pre.material.density)
        d_ex, w_ex = region_example_distance(pre.mesh, region, u_ex,
                                             density=pre.material.density)
        regions[region.name] = {
            "examples": [int(k) for k in region.examples],
            "distance_to_examples": {"no_examples": d_none, "examples": d_ex},
            "weights": {"no_examples": w_none.tolist(), "examples": w_ex.tolist()},
            "moves_toward_examples": bool(d_ex < d_none),
            "alignment_residuals": region.alignment_residuals.tolist(),
            "alignment_methods": region.methods,
        }
    summary = write_json_atomic(out_dir / "local_examples.json", {
        "scene": scene.name, "method": method, "steps": output.stats["steps"],
        "time_s": float(t), "example_influence": influence,
        "visible_change": effect.visible_change, "closest_example": effect.closest_example,
        "example_distances": effect.example_distances, "regions": regions,
        "covered_volume_fraction": pre.local.covered,
        "representation_errors": pre.local.representation_errors,
    })
    return regions_png, examples_png, result_png, summary


def _examples_label(scene) -> str:
    source = scene.examples.poses[0].source
    return source.shape or Path(source.label).stem


def _one_object(figure: str, first, second, progress: bool):
    """The precomputes of two scenes that must simulate one mesh (same points and
    tetrahedra), for a figure comparing their runs.

    Raises:
        LbshapeError: the scenes' meshes differ.
    """
    pre_first = precompute(first, progress=progress)
    pre_second = precompute(second, progress=progress)
    a, b = pre_first.mesh, pre_second.mesh
    if a.points.shape != b.points.shape or not np.allclose(a.points, b.points) \
            or not np.array_equal(a.tets, b.tets):
        raise LbshapeError(f"{figure} needs one object: {first.name} and {second.name} "
                           "simulate different meshes")
    return pre_first, pre_second


def figure3(same_topology, other_topology, path: str | Path, *,
            steps: int = FIGURE3_STEPS, progress: bool = False) -> Figure3:
    """The paper's Figure 3 for an object with two example sets (final frames).

    Panels: the object at rest; ``full`` without examples (k_ex = 0, the loads
    alone); ``full`` with ``same_topology``'s examples; ``full`` with
    ``other_topology``'s examples; ``reduced`` with ``other_topology``'s examples.
    A JSON summary (``path`` with suffix ``.json``) holds the numbers.

    Args:
        same_topology: scene whose examples share the object's topology.
        other_topology: the same object and loads with other-topology examples.
        path: output PNG.
        steps: steps per run.
        progress: precompute progress bars on stderr.

    Raises:
        LbshapeError: a scene without examples, or scenes with different objects.
    """
    for scene in (same_topology, other_topology):
        if scene.examples is None:
            raise LbshapeError(f"Figure 3 needs scenes with examples; {scene.name} has none")
    pre_same, pre_other = _one_object("Figure 3", same_topology, other_topology, progress)
    a = pre_same.mesh
    no_examples = without_examples(same_topology)
    same_label, other_label = _examples_label(same_topology), _examples_label(other_topology)
    runs = [
        ("no examples (full)", no_examples, pre_same, "full"),
        (f"{same_label} examples (full)", same_topology, pre_same, "full"),
        (f"{other_label} examples (full)", other_topology, pre_other, "full"),
        (f"{other_label} examples (reduced)", other_topology, pre_other, "reduced"),
    ]
    outputs, labels = [], ["rest"]
    for label, scene, pre, method in runs:
        output = simulate(scene, pre, method=method, steps=steps)
        if output.message:
            raise SolverError(f"Figure 3 run '{label}' stopped: {output.message}")
        outputs.append(output)
        log.info("figure 3: %s done", label)
    finals = [output.displacements[-1] for output in outputs]
    twists = [end_twist_degrees(a.points, u, end="free", fixed=pre_same.fixed_vertices)
              for u in finals]
    for (label, *_), output, twist in zip(runs, outputs, twists, strict=True):
        labels.append(f"{label}\nt={output.times[-1]:.2f} s, end twist {twist:.0f} deg")
    mass = mass_matrix(a, pre_same.material.density)
    # the examples' effect on the full-space runs, against the run without examples
    influences = [compare_runs(pre, output, outputs[0], mass).stats() for pre, output in
                  ((pre_same, outputs[1]), (pre_other, outputs[2]))]
    flat_full, flat_reduced = finals[2].reshape(-1), finals[3].reshape(-1)
    diff = flat_reduced - flat_full
    reference = float(np.sqrt(flat_full @ (mass @ flat_full)))
    relative = float(np.sqrt(diff @ (mass @ diff))) / reference if reference > 0 else float("nan")
    meshes = [a, *(deformed(pre_same, u) for u in finals)]
    scalars = [None, *(np.linalg.norm(u, axis=1) for u in finals)]
    png = render_shapes(meshes, labels, path, scalars=scalars, ghost=a,
                        scalar_name="displacement (m)")
    maxima = (0.0, *(float(np.linalg.norm(u, axis=1).max()) for u in finals))
    result = Figure3(png, tuple(labels), maxima, relative, int(steps))
    write_json_atomic(Path(path).with_suffix(".json"), {
        "scenes": [same_topology.name, other_topology.name], "steps": int(steps),
        "dt": same_topology.simulation.dt, "panels": list(labels),
        "final_max_displacement_m": list(maxima),
        "end_twist_deg": [0.0, *twists],
        "example_influence_full": {same_topology.name: influences[0],
                                   other_topology.name: influences[1]},
        "reduced_vs_full_final_relative_m_norm": relative,
    })
    return result


@dataclass(frozen=True)
class Figure5:
    """The paper's Figure 5: a free body's reaction with no example and each example alone.

    Attributes:
        path: the PNG (rows: runs; first column: the row's example on the object, then
            times).
        labels: (k+1,) run names, the first without examples.
        influence_world: (k,) ``‖u_ex(T) − u_none(T)‖_M / ‖u_none(T)‖_M`` of the world
            displacements at the last frame.
        influence_body: (k,) the same on the body-frame deformation (best rigid fit
            removed), what the examples act on.
        visible_change: (k,) largest vertex distance between the final deformations
            with the example and without, over the rest bounding-box diagonal
            (:func:`lbshape.analysis.influence.visible_change`).
        closest: (k+1,) per run, ``"rest"`` or the index of the scene's example its
            final deformation is closest to in shape space (among all the scene's
            examples; :func:`lbshape.pipeline.influence.closest_example`).
        messages: per run, the solver failure message ('' if it finished).
        shapes: the close-up PNG (``<path stem>_shapes.png``): per run, its example on
            the object beside the run's final shape in the body frame (best rigid fit
            removed), the rest shape as a wireframe in every panel.
    """

    path: Path
    labels: tuple[str, ...]
    influence_world: tuple[float, ...]
    influence_body: tuple[float, ...]
    visible_change: tuple[float, ...]
    closest: tuple[object, ...]
    messages: tuple[str, ...]
    shapes: Path | None = None


def _scalar_mass(pre):
    """(n, n) scalar mass M₁ (kg) of the object."""
    return mass_matrix(pre.mesh, pre.material.density)[0::3, 0::3]


def figure5(scene, path: str | Path, *, steps: int | None = None, frames: int = 4,
            progress: bool = False) -> Figure5:
    """Runs a free scene with no example and with each of its examples alone, side by side.

    Each variant has its own precompute (the example set is part of the cache key).
    Row k starts with example k reconstructed on the object (grey; the first row: the
    rest shape), then ``frames`` times of the run, coloured by the body-frame
    deformation (best rigid fit removed) on one colour range, under one fixed camera,
    with the contact planes. Each row's last caption gives the shape the run ends
    closest to (among the rest shape and *all* the scene's examples, on the whole
    scene's LB descriptors) and its visible change. Numbers go to
    ``<path stem>.json`` next to the PNG. The trajectory's camera shows where the body
    flies; ``<path stem>_shapes.png`` shows what each example did to its shape, close up:
    per run its example (grey) and its final shape in the body frame, coloured by the
    deformation on the same range, the rest shape as a wireframe in every panel.
    """
    if not scene.has_examples or not scene.is_free:
        raise LbshapeError(f"scene {scene.name}: Figure 5 needs a free body with examples")
    every = precompute(scene, progress=progress)  # all examples: the candidates of 'closest'
    names = [pose.pose or f"posed {k}" for k, pose in enumerate(scene.examples.poses)]
    variants = [("no example", dataclasses.replace(scene, examples=None))]
    for pose in scene.examples.poses:
        single = dataclasses.replace(scene.examples, poses=(pose,))
        variants.append((f"{pose.pose or 'posed'} example", dataclasses.replace(
            scene, examples=single)))
    runs = []
    for name, variant in variants:
        pre = precompute(variant, progress=progress)
        runs.append((name, pre, simulate(variant, pre, method="reduced", steps=steps)))
    messages = [output.message for _, _, output in runs]
    scalar_mass = _scalar_mass(every)
    rest = every.mesh.points
    # each run's final deformation (best rigid fit removed) and the shape it ends closest to
    bodies = [body_deformations(scalar_mass, rest, np.asarray(output.displacements)[-1:])[0]
              for _, _, output in runs]
    descriptors = every.examples.example_descriptors
    closest = [closest_example(every, body, descriptors)[0] for body in bodies]
    mass = mass_matrix(every.mesh, every.material.density)
    finals = [output.displacements[-1] for _, _, output in runs]
    world = [float(m_norms((u - finals[0])[None], mass)[0] / m_norms(finals[0][None], mass)[0])
             for u in finals[1:]]
    deformation = [float(m_norms((b - bodies[0])[None], mass)[0]
                         / m_norms(bodies[0][None], mass)[0]) for b in bodies[1:]]
    visible = [visible_change(rest, b, bodies[0]) for b in bodies[1:]]
    notes = [closest_caption(c, names) for c in closest]
    for k, change in enumerate(visible, start=1):
        notes[k] += f", visible change {100 * change:.1f} %"
    path, shapes = figure5_pictures(every, runs, names, notes, path, frames=frames,
                                    planes=scene_planes(scene))
    result = Figure5(path, tuple(n for n, _ in variants), tuple(world),
                     tuple(deformation), tuple(visible), tuple(closest), tuple(messages),
                     shapes)
    runs = list(result.labels)
    write_json_atomic(Path(path).with_suffix(".json"), {
        "scene": scene.name, "runs": runs, "steps": steps,
        "examples": names,
        "influence_world_final": dict(zip(runs[1:], world, strict=True)),
        "influence_body_frame_final": dict(zip(runs[1:], deformation, strict=True)),
        "visible_change": dict(zip(runs[1:], visible, strict=True)),
        "closest_example": dict(zip(runs, closest, strict=True)),
        "each_run_closest_to_its_example": all(c == k for k, c in enumerate(closest[1:])),
        "messages": list(messages),
    })
    return result


@dataclass(frozen=True)
class Figure6:
    """The paper's Figure 6: the dragged teddy without examples, with global and with
    local examples, side by side from the side; and the local run against the global one.

    Attributes:
        path: the PNG (rest | no examples | global examples | local examples, final
            frames, coloured by |u| on one range, the rest shape as a wireframe).
        difference: ``<path stem>_difference.png``: the local run's final shape
            coloured by its distance to the global run's, which is drawn as a wireframe.
        height: the object's extent along z (m; the teddy's height, the drag's direction).
        region_displacement: per run (``no examples``, ``global``, ``local``), per
            region of the local scene, its largest vertex displacement at the end over
            ``height``.
        difference_by_region: per region, the largest vertex distance between the local
            and the global run's final shapes over ``height``.
        difference_max: the largest over the whole object (m).
    """

    path: Path
    difference: Path
    height: float
    region_displacement: dict[str, dict[str, float]]
    difference_by_region: dict[str, float]
    difference_max: float


def figure6(global_scene, local_scene, path: str | Path, *, steps: int | None = None,
            progress: bool = False) -> Figure6:
    """The paper's Figure 6 for one object, one load and two example sets (reduced runs).

    ``global_scene``'s examples act on the whole object, ``local_scene``'s on its
    regions; both drag the same object with the same loads. The camera looks at the
    object from the side along x (up: z, the drag's direction), where the drag and the
    limbs' curl towards the front lie in the picture's plane. The numbers go to
    ``<path stem>.json``: per run and region the largest displacement over the
    object's height, per region the largest local-vs-global distance, and which example
    each run ends closest to (global: the whole object; local: per region).

    Raises:
        LbshapeError: scenes on different meshes or differing in anything but their
            examples (:data:`FIGURE6_SHARED`), a global scene with local examples or a
            local scene without, or a run that stopped.
    """
    if not local_scene.regions or global_scene.regions or global_scene.examples is None:
        raise LbshapeError(f"Figure 6 needs a scene with global examples and one with local "
                           f"examples; got {global_scene.name} and {local_scene.name}")
    differ = [key for key in FIGURE6_SHARED
              if getattr(global_scene, key) != getattr(local_scene, key)]
    if differ:
        raise LbshapeError(f"Figure 6 compares example sets on one motion: {global_scene.name} "
                           f"and {local_scene.name} differ in {', '.join(differ)}")
    pre_global, pre_local = _one_object("Figure 6", global_scene, local_scene, progress)
    runs = {"no examples": (without_examples(global_scene), pre_global),
            "global": (global_scene, pre_global), "local": (local_scene, pre_local)}
    finals = {}
    for name, (scene, pre) in runs.items():
        output = simulate(scene, pre, method="reduced", steps=steps)
        if output.message:
            raise SolverError(f"Figure 6 run '{name}' stopped: {output.message}")
        finals[name] = np.asarray(output.displacements[-1])
        time = float(output.times[-1])
    rest = pre_global.mesh.points
    height = float(np.ptp(rest[:, 2]))
    regions = {region.name: region.vertices for region in pre_local.local.regions}
    moved = {name: {region: float(np.linalg.norm(u[vertices], axis=1).max()) / height
                    for region, vertices in regions.items()} for name, u in finals.items()}
    distance = np.linalg.norm(finals["local"] - finals["global"], axis=1)
    by_region = {region: float(distance[vertices].max()) / height
                 for region, vertices in regions.items()}
    closest_global = closest_example(pre_global, finals["global"])[0]
    closest_local = closest_example(pre_local, finals["local"])[0]
    peak = int(np.argmax(distance))
    where = next((region for region, vertices in regions.items() if peak in vertices),
                 "outside the local regions")
    png, difference = figure6_pictures(
        pre_global, pre_local, finals, path, time=time, moved=moved,
        closest_global=closest_caption(closest_global, range(len(global_scene.examples.poses))),
        closest_local=closest_local, by_region=by_region, where=where, height=height)
    write_json_atomic(Path(path).with_suffix(".json"), {
        "scenes": [global_scene.name, local_scene.name], "method": "reduced",
        "time_s": time, "height_m": height,
        "largest_displacement_over_height": moved,
        "local_vs_global_over_height": by_region,
        "local_vs_global_max_m": float(distance.max()),
        "local_vs_global_max_where": where,
        "closest_example": {"global": closest_global, "local": closest_local},
    })
    return Figure6(png, difference, height, moved, by_region,
                   float(distance.max()))


def examples_comparison(scene, pre, output, path: str | Path, *,
                        steps: int | None = None) -> Path:
    """The rest shape, the final frame of the same run without examples (``k_ex = 0``) and
    ``output``'s final frame, side by side (a scene with examples acting on the whole
    object); the numbers (the example influence of
    :mod:`lbshape.pipeline.influence`) go to ``<path stem>.json`` beside the PNG.

    Free bodies and scenes with planes: the contact planes and one camera framing both
    whole runs. A fixed bar along z: the end twist in the captions.

    Raises:
        LbshapeError: no example force in the scene, or a run that stopped.
    """
    method = output.stats.get("method", "reduced")
    influence, none = example_influence(scene, pre, output, method=method, steps=steps)
    final = "undefined" if influence.final is None else f"{influence.final:.2f}"
    frame = " (deformation)" if influence.frame == "body" else ""
    names = [example_caption(k, pose) for k, pose in enumerate(scene.examples.poses)]
    runs = [(f"{scene.name}: no examples ({method})", none),
            (f"examples ({method}), influence{frame} {final}\n"
             f"visible change {100 * influence.visible_change:.1f} %, "
             f"{closest_caption(influence.closest_example, range(len(names)))}", output)]
    shown = [(f"{names[k]} (on object)", pre.examples.rest_points(k))
             for k in range(len(pre.shape.example_names))]
    extent = np.ptp(pre.mesh.points, axis=0)
    bar = not scene.is_free and extent[2] >= 2.5 * max(extent[0], extent[1])
    free = {"fixed_camera": True, "zoom": TRAJECTORY_ZOOM} if scene.is_free else {}
    png = comparison_figure(pre, runs, path, twist=bar, planes=scene_planes(scene),
                            examples=shown, **free)
    write_json_atomic(Path(path).with_suffix(".json"), {
        "scene": scene.name, "method": method, "steps": output.stats["steps"],
        "time_s": float(output.times[-1]), "panels": ["rest", *(c for c, _ in runs)],
        **influence.stats(),
    })
    return png


def render_scene(scene, out: str | Path, *, steps: int | None = None, method: str = "reduced",
                 frames: int = 4, progress: bool = False) -> RenderedScene:
    """Every picture of one scene into ``out`` (see the module docstring).

    Writes ``simulation.png`` (``method``'s run; a run that stopped is drawn up to its
    stop as ``simulation-STOPPED.png`` instead, labelled so, and an earlier
    ``simulation.png`` is removed; a free body's frames share one camera framing its
    whole trajectory, and the scene's contact planes are drawn), ``eigenfunctions.png``
    and, with examples, ``examples_on_object.png`` and ``examples_raw.png``; with
    examples acting on the whole object ``comparison.png`` (rest | no examples |
    examples, :func:`examples_comparison`, and ``comparison.json``); with local
    examples ``local_regions.png``, ``local_examples.png``, ``local_result.png``
    (there the no-examples comparison) and ``local_examples.json``; plus
    ``summary.json`` (the run's stats and the files).

    Args:
        scene: the scene.
        out: output folder (created).
        steps: steps of the run (default: the scene's).
        method: ``reduced``, ``euclidean`` or ``full``.
        frames: frames in ``simulation.png``.
        progress: precompute progress bars on stderr.
    """
    out = Path(out)
    pre = precompute(scene, progress=progress)
    output = simulate(scene, pre, method=method, steps=steps)
    if output.message:
        log.error("render %s: the %s run stopped: %s", scene.name, method, output.message)
    view = {"planes": scene_planes(scene), "fixed_camera": scene.is_free}
    if output.message:  # no picture of a stopped run may pass for a result
        (out / "simulation.png").unlink(missing_ok=True)
        paths = [simulation_figure(pre, output, out / "simulation-STOPPED.png", frames=frames,
                                   method=f"STOPPED {output.stats.get('method', '')}", **view)]
    else:
        (out / "simulation-STOPPED.png").unlink(missing_ok=True)
        paths = [simulation_figure(pre, output, out / "simulation.png", frames=frames, **view)]
    paths.append(eigenfunctions_figure(scene, pre, out / "eigenfunctions.png"))
    if pre.has_examples:
        paths.extend(examples_figures(scene, pre, out))
        if not output.message and has_example_force(scene, pre):
            paths.append(examples_comparison(scene, pre, output, out / "comparison.png",
                                             steps=steps))
    if pre.has_local_examples:
        paths.extend(local_examples_figures(scene, pre, output, out)[:3])
    if pre.has_examples and scene.is_free:
        runs = figure5(scene, out / "runs_by_example.png", steps=steps, progress=progress)
        paths += [runs.path, runs.shapes]
    summary = write_json_atomic(out / "summary.json", {
        "scene": scene.name, "simulation": output.stats, "message": output.message,
        "pictures": [p.name for p in paths],
    })
    return RenderedScene(scene.name, tuple(paths), summary, output.message)
