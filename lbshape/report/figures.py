"""Scene-level pictures of runs it is given, composed from :mod:`lbshape.report.render`.

* :func:`simulation_figure` — a few frames of a run side by side, coloured by the
  displacement magnitude (free bodies: one fixed camera over the whole trajectory and
  the scene's contact planes as translucent rectangles);
* :func:`examples_figures` — the examples reconstructed on the object's mesh (what
  the method sees) and the raw example meshes posed (what the user gave);
* :func:`eigenfunctions_figure` — the object's LB eigenfunctions on its interior;
* :func:`local_pictures` / :func:`local_result_figure` — scenes with local examples:
  the regions, each example as the regions it guides see it, and the final frame
  without and with the examples;
* :func:`comparison_figure` / :func:`comparison_animation` — several runs of one
  scene side by side (e.g. no examples, examples reduced, full reference): the
  final frames as a PNG, the whole runs as a GIF, with the end twist in the captions;
* :func:`figure5_pictures` — the paper's Figures 4 and 5 from a free body's runs with
  no example and with each example alone;
* :func:`figure6_pictures` — the paper's Figure 6 from its runs' final frames.

The runs behind them (and the JSON numbers beside each composite picture) are
:mod:`lbshape.studies.figures`; nothing here precomputes or simulates. Nothing here
imports pyvista; the pictures are drawn by :mod:`lbshape.report.render`.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from lbshape.analysis.free_body import body_deformations
from lbshape.analysis.influence import REST
from lbshape.analysis.twist import end_twist_degrees
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.pipeline.meshes import example_mesh
from lbshape.report.render import (
    render_animation,
    render_eigenfunctions,
    render_shape_grid,
    render_shapes,
)
from lbshape.shapespace.local_driver import local_example_shape
from lbshape.spectral.spectrum import lb_spectrum

log = logging.getLogger(__name__)

#: zoom of a fixed camera framing a whole trajectory: its bounding sphere, which the
#: camera fits, leaves a wide margin around the trajectory's box
TRAJECTORY_ZOOM = 1.2
#: Figure 6's camera direction: the teddy's left side (+x), a little from the front
#: (−y) and above, so the drag (+z) and the limbs' curl lie nearly in the picture
FIGURE6_VIEW: tuple[float, float, float] = (1.0, -0.35, 0.15)


def deformed(pre, u: np.ndarray):
    """The object's mesh displaced by u (n, 3) or (3n,) (m)."""
    return pre.mesh.with_points(pre.mesh.points + np.asarray(u).reshape(-1, 3))


def trajectory_points(pre, outputs) -> np.ndarray:
    """(p, 3) the rest shape and every sampled frame of the runs ``outputs``: what a
    fixed camera frames and contact planes are sized to."""
    rest = pre.mesh.points
    frames = [rest[None] + np.asarray(o.displacements).reshape(-1, *rest.shape)
              for o in outputs]
    return np.vstack([rest, *(f.reshape(-1, 3) for f in frames)])


def simulation_figure(pre, output, path: str | Path, *, frames: int = 4,
                      method: str | None = None, planes=(), fixed_camera: bool = False
                      ) -> Path:
    """A few frames of a run side by side, coloured by |u| (m), the last frame included.

    Args:
        pre: the scene's :class:`~lbshape.pipeline.precomputed.Precomputed` (rest mesh).
        output: a :class:`~lbshape.pipeline.simulate.SimulationOutput`
            (``displacements (k, n, 3)``, ``times (k,)``).
        path: output PNG.
        frames: how many frames (evenly spaced after t = 0).
        method: caption prefix (default: the run's method).
        planes: (point, normal) contact planes, drawn as translucent rectangles sized to
            the whole trajectory (:func:`lbshape.report.render.scene_planes`).
        fixed_camera: one camera for every panel framing the whole trajectory (a free
            body moves across the picture) instead of one framing the first panel's
            shape; implied by ``planes``.
    """
    count = len(output.times)
    if count < 2:
        raise LbshapeError("the run has no frame after the initial state to draw")
    if frames < 1:
        raise LbshapeError(f"frames must be >= 1, got {frames}")
    picks = np.unique(np.linspace(0, count - 1, frames + 1).round().astype(int)[1:])
    method = method or output.stats.get("method", "")
    meshes = [deformed(pre, output.displacements[i]) for i in picks]
    labels = [f"{method} t={output.times[i]:.3f} s" for i in picks]
    values = [np.linalg.norm(output.displacements[i], axis=1) for i in picks]
    extent = trajectory_points(pre, [output]) if fixed_camera or len(planes) else None
    wide = {} if extent is None else {"zoom": TRAJECTORY_ZOOM,
                                      "window_size": (460 * len(meshes), 440)}
    return render_shapes(meshes, labels, path, scalars=values, planes=planes, extent=extent,
                         **wide)


