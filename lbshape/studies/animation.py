"""The movie of a scene's simulation (``lbshape render SCENE --movie``).

:func:`simulation_movie` runs the scene's method and, unless that is ``full``
already, the ``full`` reference; each run writes its usual outputs
(``stats.json``, ``states.npz`` and the ParaView trajectory) into
``OUT/runs/METHOD/``; a run that stopped leaves only ``FAILED.txt`` there
(:func:`lbshape.pipeline.simulate.write_outputs`) and shows until its stop. The
frames are the runs' samples — those ``states.npz`` (:func:`read_states`) and the
ParaView trajectory hold — drawn side by side by
:func:`lbshape.report.render.animation_frames` and written as a GIF (and an MP4
where the encoder is installed) by :mod:`lbshape.report.movie`.
"""

from __future__ import annotations

import logging
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lbshape.errors import LbshapeError
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import METHODS, simulate
from lbshape.report.movie import DEFAULT_FPS, Movie, write_movie
from lbshape.report.render import animation_frames, scene_planes

log = logging.getLogger(__name__)

#: file stem of the movies in the output folder
MOVIE_STEM = "simulation"


@dataclass(frozen=True)
class SceneMovie:
    """What :func:`simulation_movie` wrote.

    Attributes:
        movies: the GIF, then the MP4 if written.
        methods: the methods shown, left to right.
        runs: the runs' output folders (one per method; a stopped run's holds only
            ``FAILED.txt``).
        frames: frames per movie.
        message: failure messages of runs that stopped early ('' if none).
    """

    movies: tuple[Movie, ...]
    methods: tuple[str, ...]
    runs: tuple[Path, ...]
    frames: int
    message: str = ""


def read_states(folder: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """The samples a run wrote: ``times (k,)`` in s and ``displacements (k, n, 3)`` in m.

    Reads ``folder/states.npz`` as written by :func:`lbshape.pipeline.simulate.simulate`.

    Raises:
        LbshapeError: missing or unreadable file, or inconsistent arrays.
    """
    path = Path(folder) / "states.npz"
    try:
        with np.load(path, allow_pickle=False) as data:
            times, u = np.asarray(data["times"], float), np.asarray(data["displacements"], float)
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
        raise LbshapeError(f"cannot read the run's states {path}: {exc}") from None
    if u.ndim != 3 or u.shape[2] != 3 or times.shape != (u.shape[0],) or not len(times):
        raise LbshapeError(f"{path}: expected times (k,) and displacements (k, n, 3), got "
                           f"{times.shape} and {u.shape}")
    return times, u


def movie_methods(method: str) -> tuple[str, ...]:
    """The methods a movie shows: ``method`` and ``full`` side by side (``full`` alone)."""
    if method not in METHODS:
        raise LbshapeError(f"method must be one of {METHODS}, got {method!r}")
    return (method,) if method == "full" else (method, "full")


def _hold_last(u: np.ndarray, count: int) -> np.ndarray:
    """(count, n, 3): a run that stopped early holds its last frame."""
    if u.shape[0] >= count:
        return u[:count]
    return np.concatenate([u, np.repeat(u[-1:], count - u.shape[0], axis=0)])


def simulation_movie(scene, out: str | Path, *, method: str = "reduced",
                     steps: int | None = None, fps: float = DEFAULT_FPS, mp4: bool = True,
                     progress: bool = False) -> SceneMovie:
    """Simulate, write the runs' trajectories, and make ``OUT/simulation.gif`` (and ``.mp4``).

    Args:
        scene: the scene.
        out: output folder; runs go to ``out/runs/METHOD``.
        method: the method shown left of ``full`` (see :func:`movie_methods`).
        steps: steps of the runs (default: the scene's).
        fps: frames per second of the movie.
        mp4: also write the MP4 when an encoder is installed.
        progress: progress bars on stderr.
    """
    methods = movie_methods(method)
    out = Path(out)
    pre = precompute(scene, progress=progress)
    runs, messages, states = [], [], []
    for name in methods:
        folder = out / "runs" / name
        output = simulate(scene, pre, method=name, steps=steps, out=folder)
        if output.message:
            messages.append(f"{name}: {output.message}")
            log.error("movie %s: the %s run stopped: %s", scene.name, name, output.message)
        runs.append(folder)
        states.append((np.asarray(output.times, float), np.asarray(output.displacements, float)))
    times = max((t for t, _ in states), key=len)
    fields = [_hold_last(u, len(times)) for _, u in states]
    labels = [f"{scene.name}: {name}" for name in methods]
    frames = animation_frames(pre.mesh, fields, labels, times, progress=progress,
                              planes=scene_planes(scene))
    movies = write_movie(frames, out / f"{MOVIE_STEM}.gif", fps=fps, mp4=mp4)
    return SceneMovie(movies, methods, tuple(runs), int(frames.shape[0]), "; ".join(messages))
