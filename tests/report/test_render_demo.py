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
def test_demo_entry_point_writes_pictures_and_summary(tmp_path, capsys):
    from PIL import Image

    from lbshape.cli import main
    from lbshape.studies.demo import SUMMARY_KEYS

    assert main(["demo", "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    summary = json.loads((tmp_path / "summary.json").read_text())
    spectra = summary["spectra"]
    assert set(spectra) == {"demo-bar", "demo-cylinder"}  # the demo's own meshes
    for values in (s["eigenvalues"] for s in spectra.values()):
        assert values == sorted(values) and values[0] > 0
    simulation = summary["simulation"]
    assert tuple(simulation) == SUMMARY_KEYS
    for picture in ("eigenfunctions.png", "demo_reduced.png", "demo_full.png",
                    "examples_on_object.png", "demo_comparison.png", "demo_end_view.png"):
        assert _png_pixels(tmp_path / picture).shape[0] > 100, picture
        assert picture in simulation["pictures"], picture
    # the teddy's eigenfunctions belong to the teddy's figures, not to the demo
    assert not any("teddy" in p.name for p in tmp_path.iterdir())
    with Image.open(tmp_path / "demo.gif") as gif:
        assert gif.n_frames > 10
    for run in ("reduced", "reduced_no_examples", "full", "full_no_examples"):
        assert simulation[run]["stable"], run
    assert 0.0 <= simulation["error_vs_full"] < 1.0, simulation["error_vs_full"]
    # the one-line headline states speed, error versus full and influence, as printed
    assert simulation["headline"] in printed
    for words in ("ms/step", "error vs full", "example influence"):
        assert words in simulation["headline"], simulation["headline"]
    twist = simulation["end_twist_deg"]
    assert twist["reduced"] > twist["reduced_no_examples"] + 10.0, twist


def test_demo_headline_states_speed_error_and_influence():
    from lbshape.studies.demo import headline

    summary = {
        "reduced": {"t_total_ms": 1.25}, "full": {"t_total_ms": 10.0}, "speedup_t_total": 8.0,
        "error_vs_full": 0.034, "example_influence": 1.66,
        "end_twist_deg": {"reduced": 39.2, "reduced_no_examples": 14.8, "full": 40.7},
    }
    line = headline(summary)
    assert "\n" not in line
    for words in ("1.25 ms/step", "10.00 ms/step", "8.0x", "3.4%", "influence 1.66", "39 deg",
                  "15 deg", "41 deg"):
        assert words in line, (words, line)