def example_caption(index: int, pose) -> str:
    """``example k: SOURCE POSE p=v …`` for an :class:`~lbshape.scene.schema.ExamplePose`
    (k from 0, as the scene's ``[[regions]]`` number the examples)."""
    source = pose.source.label
    words = [f"example {index}: {source}"]
    if pose.pose is not None:
        words.append(pose.pose)
        words += [f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
                  for k, v in pose.parameters.items() if k in ("angle", "amplitude")]
    if pose.parts:
        words.append(f"{len(pose.parts)} parts posed")
    return " ".join(words)


def examples_figures(scene, pre, out_dir: str | Path) -> tuple[Path, Path]:
    """``examples_on_object.png`` and ``examples_raw.png`` in ``out_dir``.

    The first shows the object at rest and each example reconstructed on the
    object's mesh from its LB coefficients (``pre.examples.rest_points(k)``); the
    second the example meshes as given, posed.
    """
    if not pre.has_examples or scene.examples is None:
        raise LbshapeError(f"scene {scene.name} has no examples to draw")
    out_dir = Path(out_dir)
    count = len(pre.shape.example_names)
    captions = [example_caption(k, pose) for k, pose in enumerate(scene.examples.poses)]
    if len(captions) != count:
        raise LbshapeError(f"scene {scene.name} has {len(captions)} examples, its precompute "
                           f"{count}")
    reconstructed = [pre.mesh.with_points(pre.examples.rest_points(k)) for k in range(count)]
    on_object = render_shapes(
        [pre.mesh, *reconstructed],
        ["object (rest)", *(f"{caption}, on object (m={pre.shape.eigenvalues.size})"
                            for caption in captions)],
        out_dir / "examples_on_object.png",
        scalars=[None, *(np.linalg.norm(pre.examples.rest_points(k) - pre.mesh.points, axis=1)
                         for k in range(count))],
        scalar_name="|x_k - X| (m)",
    )
    raw = [example_mesh(pose) for pose in scene.examples.poses]
    raw_path = render_shapes(
        raw, [f"{caption} ({mesh.n_vertices} vertices)" for caption, mesh in
              zip(captions, raw, strict=True)],
        out_dir / "examples_raw.png",
    )
    return on_object, raw_path


def _region_labels(pre) -> np.ndarray:
    """(n,) region number per vertex (1, 2, …; 0 outside every region)."""
    labels = np.zeros(pre.mesh.n_vertices)
    for number, region in enumerate(pre.local.regions, start=1):
        labels[region.vertices] = number
    return labels


def view_vector_of(mesh) -> tuple[float, float, float]:
    """A camera direction: mostly along the thin axis of a flat object, else oblique."""
    extent = np.ptp(mesh.points, axis=0)
    thin = int(np.argmin(extent))
    if extent[thin] >= 0.3 * extent.max():
        return (1.0, -1.0, 0.5)
    view = np.array([0.35, -0.6, 0.35])
    view[thin] = 1.0
    return tuple(float(v) for v in view)


def local_pictures(scene, pre, out_dir: str | Path) -> tuple[Path, Path, tuple]:
    """``local_regions.png`` and ``local_examples.png`` of a scene with local examples.

    The regions picture colours the object at rest by region; the examples picture
    shows the rest shape and each example as the regions it guides see it
    (reconstructed on the object's mesh from the region's m coefficients), coloured
    by the example's displacement, the rest shape as a faint wireframe in every panel.

    Returns:
        ``(regions PNG, examples PNG, the camera direction used)``.
    """
    out_dir = Path(out_dir)
    labels = _region_labels(pre)
    names = ", ".join(f"{i}={reg.name}" for i, reg in enumerate(pre.local.regions, start=1))
    shapes, captions = [], []
    for index, pose in enumerate(scene.examples.poses):
        u = local_example_shape(pre.mesh, pre.local, index)
        if u is not None:
            users = [reg.name for reg in pre.local.regions if index in reg.examples]
            shapes.append(u)
            captions.append(f"{example_caption(index, pose)} -> {', '.join(users)}")
    view = view_vector_of(pre.mesh)
    regions_png = render_shapes(
        [pre.mesh], [f"{scene.name}: regions ({names}; 0 = none)"],
        out_dir / "local_regions.png", scalars=[labels], scalar_name="region",
        window_size=(900, 640), view_vector=view, clim=(0.0, float(labels.max())))
    examples_png = render_shapes(
        [pre.mesh, *(deformed(pre, u) for u in shapes)],
        ["rest", *captions], out_dir / "local_examples.png",
        scalars=[None, *(np.linalg.norm(u, axis=1) for u in shapes)],
        scalar_name="|x_k - X| (m)", window_size=(480 * (len(shapes) + 1), 560),
        view_vector=view, ghost=pre.mesh)
    return regions_png, examples_png, view


