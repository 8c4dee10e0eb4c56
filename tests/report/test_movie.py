"""The movie writer (GIF, MP4) and ``lbshape render --movie`` on the demo scene."""

from __future__ import annotations

import re

import numpy as np
import pytest
from PIL import Image

from lbshape.cli import main
from lbshape.errors import LbshapeError
from lbshape.report.movie import (
    as_frames,
    mp4_available,
    side_by_side,
    write_gif,
    write_movie,
    write_mp4,
)


def _frames(k=7, height=33, width=50):
    """k distinct frames: a bar moving down, the red channel rising."""
    frames = np.full((k, height, width, 3), 255, dtype=np.uint8)
    for i in range(k):
        frames[i, i:i + 4, :] = (40 * i % 256, 30, 200)
    return frames


def test_gif_has_every_frame_at_its_size_and_rate(tmp_path):
    frames = _frames()
    movie = write_gif(frames, tmp_path / "a.gif", fps=25)
    assert (movie.frames, movie.size) == (7, (33, 50))
    with Image.open(movie.path) as image:
        assert image.n_frames == 7 and image.size == (50, 33)
        assert image.info["duration"] == 40 and image.info["loop"] == 0
        image.seek(3)
        rgb = np.asarray(image.convert("RGB"))
    # one global palette, no dithering: the frame comes back within quantisation error
    assert np.abs(rgb.astype(int) - frames[3]).max() <= 8
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.gif"]  # no temporaries


def test_gif_merges_identical_consecutive_frames_and_says_so(tmp_path):
    frames = _frames(4)
    frames = np.concatenate([frames[:2], frames[1:2], frames[2:]])  # frame 1 repeated
    movie = write_gif(frames, tmp_path / "b.gif", fps=20)
    assert movie.frames == 4, movie


def test_frames_are_validated(tmp_path):
    with pytest.raises(LbshapeError, match="uint8"):
        write_gif(np.zeros((2, 4, 4, 3)), tmp_path / "x.gif")
    with pytest.raises(LbshapeError, match=r"\(k, H, W, 3\)"):
        as_frames(np.zeros((4, 4, 3), dtype=np.uint8))
    with pytest.raises(LbshapeError, match="one size"):
        as_frames([np.zeros((4, 4, 3), np.uint8), np.zeros((5, 4, 3), np.uint8)])
    with pytest.raises(LbshapeError, match="fps"):
        write_gif(_frames(), tmp_path / "x.gif", fps=0)
    assert list(tmp_path.iterdir()) == []
    assert as_frames(np.zeros((2, 3, 4, 4), np.uint8)).shape == (2, 3, 4, 3)  # alpha dropped


def test_side_by_side_joins_panels():
    left, right = _frames(3, 20, 10), _frames(3, 16, 6)
    joined = side_by_side(left, right, gap=2)
    assert joined.shape == (3, 20, 18, 3)
    np.testing.assert_array_equal(joined[:, :, :10], left)
    np.testing.assert_array_equal(joined[:, 2:18, 12:], right)
    assert (joined[:, :2, 12:] == 255).all()
    with pytest.raises(LbshapeError, match="same number of frames"):
        side_by_side(left, _frames(2, 20, 10))


@pytest.mark.skipif(not mp4_available(), reason="imageio-ffmpeg not installed")
def test_mp4_frame_count_and_even_size(tmp_path):
    import imageio_ffmpeg

    movie = write_mp4(_frames(9, 33, 51), tmp_path / "c.mp4", fps=10)
    assert movie.size == (34, 52) and movie.frames == 9
    count, seconds = imageio_ffmpeg.count_frames_and_secs(str(movie.path))
    assert count == 9 and seconds == pytest.approx(0.9, abs=0.11)
    gif, mp4 = write_movie(_frames(), tmp_path / "d.gif")
    assert (gif.path.name, mp4.path.name) == ("d.gif", "d.mp4")


@pytest.mark.slow
def test_render_movie_shows_reduced_and_full_from_the_written_trajectories(tmp_path):
    from lbshape.studies.animation import read_states

    out = tmp_path / "figures"
    assert main(["render", "demo", "--out", str(out), "--steps", "12", "--movie"]) == 0
    times, u = read_states(out / "runs" / "reduced")
    full_times, _ = read_states(out / "runs" / "full")
    np.testing.assert_array_equal(times, full_times)
    pvd = (out / "runs" / "reduced" / "trajectory.pvd").read_text()
    assert len(re.findall(r"<DataSet ", pvd)) == len(times) == 13
    with Image.open(out / "simulation.gif") as image:
        assert image.n_frames == len(times)
        assert image.size == (2 * 360, 420)  # reduced | full, one panel each
        image.seek(image.n_frames - 1)
        last = np.asarray(image.convert("RGB"))
    coloured = (last.max(axis=2).astype(int) - last.min(axis=2) > 25).mean()
    assert coloured > 0.02, f"only {coloured:.2%} coloured pixels in the last frame"
    assert (out / "simulation.mp4").exists() == mp4_available()


def test_animation_frames_rejects_mismatched_panels():
    from lbshape.geometry.primitives import structured_box
    from lbshape.report.render import animation_frames

    mesh = structured_box((1.0, 0.5, 0.5), (2, 1, 1))
    u = np.zeros((3, mesh.n_vertices, 3))
    with pytest.raises(LbshapeError, match="one label per panel"):
        animation_frames(mesh, [u, u], ["reduced"], np.arange(3.0))
    with pytest.raises(LbshapeError, match="shape"):
        animation_frames(mesh, [u[:2]], ["reduced"], np.arange(3.0))
