"""Draw each analytic pose on a bar: ``docs/images/pose_*.png`` (off-screen pyvista).

A 0.2 x 0.2 x 1 m structured bar along z, its rest shape as a grey wireframe, the posed
bar as a surface, for every pose of :data:`lbshape.geometry.poses.POSES` with the
parameters below (the anchor end, ``z = 0``, stays in place).

Usage: ``.venv/bin/python scripts/pose_pictures.py [--out docs/images]``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from lbshape.geometry.poses import POSES, apply_pose
from lbshape.geometry.primitives import structured_box

ROOT = Path(__file__).resolve().parents[1]
#: pose name -> (parameters, caption)
EXAMPLES: dict[str, tuple[dict, str]] = {
    "twist": ({"angle": 1.5708, "axis": "z", "anchor": "min"},
              'twist\nangle = 1.5708 rad, axis = "z", anchor = "min"'),
    "arc": ({"angle": 1.0, "direction": "x", "axis": "z", "anchor": "min"},
            'arc\nangle = 1.0 rad, direction = "x",\naxis = "z", anchor = "min"'),
    "s-bend": ({"amplitude": 0.25, "direction": "x", "axis": "z", "anchor": "min"},
               's-bend\namplitude = 0.25 m, direction = "x",\naxis = "z", anchor = "min"'),
}


def _surface(points: np.ndarray, faces: np.ndarray):
    import pyvista as pv

    cells = np.hstack([np.full((len(faces), 1), 3), faces]).ravel()
    return pv.PolyData(points, cells)


def draw(out: Path) -> list[Path]:
    """Write one PNG per pose into ``out``; returns their paths."""
    import pyvista as pv

    assert set(EXAMPLES) == set(POSES), "a pose without a picture"
    bar = structured_box((0.2, 0.2, 1.0), (4, 4, 16), origin=(-0.1, -0.1, 0.0))
    faces = bar.boundary_faces()
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, (params, caption) in EXAMPLES.items():
        posed = apply_pose(bar, name, **params)
        plotter = pv.Plotter(off_screen=True, window_size=(460, 560))
        plotter.set_background("white")
        plotter.add_mesh(_surface(bar.points, faces), style="wireframe", color="grey",
                         opacity=0.35)
        plotter.add_mesh(_surface(posed.points, faces), color="lightsteelblue",
                         show_edges=True, edge_color="dimgray")
        plotter.add_text(caption, font_size=8, color="black", position="upper_left")
        plotter.add_axes(color="black")
        plotter.camera_position = [(1.6, -2.2, 1.1), (0.05, 0.0, 0.5), (0.0, 0.0, 1.0)]
        path = out / f"pose_{name}.png"
        plotter.screenshot(str(path))
        plotter.close()
        written.append(path)
    return written


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images")
    args = parser.parse_args(argv)
    for path in draw(args.out):
        print(path)


if __name__ == "__main__":
    main()
