"""Off-screen pictures with pyvista (with :mod:`lbshape.live.window`, the on-screen window,
the only modules of lbshape that import it).

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


#: colour and opacity of contact planes (drawn unlit, so the colour is exact)
PLANE_COLOR = "#8c6d46"
PLANE_OPACITY = 0.35
#: a plane's rectangle reaches this fraction of the trajectory's size beyond it
PLANE_MARGIN = 0.15

Planes = Sequence[tuple[np.ndarray, np.ndarray]]


def plane_rectangles(planes: Planes, points: np.ndarray, *,
                     margin: float = PLANE_MARGIN) -> list[np.ndarray]:
    """Finite rectangles of infinite contact planes, sized to what they are drawn with.

    Each rectangle lies in its plane, centred on the plane's point nearest the centre
    of ``points``, and covers the projection of ``points`` on the plane plus ``margin``
    times their bounding-box diagonal on every side.

    Args:
        planes: (point (3,), normal (3,)) pairs (the normal need not be unit).
        points: (p, 3) what the picture shows, e.g. every frame of a trajectory.

    Returns:
        One (4, 3) array of corners per plane, in order around the rectangle.
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    centre = 0.5 * (points.min(axis=0) + points.max(axis=0))
    diagonal = float(np.linalg.norm(np.ptp(points, axis=0))) or 1.0
    rectangles = []
    for point, normal in planes:
        n = np.asarray(normal, dtype=float)
        n = n / np.linalg.norm(n)
        origin = centre - ((centre - np.asarray(point, dtype=float)) @ n) * n
        helper = np.eye(3)[int(np.argmin(np.abs(n)))]
        e1 = np.cross(n, helper)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)
        a, b = (points - origin) @ e1, (points - origin) @ e2
        pad = margin * diagonal
        (a0, a1), (b0, b1) = (a.min() - pad, a.max() + pad), (b.min() - pad, b.max() + pad)
        rectangles.append(np.array([origin + a0 * e1 + b0 * e2, origin + a1 * e1 + b0 * e2,
                                    origin + a1 * e1 + b1 * e2, origin + a0 * e1 + b1 * e2]))
    return rectangles


def scene_planes(scene) -> list[tuple[np.ndarray, np.ndarray]]:
    """The (point, normal) pairs of a scene's contact planes (``[[planes]]``)."""
    return [(np.asarray(p.point, dtype=float), np.asarray(p.normal, dtype=float))
            for p in scene.planes]


def add_rectangles(plotter, pv, rectangles: Sequence[np.ndarray]) -> None:
    """Draw contact planes' rectangles (each (4, 3) corners, :func:`plane_rectangles`) in
    the plotter's current panel, translucent and unlit."""
    for corners in rectangles:
        quad = pv.PolyData(np.asarray(corners, dtype=float), faces=np.array([4, 0, 1, 2, 3]))
        plotter.add_mesh(quad, color=PLANE_COLOR, opacity=PLANE_OPACITY, lighting=False,
                         show_edges=True, edge_color="#5a4630", line_width=1.0)


def bounds_of(points: np.ndarray) -> tuple[float, ...]:
    """(xmin, xmax, ymin, ymax, zmin, zmax) of points (p, 3), as VTK's cameras take them."""
    low, high = points.min(axis=0), points.max(axis=0)
    return (low[0], high[0], low[1], high[1], low[2], high[2])


