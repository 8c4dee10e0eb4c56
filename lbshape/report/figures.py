"""Scene-level pictures composed from :mod:`lbshape.report.render` (``lbshape render``).

* :func:`simulation_figure` — a few frames of a run side by side, coloured by the
  displacement magnitude;
* :func:`examples_figures` — the examples reconstructed on the object's mesh (what
  the method sees) and the raw example meshes posed (what the user gave);
* :func:`eigenfunctions_figure` — the object's LB eigenfunctions on its interior;
* :func:`figure3` — the paper's Figure 3: rest; no examples, same-topology examples
  and other-topology examples in full space; other-topology examples reduced — the
  final frame of each;
* :func:`render_scene` — all of the above that a scene supports, into one folder.

Numbers behind each composite picture go to a JSON file next to it. Nothing here
imports pyvista; the pictures are drawn by :mod:`lbshape.report.render`.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.io.atomic import write_json_atomic
from lbshape.io.paths import RESULTS_DIR
from lbshape.pipeline.meshes import example_mesh
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import simulate
from lbshape.report.render import render_eigenfunctions, render_shapes
from lbshape.spectral.spectrum import lb_spectrum

log = logging.getLogger(__name__)

#: repository-relative default output root (one folder per scene)
DEFAULT_OUT = RESULTS_DIR / "figures"
#: built-in scenes for the Figure 3 comparison: (same-topology, other-topology examples)
FIGURE3_SCENES: tuple[str, str] = ("bar-cuboid", "bar-cylinder")
#: steps of the Figure 3 runs (0.4 s at dt = 1 ms: the 0.3 s torque ramp is over)
FIGURE3_STEPS = 400


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


def _deformed(pre, u: np.ndarray):
    return pre.mesh.with_points(pre.mesh.points + np.asarray(u).reshape(-1, 3))


def simulation_figure(pre, output, path: str | Path, *, frames: int = 4,
                      method: str | None = None) -> Path:
    """A few frames of a run side by side, coloured by |u| (m), the last frame included.

    Args:
        pre: the scene's :class:`~lbshape.pipeline.precompute.Precomputed` (rest mesh).
        output: a :class:`~lbshape.pipeline.simulate.SimulationOutput`
            (``displacements (k, n, 3)``, ``times (k,)``).
        path: output PNG.
        frames: how many frames (evenly spaced after t = 0).
        method: caption prefix (default: the run's method).
    """
    count = len(output.times)
    if count < 2:
        raise LbshapeError("the run has no frame after the initial state to draw")
    if frames < 1:
        raise LbshapeError(f"frames must be >= 1, got {frames}")
    picks = np.unique(np.linspace(0, count - 1, frames + 1).round().astype(int)[1:])
    method = method or output.stats.get("method", "")
    meshes = [_deformed(pre, output.displacements[i]) for i in picks]
    labels = [f"{method} t={output.times[i]:.3f} s" for i in picks]
    values = [np.linalg.norm(output.displacements[i], axis=1) for i in picks]
    return render_shapes(meshes, labels, path, scalars=values)


def example_caption(index: int, pose) -> str:
    """``example k: SOURCE POSE p=v …`` for an :class:`~lbshape.scene.schema.ExamplePose`."""
    source = pose.source.shape or Path(pose.source.mesh_file).name
    words = [f"example {index + 1}: {source}"]
    if pose.pose is not None:
        words.append(pose.pose)
        words += [f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
                  for k, v in pose.parameters.items() if k in ("angle", "amplitude")]
    return " ".join(words)


def examples_figures(scene, pre, out_dir: str | Path) -> tuple[Path, Path]:
    """``examples_on_object.png`` and ``examples_raw.png`` in ``out_dir``.

    The first shows the object at rest and each example reconstructed on the
    object's mesh from its LB coefficients (``pre.example_rest_points(k)``); the
    second the example meshes as given, posed.
    """
    if not pre.has_examples or scene.examples is None:
        raise LbshapeError(f"scene {scene.name} has no examples to draw")
    out_dir = Path(out_dir)
    count = len(pre.example_names)
    captions = [example_caption(k, pose) for k, pose in enumerate(scene.examples.poses)]
    if len(captions) != count:
        raise LbshapeError(f"scene {scene.name} has {len(captions)} examples, its precompute "
                           f"{count}")
    reconstructed = [pre.mesh.with_points(pre.example_rest_points(k)) for k in range(count)]
    on_object = render_shapes(
        [pre.mesh, *reconstructed],
        ["object (rest)", *(f"{caption}, on object (m={pre.eigenvalues.size})"
                            for caption in captions)],
        out_dir / "examples_on_object.png",
        scalars=[None, *(np.linalg.norm(pre.example_rest_points(k) - pre.mesh.points, axis=1)
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


def eigenfunctions_figure(scene, pre, path: str | Path, *, count: int = 4) -> Path:
    """The object's first ``count`` LB eigenfunctions on a cut through its interior.

    Uses the precomputed spectrum, or computes ``scene.reduced.m`` pairs for a
    scene without examples.
    """
    if pre.eigenvectors is not None:
        values, vectors = pre.eigenvalues, pre.eigenvectors
    else:
        spectrum = lb_spectrum(pre.mesh, max(count, scene.reduced.m))
        values, vectors = spectrum.eigenvalues, spectrum.eigenvectors
    indices = tuple(range(min(count, values.size)))
    return render_eigenfunctions(pre.mesh, vectors, values, path, indices=indices,
                                 window_size=(400 * len(indices), 500),
                                 title=f"{scene.name}: LB eigenfunctions")


def _examples_label(scene) -> str:
    source = scene.examples.poses[0].source
    return source.shape or Path(source.mesh_file).stem


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
    pre_same = precompute(same_topology, progress=progress)
    pre_other = precompute(other_topology, progress=progress)
    a, b = pre_same.mesh, pre_other.mesh
    if a.points.shape != b.points.shape or not np.allclose(a.points, b.points) \
            or not np.array_equal(a.tets, b.tets):
        raise LbshapeError(f"Figure 3 needs one object: {same_topology.name} and "
                           f"{other_topology.name} simulate different meshes")
    no_examples = dataclasses.replace(
        same_topology, examples=dataclasses.replace(same_topology.examples, stiffness=0.0))
    same_label, other_label = _examples_label(same_topology), _examples_label(other_topology)
    runs = [
        ("no examples (full)", no_examples, pre_same, "full"),
        (f"{same_label} examples (full)", same_topology, pre_same, "full"),
        (f"{other_label} examples (full)", other_topology, pre_other, "full"),
        (f"{other_label} examples (reduced)", other_topology, pre_other, "reduced"),
    ]
    finals, labels = [], ["rest"]
    for label, scene, pre, method in runs:
        output = simulate(scene, pre, method=method, steps=steps)
        if output.message:
            raise LbshapeError(f"Figure 3 run '{label}' stopped: {output.message}")
        finals.append(output.displacements[-1])
        labels.append(f"{label} t={output.times[-1]:.2f} s")
        log.info("figure 3: %s done", label)
    mass = mass_matrix(a, pre_same.material.density)
    flat_full, flat_reduced = finals[2].reshape(-1), finals[3].reshape(-1)
    diff = flat_reduced - flat_full
    reference = float(np.sqrt(flat_full @ (mass @ flat_full)))
    relative = float(np.sqrt(diff @ (mass @ diff))) / reference if reference > 0 else float("nan")
    meshes = [a, *(_deformed(pre_same, u) for u in finals)]
    scalars = [None, *(np.linalg.norm(u, axis=1) for u in finals)]
    png = render_shapes(meshes, labels, path, scalars=scalars)
    maxima = (0.0, *(float(np.linalg.norm(u, axis=1).max()) for u in finals))
    result = Figure3(png, tuple(labels), maxima, relative, int(steps))
    write_json_atomic(Path(path).with_suffix(".json"), {
        "scenes": [same_topology.name, other_topology.name], "steps": int(steps),
        "dt": same_topology.simulation.dt, "panels": list(labels),
        "final_max_displacement_m": list(maxima),
        "reduced_vs_full_final_relative_m_norm": relative,
    })
    return result


def render_scene(scene, out: str | Path, *, steps: int | None = None, method: str = "reduced",
                 frames: int = 4, progress: bool = False) -> RenderedScene:
    """Every picture of one scene into ``out`` (see the module docstring).

    Writes ``simulation.png`` (``method``'s run), ``eigenfunctions.png`` and, with
    examples, ``examples_on_object.png`` and ``examples_raw.png``; plus
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
    paths = [simulation_figure(pre, output, out / "simulation.png", frames=frames)]
    paths.append(eigenfunctions_figure(scene, pre, out / "eigenfunctions.png"))
    if pre.has_examples:
        paths.extend(examples_figures(scene, pre, out))
    summary = write_json_atomic(out / "summary.json", {
        "scene": scene.name, "simulation": output.stats, "message": output.message,
        "pictures": [p.name for p in paths],
    })
    return RenderedScene(scene.name, tuple(paths), summary, output.message)
