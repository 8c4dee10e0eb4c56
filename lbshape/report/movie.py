"""Movies from frames: animated GIF (Pillow) and MP4 (H.264, the ffmpeg of ``imageio-ffmpeg``).

Frames are a ``(k, H, W, 3)`` ``uint8`` RGB array (or a sequence of ``(H, W, 3)``
arrays of one size; an alpha channel is dropped). Every file is written atomically
(:mod:`lbshape.io.atomic`): a reader never sees a half-written movie.

* :func:`write_gif` — one global palette for all frames (no colour flicker), looping;
  consecutive identical frames are merged by the GIF encoder into one longer frame
  (the timing is kept), so :attr:`Movie.frames` reports what the file holds;
* :func:`write_mp4` — yuv420p H.264, frames padded to even sizes; needs
  ``imageio-ffmpeg`` (:func:`mp4_available`);
* :func:`write_movie` — the GIF, plus the MP4 where the encoder is available;
* :func:`side_by_side` — panels of the same frame count joined horizontally.

Nothing here draws: pictures come from :mod:`lbshape.report.render` or anywhere else.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lbshape.errors import LbshapeError
from lbshape.io.atomic import write_atomic

log = logging.getLogger(__name__)

#: frames per second of the movies unless told otherwise
DEFAULT_FPS = 20.0


@dataclass(frozen=True)
class Movie:
    """A written movie file.

    Attributes:
        path: the file.
        frames: frames the file holds.
        size: ``(height, width)`` in pixels.
        fps: frames per second.
    """

    path: Path
    frames: int
    size: tuple[int, int]
    fps: float


def as_frames(frames) -> np.ndarray:
    """Validate frames: ``(k, H, W, 3)`` uint8, k ≥ 1 (RGBA input loses its alpha).

    Raises:
        LbshapeError: wrong shape or dtype, or no frame.
    """
    if not isinstance(frames, np.ndarray):
        frames = list(frames)
        if not frames:
            raise LbshapeError("a movie needs at least one frame")
        shapes = {np.shape(f) for f in frames}
        if len(shapes) != 1:
            raise LbshapeError(f"frames must all have one size, got {sorted(shapes)}")
        frames = np.stack(frames)
    if frames.ndim != 4 or frames.shape[-1] not in (3, 4) or frames.shape[0] == 0 \
            or 0 in frames.shape[1:3]:
        raise LbshapeError(f"frames must be a (k, H, W, 3) array with k >= 1, got shape "
                           f"{frames.shape}")
    if frames.dtype != np.uint8:
        raise LbshapeError(f"frames must be uint8 RGB, got {frames.dtype}")
    return np.ascontiguousarray(frames[..., :3])


def _check_fps(fps: float) -> float:
    fps = float(fps)
    if not np.isfinite(fps) or fps <= 0:
        raise LbshapeError(f"fps must be > 0, got {fps}")
    return fps


def side_by_side(*panels, gap: int = 0, background: int = 255) -> np.ndarray:
    """Join panels of the same frame count horizontally: ``(k, H, ΣW + gaps, 3)``.

    Shorter panels are centred vertically on ``background`` (0–255 grey).
    """
    if not panels:
        raise LbshapeError("side_by_side needs at least one panel")
    panels = [as_frames(p) for p in panels]
    counts = {p.shape[0] for p in panels}
    if len(counts) != 1:
        raise LbshapeError(f"panels must have the same number of frames, got {sorted(counts)}")
    height = max(p.shape[1] for p in panels)
    width = sum(p.shape[2] for p in panels) + gap * (len(panels) - 1)
    out = np.full((panels[0].shape[0], height, width, 3), background, dtype=np.uint8)
    x = 0
    for panel in panels:
        top = (height - panel.shape[1]) // 2
        out[:, top:top + panel.shape[1], x:x + panel.shape[2]] = panel
        x += panel.shape[2] + gap
    return out


def _palette(frames: np.ndarray):
    """One 256-colour palette image for all frames (median cut over a pixel sample)."""
    from PIL import Image

    step = max(1, frames.shape[0] // 12)
    sample = frames[::step, ::2, ::2].reshape(-1, 3)
    side = int(np.ceil(np.sqrt(sample.shape[0])))
    padded = np.zeros((side * side, 3), dtype=np.uint8)
    padded[:sample.shape[0]] = sample
    padded[sample.shape[0]:] = sample[0]
    return Image.fromarray(padded.reshape(side, side, 3)).quantize(
        colors=256, method=Image.Quantize.MEDIANCUT)


def write_gif(frames, path: str | Path, *, fps: float = DEFAULT_FPS, loop: int = 0) -> Movie:
    """An animated GIF of ``frames`` (k, H, W, 3) uint8, written atomically.

    Args:
        frames: the frames (see :func:`as_frames`).
        path: output ``.gif``.
        fps: frames per second (GIF delays are multiples of 10 ms).
        loop: 0 loops forever, else how many times to play.
    """
    from PIL import Image

    frames, fps = as_frames(frames), _check_fps(fps)
    palette = _palette(frames)
    images = [Image.fromarray(frame).quantize(palette=palette, dither=Image.Dither.NONE)
              for frame in frames]
    duration = max(10, int(round(100.0 / fps)) * 10)  # ms

    def save(tmp: Path) -> None:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:],
                       duration=duration, loop=int(loop), optimize=False, disposal=1)

    path = write_atomic(path, save)
    with Image.open(path) as image:
        count = int(getattr(image, "n_frames", 1))
    return Movie(Path(path), count, (frames.shape[1], frames.shape[2]), 1000.0 / duration)


def mp4_encoder() -> str | None:
    """Path of the ffmpeg that ``imageio-ffmpeg`` ships, or None without it."""
    try:
        import imageio_ffmpeg
    except ImportError:
        return None
    try:
        return imageio_ffmpeg.get_ffmpeg_exe()
    except RuntimeError:
        return None


def mp4_available() -> bool:
    """True when :func:`write_mp4` can encode (``imageio-ffmpeg`` and its ffmpeg present)."""
    return mp4_encoder() is not None


def write_mp4(frames, path: str | Path, *, fps: float = DEFAULT_FPS) -> Movie:
    """An H.264 MP4 (yuv420p) of ``frames`` (k, H, W, 3) uint8, written atomically.

    Odd heights or widths are padded by one white row or column (the encoder needs
    even sizes).

    Raises:
        LbshapeError: no encoder (``imageio-ffmpeg`` missing) or bad frames.
    """
    if not mp4_available():
        raise LbshapeError("MP4 needs the imageio-ffmpeg package (pip install imageio-ffmpeg)")
    import imageio_ffmpeg

    frames, fps = as_frames(frames), _check_fps(fps)
    k, height, width, _ = frames.shape
    even = np.full((k, height + height % 2, width + width % 2, 3), 255, dtype=np.uint8)
    even[:, :height, :width] = frames

    def save(tmp: Path) -> None:
        writer = imageio_ffmpeg.write_frames(
            str(tmp), (even.shape[2], even.shape[1]), fps=fps, codec="libx264",
            pix_fmt_in="rgb24", pix_fmt_out="yuv420p", macro_block_size=1,
            ffmpeg_log_level="error", output_params=["-f", "mp4"])
        writer.send(None)
        try:
            for frame in even:
                writer.send(frame.tobytes())
        finally:
            writer.close()

    path = write_atomic(path, save)
    return Movie(Path(path), k, (even.shape[1], even.shape[2]), fps)


def write_movie(frames, path: str | Path, *, fps: float = DEFAULT_FPS,
                mp4: bool = True) -> tuple[Movie, ...]:
    """``path`` with suffix ``.gif``, and ``.mp4`` beside it when ``mp4`` and an encoder exist.

    Returns:
        The GIF's :class:`Movie`, then the MP4's if written.
    """
    frames = as_frames(frames)
    path = Path(path)
    movies = [write_gif(frames, path.with_suffix(".gif"), fps=fps)]
    if mp4:
        if mp4_available():
            movies.append(write_mp4(frames, path.with_suffix(".mp4"), fps=fps))
        else:
            log.warning("no MP4 encoder (install imageio-ffmpeg): wrote the GIF only")
    return tuple(movies)