def set_camera(plotter, view_vector, *, view_up=None, bounds=None, zoom: float = 1.0) -> None:
    """Point the current panel's camera along ``view_vector``; frame ``bounds`` (fixed,
    the same for every panel given them) or else what the panel shows."""
    plotter.view_vector(view_vector, viewup=view_up)
    if bounds is not None:
        plotter.reset_camera(bounds=bounds)
    if zoom != 1.0:
        plotter.camera.zoom(zoom)


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
    planes: Planes = (),
    extent: np.ndarray | None = None,
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
        planes: (point, normal) contact planes, drawn in every panel as translucent
            rectangles sized to ``extent`` (:func:`plane_rectangles`).
        extent: (p, 3) points (e.g. every frame of a free body's trajectory): every
            panel gets one fixed camera framing them and the planes; default with
            planes: the panels' shapes; without either, the first panel's framing.
    """
    pv = _pyvista()
    k = len(meshes)
    window_size = window_size or (380 * k, 520)
    if extent is None and len(planes):
        extent = np.vstack([m.points for m in meshes])
    rectangles = plane_rectangles(planes, extent) if len(planes) else []
    bounds = None
    if extent is not None:
        bounds = bounds_of(np.vstack([np.asarray(extent, dtype=float).reshape(-1, 3),
                                    *rectangles]))
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
        add_rectangles(plotter, pv, rectangles)
        plotter.add_text(label, font_size=10)
        set_camera(plotter, view_vector, view_up=view_up, bounds=bounds, zoom=zoom)
    plotter.link_views()
    return _save(plotter, Path(path))


def render_shape_grid(
    rows: Sequence[Sequence[TetMesh]],
    labels: Sequence[Sequence[str]],
    path: str | Path,
    *,
    scalars: Sequence[Sequence[np.ndarray]] | None = None,
    scalar_name: str = "|u| (m)",
    view_vector: tuple[float, float, float] = (1.0, -1.0, 0.5),
    planes: Planes = (),
    zoom: float = 1.0,
    extent: np.ndarray | None = None,
) -> Path:
    """A grid of solids (rows × columns), one fixed camera, shared colour range.

    Args:
        rows: ``rows[i][j]`` the mesh of panel (i, j).
        labels: captions, same layout.
        path: output PNG.
        scalars: optional per-vertex values (n,), same layout; a None panel is drawn
            plain grey (e.g. an example's shape beside the runs).
        planes: (point (3,), normal (3,)) contact planes, drawn as translucent rectangles
            sized to ``extent`` (:func:`plane_rectangles`).
        zoom: camera zoom factor.
        extent: (p, 3) points every panel's camera frames (default: all panels' shapes).
    """
    pv = _pyvista()
    n_rows, n_cols = len(rows), max(len(r) for r in rows)
    plotter = _plotter(pv, shape=(n_rows, n_cols), window_size=(330 * n_cols, 300 * n_rows),
                       border=False)
    values = [v for row in (scalars or []) for v in row if v is not None]
    clim = (0.0, float(max(np.max(v) for v in values)) or 1.0) if values else None
    if extent is None:
        extent = np.vstack([m.points for row in rows for m in row])
    extent = np.asarray(extent, dtype=float).reshape(-1, 3)
    rectangles = plane_rectangles(planes, extent) if len(planes) else []
    bounds = bounds_of(np.vstack([extent, *rectangles]))
    for i, row in enumerate(rows):
        for j, mesh in enumerate(row):
            plotter.subplot(i, j)
            value = scalars[i][j] if scalars is not None else None
            data = {scalar_name: value} if value is not None else None
            surface = to_grid(mesh, data).extract_surface(algorithm="dataset_surface")
            if value is not None:
                plotter.add_mesh(surface, scalars=scalar_name, cmap="viridis", clim=clim,
                                 show_edges=True, edge_color="#333333", line_width=0.2,
                                 show_scalar_bar=False)
            else:
                plotter.add_mesh(surface, color="#c8d2e0", show_edges=True,
                                 edge_color="#333333", line_width=0.2)
            add_rectangles(plotter, pv, rectangles)
            plotter.add_text(labels[i][j], font_size=8)
            set_camera(plotter, view_vector, bounds=bounds, zoom=zoom)
    if clim is not None:
        plotter.add_text(f"colour: {scalar_name} {clim[0]:.3g} (dark) to {clim[1]:.3g} "
                         "(yellow)", position="lower_right", font_size=7)
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
    planes: Planes = (),
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
        planes: (point, normal) contact planes, drawn in every panel as translucent
            rectangles sized to all frames (:func:`plane_rectangles`).

    Returns:
        (f, height, width, 3) uint8 RGB frames.

    Raises:
        LbshapeError: not one label and one (f, n, 3) array per panel.
    """
    runs = [np.asarray(u, dtype=float) for u in displacements]
    k, count = len(runs), len(times)
    _check_panels(rest, runs, labels, count, notes)
    norms = [np.linalg.norm(u, axis=2) for u in runs]
    if clim is None:
        clim = (0.0, float(max(v.max() for v in norms)) or 1.0)
    moved = np.vstack([rest.points, *((rest.points[None] + u).reshape(-1, 3) for u in runs)])
    rectangles = plane_rectangles(planes, moved) if len(planes) else []
    bounds = bounds_of(np.vstack([moved, *rectangles]))
    width, height = window_size or (360 * k, 420)
    pv = _pyvista()
    plotter = _plotter(pv, shape=(1, k), window_size=(width, height), border=False)
    base = to_grid(rest).extract_surface(algorithm="dataset_surface")
    ids = np.asarray(base.point_data["vtkOriginalPointIds"])
    surfaces = [_animation_panel(plotter, pv, panel, base, norms[panel][0][ids], scalar_name,
                                 clim, ghost, rectangles, view_vector, bounds)
                for panel in range(k)]
    plotter.link_views()
    plotter.subplot(0, k - 1)
    plotter.add_text(f"colour: {scalar_name} {clim[0]:.3g} (dark) to {clim[1]:.3g} (yellow)",
                     position="lower_right", font_size=8)
    try:
        return _record_frames(plotter, surfaces, rest.points[ids], [u[:, ids] for u in runs],
                              [v[:, ids] for v in norms], labels, times, scalar_name=scalar_name,
                              notes=notes, size=(height, width), progress=progress)
    finally:
        plotter.close()


def _record_frames(plotter, surfaces, points: np.ndarray, runs: Sequence[np.ndarray],
                   norms: Sequence[np.ndarray], labels: Sequence[str], times: np.ndarray, *,
                   scalar_name: str, notes, size: tuple[int, int], progress: bool
                   ) -> np.ndarray:
    """Each frame of :func:`animation_frames`: the panels' surfaces (``points`` (p, 3) at
    rest, ``runs`` (f, p, 3) and ``norms`` (f, p) per panel on the surface's points) moved,
    captioned and rendered; (f, height, width, 3) uint8 RGB."""
    from tqdm import tqdm

    height, width = size
    out = np.empty((len(times), height, width, 3), dtype=np.uint8)
    for frame in tqdm(range(len(times)), desc="frames", disable=not progress, file=sys.stderr):
        for panel, surface in enumerate(surfaces):
            surface.points = points + runs[panel][frame]
            surface.point_data[scalar_name] = norms[panel][frame]
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
    return out


def _check_panels(rest: TetMesh, runs: Sequence[np.ndarray], labels: Sequence[str],
                  count: int, notes) -> None:
    """Raise a one-line :class:`LbshapeError` unless there is one label and one
    (count, n, 3) displacement array per panel (and, with ``notes``, count × panels)."""
    k = len(runs)
    if k == 0 or len(labels) != k:
        raise LbshapeError(f"give one label per panel: {k} panels, {len(labels)} labels")
    expected = (count, rest.n_vertices, 3)
    if count == 0 or any(u.shape != expected for u in runs):
        raise LbshapeError(f"each panel needs displacements of shape {expected}, got "
                           f"{[u.shape for u in runs]}")
    if notes is not None and (len(notes) != count or any(len(n) != k for n in notes)):
        raise LbshapeError(f"notes must be {count} frames x {k} panels of captions")


def _animation_panel(plotter, pv, panel: int, base, first_values: np.ndarray, scalar_name: str,
                     clim, ghost: bool, rectangles, view_vector, bounds):
    """Panel ``panel`` of :func:`animation_frames`: a copy of the surface ``base`` coloured
    by ``first_values`` (its vertices' |u| in the first frame), the rest shape as a ghost,
    the planes, and the camera that frames every frame; returns the surface to move."""
    plotter.subplot(0, panel)
    surface = base.copy()
    surface.point_data[scalar_name] = first_values
    plotter.add_mesh(surface, scalars=scalar_name, cmap="viridis", clim=clim, show_edges=True,
                     edge_color="#333333", line_width=0.3, show_scalar_bar=False)
    if ghost:
        plotter.add_mesh(base.copy(), style="wireframe", color="#888888", opacity=0.25,
                         line_width=0.5)
    add_rectangles(plotter, pv, rectangles)
    set_camera(plotter, view_vector, bounds=bounds)  # every frame in view; the camera stays
    return surface


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
    planes: Planes = (),
) -> Path:
    """An animated GIF of several runs of one mesh side by side (one panel per run).

    The frames of :func:`animation_frames` (same arguments; default window 330 per
    panel × 520) written by :func:`lbshape.report.movie.write_gif` (looped, at ``fps``).
    """
    frames = animation_frames(rest, displacements, labels, times, scalar_name=scalar_name,
                              clim=clim, window_size=window_size or (330 * len(labels), 520),
                              view_vector=view_vector, ghost=ghost, notes=notes,
                              planes=planes)
    return write_gif(frames, path, fps=fps).path