def local_result_figure(pre, output, none, effect, path: str | Path, *, method: str,
                        view) -> Path:
    """``local_result.png``: the rest shape, the examples on their regions, the final frame
    of the run without examples (``none``) and of ``output``, coloured by |u|; ``effect``
    is the runs' :class:`~lbshape.pipeline.influence.Influence` (its captions)."""
    u_none, u_ex = none.displacements[-1], output.displacements[-1]
    t = output.times[-1]
    strongest = [int(region.examples[0]) for region in pre.local.regions]
    closest = ", ".join(f"{name} {'rest' if k == REST else k}"
                        for name, k in effect.closest_example.items())
    return render_shapes(
        [pre.mesh, deformed(pre, local_example_shape(pre.mesh, pre.local, strongest)),
         deformed(pre, u_none), deformed(pre, u_ex)],
        ["rest", f"examples {sorted(set(strongest))} on their regions",
         f"no examples ({method}) t={t:.2f} s",
         f"local examples ({method}) t={t:.2f} s, influence {effect.final:.2f}\n"
         f"visible change {100 * effect.visible_change:.1f} %\nclosest: {closest}"],
        path,
        scalars=[None, None, np.linalg.norm(u_none, axis=1), np.linalg.norm(u_ex, axis=1)],
        window_size=(1800, 640), view_vector=view, ghost=pre.mesh)


def eigenfunctions_figure(scene, pre, path: str | Path, *, count: int = 4) -> Path:
    """The object's first ``count`` LB eigenfunctions on a cut through its interior.

    Uses the precomputed spectrum, or computes ``scene.reduced.m`` pairs for a
    scene without examples.
    """
    if pre.shape is not None:
        values, vectors = pre.shape.eigenvalues, pre.shape.eigenvectors
    else:
        spectrum = lb_spectrum(pre.mesh, max(count, scene.reduced.m))
        values, vectors = spectrum.eigenvalues, spectrum.eigenvectors
    indices = tuple(range(min(count, values.size)))
    return render_eigenfunctions(pre.mesh, vectors, values, path, indices=indices,
                                 window_size=(400 * len(indices), 500),
                                 title=f"{scene.name}: LB eigenfunctions")


def closest_caption(closest, names: Sequence) -> str:
    """``closest: rest`` / ``closest: arc`` (a name) / ``closest: example 1`` (an index)
    for :func:`closest_example`'s answer, ``names[k]`` naming example k."""
    if closest == REST:
        return "closest: rest"
    name = names[int(closest)]
    return f"closest: example {name}" if isinstance(name, int | np.integer) else \
        f"closest: {name}"


