"""Off-screen rendering and the demo entry point produce real pictures."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lbshape.geometry.primitives import structured_box


def _png_pixels(path):
    import matplotlib.image

    return matplotlib.image.imread(str(path))


def test_render_eigenfunction_panels(tmp_path):
    from lbshape.report.render import render_eigenfunctions

    mesh = structured_box((1.0, 0.5, 0.5), (6, 3, 3))
    x = mesh.points[:, 0]
    fields = np.column_stack([np.cos(np.pi * x), np.cos(2 * np.pi * x)])
    path = render_eigenfunctions(mesh, fields, np.array([np.pi**2, 4 * np.pi**2]),
                                 tmp_path / "eig.png", indices=(0, 1), window_size=(600, 300))
    image = _png_pixels(path)
    assert image.shape[:2] == (300, 600)
    # the panels are coloured (red and blue of the diverging map), not blank
    rgb = image[..., :3]
    assert ((rgb[..., 0] - rgb[..., 2]) > 0.3).any() and ((rgb[..., 2] - rgb[..., 0]) > 0.3).any()


@pytest.mark.slow
def test_demo_entry_point_writes_pictures_and_summary(tmp_path):
    from lbshape.cli import main

    assert main(["demo", "--out", str(tmp_path)]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    spectra = summary["spectra"]
    for name in ("demo-bar", "demo-cylinder", "teddy"):
        values = spectra[name]["eigenvalues"]
        assert values == sorted(values) and values[0] > 0
    for picture in ("teddy_eigenfunctions.png", "demo_reduced.png", "demo_full.png",
                    "examples_on_object.png"):
        assert _png_pixels(tmp_path / picture).shape[0] > 100, picture
    simulation = summary["simulation"]
    assert simulation["reduced"]["stable"] and simulation["full"]["stable"]
    assert 0.0 <= simulation["error_vs_full"] < 1.0, simulation["error_vs_full"]
