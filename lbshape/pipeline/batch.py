"""Batch jobs: one job per scene, in worker processes, failures kept per scene.

* :func:`expand_scenes` — command-line scene arguments (built-in names, TOML paths,
  globs such as ``scenes/*.toml``) to a list of distinct scene arguments;
* :func:`run_jobs` — call ``job(scene_argument)`` for each scene, in this process
  (``jobs=1``) or in ``jobs`` worker processes (:class:`ProcessPoolExecutor`, each
  worker its own process with one OpenMP/BLAS thread); a scene whose job raises is
  reported in its :class:`JobResult` and does not stop the others;
* :func:`summary_table` — one Markdown-style table of the results.

Workers share the artifact cache safely: the precompute holds the artifact's lock
(:func:`lbshape.io.cache.artifact_lock`) while it checks and computes, and every
cache file is written atomically.
"""

from __future__ import annotations

import contextlib
import glob
import multiprocessing
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from typing import Any

from lbshape.errors import LbshapeError

#: environment of every worker process: one thread per numerical library
WORKER_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
_GLOB_CHARS = frozenset("*?[")


@dataclass(frozen=True)
class JobResult:
    """What one scene's job gave.

    Attributes:
        scene: the scene argument as given (name, path or a glob's match).
        value: the job's return value (None if it failed).
        error: one-line failure message ('' if it succeeded).
        exit_code: the failure's exit code (0 if it succeeded).
        seconds: wall time of the job (s).
    """

    scene: str
    value: Any = None
    error: str = ""
    exit_code: int = 0
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        return not self.error


def expand_scenes(arguments: Sequence[str]) -> tuple[list[str], list[JobResult]]:
    """Scene arguments with globs expanded (sorted matches), duplicates dropped.

    Returns:
        ``(scenes, unmatched)``: the scene arguments in order, and one failed
        :class:`JobResult` per glob that matched no file.
    """
    scenes: list[str] = []
    unmatched: list[JobResult] = []
    for argument in arguments:
        if _GLOB_CHARS.intersection(argument) and not os.path.exists(argument):
            matches = sorted(glob.glob(os.path.expanduser(argument)))
            if not matches:
                unmatched.append(JobResult(argument, error=f"no scene file matches '{argument}'",
                                           exit_code=LbshapeError.exit_code))
            scenes.extend(matches)
        else:
            scenes.append(argument)
    return list(dict.fromkeys(scenes)), unmatched


def _call(job: Callable[[str], Any], scene: str) -> JobResult:
    """``job(scene)`` as a :class:`JobResult`: errors become one-line messages."""
    started = time.perf_counter()
    try:
        value = job(scene)
    except LbshapeError as exc:
        return JobResult(scene, error=str(exc), exit_code=exc.exit_code,
                         seconds=time.perf_counter() - started)
    except Exception as exc:  # noqa: BLE001 -- one scene's bug must not stop the batch
        message = " ".join(f"{type(exc).__name__}: {exc}".split())
        return JobResult(scene, error=message, exit_code=1,
                         seconds=time.perf_counter() - started)
    return JobResult(scene, value=value, seconds=time.perf_counter() - started)


@contextlib.contextmanager
def _worker_environment() -> Iterator[None]:
    """:data:`WORKER_ENV` in ``os.environ`` while workers are started (they inherit it)."""
    saved = {name: os.environ.get(name) for name in WORKER_ENV}
    os.environ.update(WORKER_ENV)
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def run_jobs(job: Callable[[str], Any], scenes: Sequence[str], *, jobs: int = 1,
             progress: bool = False, desc: str = "scenes") -> list[JobResult]:
    """Run ``job(scene)`` for every scene; results in the order of ``scenes``.

    Args:
        job: a picklable callable (a module-level function or a
            :func:`functools.partial` of one) taking a scene argument.
        scenes: scene arguments (see :func:`expand_scenes`).
        jobs: worker processes; 1 runs the jobs one after the other in this process.
        progress: a progress bar over the finished scenes on stderr.
        desc: the progress bar's label.

    Raises:
        LbshapeError: ``jobs < 1``.
    """
    if isinstance(jobs, bool) or int(jobs) != jobs or jobs < 1:
        raise LbshapeError(f"-j/--jobs must be an integer >= 1, got {jobs}")
    from tqdm import tqdm

    if jobs == 1 or len(scenes) <= 1:
        return [_call(job, scene) for scene in tqdm(
            scenes, desc=desc, disable=not progress or len(scenes) <= 1, file=sys.stderr)]
    results: dict[int, JobResult] = {}
    context = multiprocessing.get_context("spawn")  # no PETSc/MPI state copied by fork
    with _worker_environment(), ProcessPoolExecutor(
            max_workers=min(int(jobs), len(scenes)), mp_context=context) as pool:
        futures = {pool.submit(_call, job, scene): index for index, scene in enumerate(scenes)}
        with tqdm(total=len(scenes), desc=desc, disable=not progress, file=sys.stderr) as bar:
            for future in as_completed(futures):
                index = futures[future]
                try:
                    results[index] = future.result()
                except Exception as exc:  # noqa: BLE001 -- a worker died (e.g. killed)
                    results[index] = JobResult(
                        scenes[index], error=f"worker process failed: {type(exc).__name__}",
                        exit_code=1)
                bar.update(1)
    return [results[index] for index in range(len(scenes))]


def summary_table(results: Sequence[JobResult], columns: Sequence[str],
                  cells: Callable[[Any], Sequence[str]]) -> str:
    """A Markdown table: scene, status, seconds, the job's own ``columns``, message.

    Args:
        results: the jobs' results.
        columns: headers of the job-specific columns.
        cells: the job-specific cells of a successful result's ``value`` (as many
            as ``columns``); failed rows leave them empty.
    """
    header = ["scene", "status", "seconds", *columns, "message"]
    rows = []
    for result in results:
        extra = list(cells(result.value)) if result.ok else [""] * len(columns)
        if len(extra) != len(columns):
            raise ValueError(f"{len(extra)} cells for {len(columns)} columns")
        rows.append([result.scene, "ok" if result.ok else "FAILED", f"{result.seconds:.1f}",
                     *extra, result.error])
    widths = [max(len(str(row[i])) for row in [header, *rows]) for i in range(len(header))]

    def line(row):
        return "| " + " | ".join(str(c).ljust(w) for c, w in zip(row, widths, strict=True)) + " |"

    rule = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    return "\n".join([line(header), rule, *(line(row) for row in rows)])