def figure5_pictures(every, runs, example_names, notes, path: str | Path, *, frames: int,
                     planes) -> tuple[Path, Path]:
    """Figure 5's pictures from its finished runs.

    Row k starts with example k reconstructed on the object (grey; the first row: the
    rest shape), then ``frames`` times of the run, coloured by the body-frame
    deformation (best rigid fit removed) on one colour range, under one fixed camera,
    with the contact planes; ``<path stem>_shapes.png`` is the close-up
    (:func:`_figure5_shapes`).

    Args:
        every: the precompute with all the scene's examples (rest mesh, examples on it).
        runs: ``(name, pre, output)`` per run, the first without examples, run k with
            example k − 1 alone.
        example_names: the scene's examples' names.
        notes: per run, what its last caption ends with (closest shape, visible change).
        path: the grid's PNG.
        frames: times per run.
        planes: (point, normal) contact planes.

    Returns:
        ``(grid PNG, close-up PNG)``.
    """
    scalar_mass = mass_matrix(every.mesh, every.material.density)[0::3, 0::3]
    rest = every.mesh.points
    rows, labels, scalars, bodies, endings = [], [], [], [], []
    for index, ((name, pre, output), note) in enumerate(zip(runs, notes, strict=True)):
        count = len(output.times)
        picks = np.unique(np.linspace(0, count - 1, frames + 1).round().astype(int)[1:])
        shown = rest if index == 0 else every.examples.rest_points(index - 1)
        picked = body_deformations(scalar_mass, rest, np.asarray(output.displacements)[picks])
        rows.append([every.mesh.with_points(shown),
                     *(deformed(pre, output.displacements[i]) for i in picks)])
        captions = [f"{name} t={output.times[i]:.2f} s" for i in picks]
        captions[-1] += f"\n{note}"
        endings.append(f"t={output.times[picks[-1]]:.2f} s, {note}")
        labels.append(["rest shape" if index == 0 else f"example: {example_names[index - 1]}",
                       *captions])
        scalars.append([None, *np.linalg.norm(picked, axis=2)])
        bodies.append(picked[-1])
    path = render_shape_grid(rows, labels, path, scalars=scalars, planes=planes,
                             view_vector=(0.3, -1.0, 0.35), zoom=1.1,
                             scalar_name="deformation (m)",
                             extent=trajectory_points(every, [run[2] for run in runs]))
    shapes = _figure5_shapes(every, [row[0] for row in rows], [row[0] for row in labels],
                             [f"{name}: final shape (body frame)\n{ending}"
                              for (name, _, _), ending in zip(runs, endings, strict=True)],
                             bodies, Path(path))
    return Path(path), shapes


def _figure5_shapes(every, examples, example_labels, run_labels, bodies,
                    path: Path) -> Path:
    """Figure 5's close-up, ``<path stem>_shapes.png``: per run its example on the
    object (or the rest shape) and its final body-frame shape ``X + d`` (d (n, 3) m,
    best rigid fit removed), one camera, the rest shape as a wireframe."""
    rest = every.mesh.points
    meshes, captions, scalars = [], [], []
    for example, example_label, run_label, body in zip(
            examples, example_labels, run_labels, bodies, strict=True):
        meshes += [example, every.mesh.with_points(rest + body)]
        captions += [example_label, run_label]
        scalars += [None, np.linalg.norm(body, axis=1)]
    return render_shapes(meshes, captions, path.with_name(f"{path.stem}_shapes.png"),
                         scalars=scalars, scalar_name="deformation (m)", ghost=every.mesh,
                         window_size=(330 * len(meshes), 420),
                         view_vector=(0.3, -1.0, 0.35))


def _twist_caption(pre, u: np.ndarray) -> str:
    """`twist X deg` of the bar's free end for bar-like objects, '' otherwise."""
    try:
        return f"end twist {end_twist_degrees(pre.mesh.points, u):.0f} deg"
    except LbshapeError:
        return ""


def comparison_figure(pre, runs: Sequence[tuple[str, object]], path: str | Path, *,
                      frame: int = -1, twist: bool = False,
                      view_vector: tuple[float, float, float] = (1.0, -1.0, 0.5),
                      view_up: tuple[float, float, float] | None = None,
                      zoom: float = 1.0, planes=(), fixed_camera: bool = False,
                      examples: Sequence[tuple[str, np.ndarray]] = ()) -> Path:
    """One frame of several runs of a scene side by side, after the rest shape.

    Args:
        pre: the scene's precompute (rest mesh).
        runs: ``(caption, SimulationOutput)`` pairs sampled at the same times.
        path: output PNG.
        frame: which sample (default: the last).
        twist: add the twist of the end section (for a bar along z) to the captions.
        view_vector: direction from the object to the camera; ``view_up`` its up
            direction and ``zoom`` a zoom factor.
        planes: (point, normal) contact planes drawn as translucent rectangles sized to
            the runs' whole trajectories.
        fixed_camera: one camera framing the runs' whole trajectories (free bodies);
            implied by ``planes``.
        examples: ``(caption, points (n, 3))`` shapes drawn plain grey after the rest
            shape (e.g. the examples reconstructed on the object), so that the runs can
            be compared with them.

    Each panel shows the rest shape as a faint wireframe and is coloured by |u| on
    one shared scale; its caption gives the time (and the twist).
    """
    if not runs:
        raise LbshapeError("no runs to compare")
    finals = [np.asarray(output.displacements[frame]) for _, output in runs]
    labels = ["rest"]
    for (caption, output), u in zip(runs, finals, strict=True):
        words = _twist_caption(pre, u) if twist else ""
        labels.append(f"{caption}\nt = {output.times[frame]:.2f} s" + (f", {words}" if words
                                                                         else ""))
    labels[1:1] = [caption for caption, _ in examples]
    meshes = [pre.mesh, *(pre.mesh.with_points(points) for _, points in examples),
              *(deformed(pre, u) for u in finals)]
    scalars = [None, *(None for _ in examples), *(np.linalg.norm(u, axis=1) for u in finals)]
    extent = (trajectory_points(pre, [output for _, output in runs])
              if fixed_camera or len(planes) else None)
    size = (330 * len(meshes), 560) if extent is None else (460 * len(meshes), 440)
    return render_shapes(meshes, labels, path, scalars=scalars, ghost=pre.mesh,
                         scalar_name="displacement (m)", window_size=size,
                         view_vector=view_vector, view_up=view_up, zoom=zoom, planes=planes,
                         extent=extent)


