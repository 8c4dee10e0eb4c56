"""Off-screen pictures with pyvista (the only module of lbshape that imports it).

All functions write a PNG atomically and return its path. Rendering is headless:
VTK falls back from X to an off-screen context; its harmless "bad X server
connection" warning is silenced while a plotter is made and used (:func:`quiet_vtk`).
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.io.atomic import write_atomic
from lbshape.report.movie import write_gif

_VTK_TETRA = 10


def _pyvista():
    import pyvista as pv

    pv.OFF_SCREEN = True
    return pv


@contextlib.contextmanager
def quiet_vtk() -> Iterator[None]:
    """VTK's log to stderr at errors only inside the block (restored after it).

    Headless, VTK's X render window logs a warning before it falls back to an
    off-screen context; errors still show.
    """
    from vtkmodules.vtkCommonCore import vtkLogger

    previous = vtkLogger.GetCurrentVerbosityCutoff()
    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_ERROR)
    try:
        yield
    finally:
        vtkLogger.SetStderrVerbosity(previous)


def _plotter(pv, **options):
    """An off-screen ``pyvista.Plotter`` made without the X warning."""
    with quiet_vtk():
        return pv.Plotter(off_screen=True, **options)


def to_grid(mesh: TetMesh, point_data: dict[str, np.ndarray] | None = None):
    """A ``pyvista.UnstructuredGrid`` of the tetrahedra with optional point data (n,) or (n,3)."""
    pv = _pyvista()
    cells = np.hstack([np.full((mesh.n_tets, 1), 4), mesh.tets]).ravel()
    types = np.full(mesh.n_tets, _VTK_TETRA, dtype=np.uint8)
    grid = pv.UnstructuredGrid(cells, types, mesh.points)
    for name, values in (point_data or {}).items():
        grid.point_data[name] = np.asarray(values)
    return grid


def _save(plotter, path: Path) -> Path:
    """Screenshot ``plotter`` to the PNG ``path`` atomically, then close it."""
    try:
        with quiet_vtk():
            return write_atomic(path, lambda tmp: plotter.screenshot(str(tmp)))
    finally:
        plotter.close()


def render_eigenfunctions(
    mesh: TetMesh,
    eigenvectors: np.ndarray,
    eigenvalues: np.ndarray,
    path: str | Path,
    *,
    indices: Sequence[int] = (0, 1, 2, 3),
    clip_normal: tuple[float, float, float] = (0.0, 1.0, 0.0),
    window_size: tuple[int, int] = (1600, 500),
    title: str = "",
) -> Path:
    """Eigenfunctions on the *interior* of a solid (a clip through its centre), one panel each.

    Like the paper's Figure 2: the volumetric eigenfunction is shown on the cut
    face and on the remaining boundary, with a diverging colour map.

    Args:
        mesh: the solid.
        eigenvectors: (n, m) eigenfunctions in input vertex order.
        eigenvalues: (m,) in 1/m².
        path: output PNG.
        indices: which eigenfunctions (0 = first non-constant one).
        clip_normal: normal of the clipping plane through the centroid.
    """
    pv = _pyvista()
    grid = to_grid(mesh)
    centre = mesh.points.mean(axis=0)
    plotter = _plotter(pv, shape=(1, len(indices)), window_size=window_size, border=False)
    for panel, i in enumerate(indices):
        plotter.subplot(0, panel)
        field = eigenvectors[:, i]
        limit = float(np.max(np.abs(field))) or 1.0
        grid.point_data["phi"] = field
        clipped = grid.clip(normal=clip_normal, origin=centre, invert=True)
        plotter.add_mesh(
            clipped,
            scalars="phi",
            cmap="coolwarm",
            clim=(-limit, limit),
            show_scalar_bar=False,
            smooth_shading=False,
        )
        plotter.add_mesh(grid.extract_feature_edges(), color="black", line_width=1, opacity=0.15)
        plotter.add_text(f"phi_{i + 1}  lambda={eigenvalues[i]:.3g}", font_size=10)
        n = np.asarray(clip_normal, dtype=float)
        plotter.view_vector(tuple(1.4 * n + np.array([0.5, 0.3, 0.45])))
        plotter.camera.zoom(1.2)
    if title:
        plotter.subplot(0, 0)
        plotter.add_text(title, position="lower_left", font_size=9)
    return _save(plotter, Path(path))


def render_shapes(
    meshes: Sequence[TetMesh],
    labels: Sequence[str],
    path: str | Path,
    *,
    scalars: Sequence[np.ndarray | None] | None = None,
    scalar_name: str = "|u| (m)",
    window_size: tuple[int, int] | None = None,
    view_vector: tuple[float, float, float] = (1.0, -1.0, 0.5),
    clim: tuple[float, float] | None = None,
    ghost: TetMesh | None = None,
    view_up: tuple[float, float, float] | None = None,
    zoom: float = 1.0,
) -> Path:
    """Several solids side by side (one panel each), sharing one camera direction.

    Args:
        meshes: the shapes to draw (e.g. rest, examples, simulated frames).
        labels: one caption per panel.
        path: output PNG.
        scalars: optional per-vertex (n,) values per panel (e.g. displacement norm).
        clim: colour range shared by all panels (default: the max over panels).
        ghost: a shape drawn as a faint wireframe in every panel (e.g. the rest shape).
        view_up: the camera's up direction (default: pyvista's).
        zoom: camera zoom factor after framing the shape.
    """
    pv = _pyvista()
    k = len(meshes)
    window_size = window_size or (380 * k, 520)
    plotter = _plotter(pv, shape=(1, k), window_size=window_size, border=False)
    scalars = list(scalars) if scalars is not None else [None] * k
    finite = [np.max(s) for s in scalars if s is not None and len(s)]
    if clim is None and finite:
        clim = (0.0, float(max(finite)) or 1.0)
    for panel, (mesh, label, values) in enumerate(zip(meshes, labels, scalars, strict=True)):
        plotter.subplot(0, panel)
        data = {scalar_name: values} if values is not None else None
        surface = to_grid(mesh, data).extract_surface(algorithm="dataset_surface")
        if values is not None:
            # no scalar-bar actor: its label formatting aborts in some VTK builds;
            # the colour range is printed on the last panel instead
            plotter.add_mesh(
                surface, scalars=scalar_name, cmap="viridis", clim=clim, show_edges=True,
                edge_color="#333333", line_width=0.3, show_scalar_bar=False,
            )
            if panel == k - 1:
                plotter.add_text(f"colour: {scalar_name} {clim[0]:.3g} (dark) to "
                                 f"{clim[1]:.3g} (yellow)", position="lower_right", font_size=8)
        else:
            plotter.add_mesh(surface, color="#c8d2e0", show_edges=True, edge_color="#333333",
                             line_width=0.3)
        if ghost is not None and mesh is not ghost:
            plotter.add_mesh(to_grid(ghost).extract_surface(algorithm="dataset_surface"),
                             style="wireframe", color="#888888", opacity=0.25, line_width=0.5)
        plotter.add_text(label, font_size=10)
        plotter.view_vector(view_vector, viewup=view_up)
        if zoom != 1.0:
            plotter.camera.zoom(zoom)
    plotter.link_views()
    return _save(plotter, Path(path))


def animation_frames(
    rest: TetMesh,
    displacements: Sequence[np.ndarray],
    labels: Sequence[str],
    times: np.ndarray,
    *,
    scalar_name: str = "|u| (m)",
    clim: tuple[float, float] | None = None,
    window_size: tuple[int, int] | None = None,
    view_vector: tuple[float, float, float] = (1.0, -1.0, 0.5),
    ghost: bool = False,
    notes: Sequence[Sequence[str]] | None = None,
    progress: bool = False,
) -> np.ndarray:
    """Frames of deforming copies of one mesh side by side (one panel per run), for a movie.

    Each panel shows the surface of ``rest`` moved by its run's displacements,
    coloured by |u| on one range shared by all panels and frames; the camera is fixed
    and frames the union of every frame's bounding box. Write the frames with
    :mod:`lbshape.report.movie`.

    Args:
        rest: the rest mesh (n vertices) all runs displace.
        displacements: one (f, n, 3) array per panel (m), the same f frames each.
        labels: one caption per panel.
        times: (f,) frame times (s), printed on the first panel.
        scalar_name: name of the colour field, |u| of each vertex.
        clim: shared colour range (default: 0 to the largest |u| of any frame).
        window_size: (width, height) in pixels (default: 360 per panel × 420).
        ghost: draw the rest shape as a faint wireframe in every panel.
        notes: optional (f, panels) second caption lines, one per frame and panel.
        progress: a progress bar over the frames on stderr.

    Returns:
        (f, height, width, 3) uint8 RGB frames.

    Raises:
        LbshapeError: not one label and one (f, n, 3) array per panel.
    """
    from tqdm import tqdm

    runs = [np.asarray(u, dtype=float) for u in displacements]
    k, count = len(runs), len(times)
    if k == 0 or len(labels) != k:
        raise LbshapeError(f"give one label per panel: {k} panels, {len(labels)} labels")
    expected = (count, rest.n_vertices, 3)
    if count == 0 or any(u.shape != expected for u in runs):
        raise LbshapeError(f"each panel needs displacements of shape {expected}, got "
                           f"{[u.shape for u in runs]}")
    if notes is not None and (len(notes) != count or any(len(n) != k for n in notes)):
        raise LbshapeError(f"notes must be {count} frames x {k} panels of captions")
    norms = [np.linalg.norm(u, axis=2) for u in runs]
    if clim is None:
        clim = (0.0, float(max(v.max() for v in norms)) or 1.0)
    moved = np.vstack([rest.points, *((rest.points[None] + u).reshape(-1, 3) for u in runs)])
    low, high = moved.min(axis=0), moved.max(axis=0)
    bounds = (low[0], high[0], low[1], high[1], low[2], high[2])
    width, height = window_size or (360 * k, 420)
    pv = _pyvista()
    plotter = _plotter(pv, shape=(1, k), window_size=(width, height), border=False)
    base = to_grid(rest).extract_surface(algorithm="dataset_surface")
    ids = np.asarray(base.point_data["vtkOriginalPointIds"])
    surfaces = []
    for panel in range(k):
        plotter.subplot(0, panel)
        surface = base.copy()
        surface.point_data[scalar_name] = norms[panel][0][ids]
        plotter.add_mesh(surface, scalars=scalar_name, cmap="viridis", clim=clim, show_edges=True,
                         edge_color="#333333", line_width=0.3, show_scalar_bar=False)
        if ghost:
            plotter.add_mesh(base.copy(), style="wireframe", color="#888888", opacity=0.25,
                             line_width=0.5)
        plotter.view_vector(view_vector)
        plotter.reset_camera(bounds=bounds)  # every frame in view; the camera then stays
        surfaces.append(surface)
    plotter.link_views()
    plotter.subplot(0, k - 1)
    plotter.add_text(f"colour: {scalar_name} {clim[0]:.3g} (dark) to {clim[1]:.3g} (yellow)",
                     position="lower_right", font_size=8)
    out = np.empty((count, height, width, 3), dtype=np.uint8)
    try:
        for frame in tqdm(range(count), desc="frames", disable=not progress, file=sys.stderr):
            for panel, surface in enumerate(surfaces):
                surface.points = rest.points[ids] + runs[panel][frame][ids]
                surface.point_data[scalar_name] = norms[panel][frame][ids]
                surface.Modified()
                plotter.subplot(0, panel)
                caption = labels[panel] if notes is None else \
                    f"{labels[panel]}\n{notes[frame][panel]}"
                plotter.add_text(caption, font_size=10, name="caption")
            plotter.subplot(0, 0)
            plotter.add_text(f"t = {times[frame]:.3f} s", position="lower_left", font_size=10,
                             name="time")
            with quiet_vtk():
                plotter.render()
                image = np.asarray(plotter.screenshot(return_img=True))[..., :3]
            out[frame] = image[:height, :width]
    finally:
        plotter.close()
    return out


def render_animation(
    rest: TetMesh,
    displacements: Sequence[np.ndarray],
    labels: Sequence[str],
    path: str | Path,
    *,
    times: np.ndarray,
    scalar_name: str = "|u| (m)",
    clim: tuple[float, float] | None = None,
    fps: float = 12.0,
    window_size: tuple[int, int] | None = None,
    view_vector: tuple[float, float, float] = (1.0, -1.0, 0.5),
    ghost: bool = True,
    notes: Sequence[Sequence[str]] | None = None,
) -> Path:
    """An animated GIF of several runs of one mesh side by side (one panel per run).

    The frames of :func:`animation_frames` (same arguments; default window 330 per
    panel × 520) written by :func:`lbshape.report.movie.write_gif` (looped, at ``fps``).
    """
    frames = animation_frames(rest, displacements, labels, times, scalar_name=scalar_name,
                              clim=clim, window_size=window_size or (330 * len(labels), 520),
                              view_vector=view_vector, ghost=ghost, notes=notes)
    return write_gif(frames, path, fps=fps).path