def comparison_animation(pre, runs: Sequence[tuple[str, object]], path: str | Path, *,
                         frames: int = 40, fps: float = 12.0, twist: bool = False) -> Path:
    """A GIF of several runs of a scene side by side (same sample times), ``frames`` frames;
    with ``twist`` each panel's caption follows the twist of a bar's end section."""
    if not runs:
        raise LbshapeError("no runs to animate")
    times = np.asarray(runs[0][1].times)
    for caption, output in runs:
        if len(output.times) != len(times) or not np.allclose(output.times, times):
            raise LbshapeError(f"run '{caption}' is sampled at other times than the first run")
    picks = np.unique(np.linspace(0, len(times) - 1, max(2, frames)).round().astype(int))
    displacements = [np.asarray(output.displacements)[picks] for _, output in runs]
    notes = None
    if twist:
        notes = [[_twist_caption(pre, u[f]) for u in displacements] for f in range(picks.size)]
    return render_animation(pre.mesh, displacements, [caption for caption, _ in runs], path,
                            times=times[picks], scalar_name="displacement (m)", fps=fps,
                            notes=notes, window_size=(280 * len(runs), 470))


def figure6_pictures(pre_global, pre_local, finals: dict, path: str | Path, *, time: float,
                     moved: dict, closest_global: str, closest_local: dict,
                     by_region: dict, where: str, height: float) -> tuple[Path, Path]:
    """Figure 6's pictures from its runs' final frames.

    Args:
        pre_global, pre_local: the two scenes' precomputes (one mesh).
        finals: run name (``no examples``, ``global``, ``local``) -> final (n, 3) displacement (m).
        path: the PNG (rest | the runs, coloured by |u|, the rest shape as a wireframe);
            ``<path stem>_difference.png``: the local run coloured by its distance to the
            global one, drawn as a wireframe.
        time: the runs' last time (s).
        moved: per run, per region, the largest displacement over ``height``.
        closest_global: the global run's closest-shape caption; closest_local: per
            region, the shape the local run ends closest to.
        by_region: per region, the largest local-to-global distance over ``height``.
        where: the region of the largest distance.
        height: the object's extent along z (m).

    Returns:
        ``(PNG, difference PNG)``.
    """
    a = pre_global.mesh
    distance = np.linalg.norm(finals["local"] - finals["global"], axis=1)
    view = {"view_vector": FIGURE6_VIEW, "view_up": (0.0, 0.0, 1.0)}
    lifts = {name: max(values.values()) for name, values in moved.items()}
    labels = ["rest", *(f"{name} (reduced) t={time:.2f} s\nlargest displacement "
                        f"{100 * lifts[name]:.1f} % of the height" for name in finals)]
    labels[2] += f"\n{closest_global}"
    labels[3] += "\nclosest: " + ", ".join(f"{region} {k}"
                                          for region, k in closest_local.items())
    png = render_shapes([a, *(deformed(pre_global, u) for u in finals.values())], labels,
                        path, scalars=[None, *(np.linalg.norm(u, axis=1)
                                               for u in finals.values())],
                        ghost=a, scalar_name="displacement (m)", window_size=(1800, 600),
                        **view)
    limbs = ", ".join(f"{region} {100 * value:.1f} %" for region, value in by_region.items())
    difference = render_shapes(
        [deformed(pre_local, finals["local"])],
        [f"local examples (solid) against global examples (wireframe)\n"
         f"largest distance {100 * distance.max():.1f} cm ({where}) = "
         f"{100 * distance.max() / height:.1f} % of the height\nper region: {limbs}"],
        Path(path).with_name(f"{Path(path).stem}_difference.png"), scalars=[distance],
        scalar_name="distance local to global (m)",
        ghost=deformed(pre_global, finals["global"]), window_size=(900, 640), **view)
    return Path(png), Path(difference)
