"""Running the precompute's stages: a progress bar, the wall time and the peak resident
memory of each, and over how many MPI ranks each ran.

* :class:`StageRecorder` — one context per stage (:meth:`StageRecorder.stage`): a
  progress bar on stderr, ``seconds`` and ``peak_mb`` per stage name.
* :class:`PeakMemory` — the largest resident set size seen while it is open, sampled by
  a thread every :data:`RSS_INTERVAL` seconds (and at its start and end), so a stage
  that frees what it used shows its own peak, not the process's largest so far.
* :class:`Ranks` — runs a stage either on every rank of a communicator (a collective
  solver stage, :meth:`Ranks.distributed`) or on rank 0 alone
  (:meth:`Ranks.on_root`, :func:`lbshape.fem.mpi.compute_on_root`), timing it with a
  :class:`StageRecorder` and recording the rank count (the artifact's ``stage_ranks``);
  given a :class:`StageCache`, a stage whose entry is stored is loaded instead of run.
* :class:`StageCache` — each stage's result stored under its own key
  (:func:`lbshape.pipeline.precompute_key.stage_keys`,
  :func:`lbshape.io.cache.load_stage`), serial runs only.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from collections.abc import Callable
from typing import TypeVar

from mpi4py import MPI

from lbshape.fem.mpi import compute_on_root
from lbshape.io.cache import load_stage, save_stage

#: seconds between two samples of the resident set size
RSS_INTERVAL = 0.02

T = TypeVar("T")


class StageRecorder:
    """A progress bar per stage (stderr), the time spent in each and its peak memory.

    Args:
        names: the stages in the order they run (numbers the progress bars).
        show: draw the progress bars.

    Attributes:
        seconds: stage name -> wall time (s).
        peak_mb: stage name -> largest resident set size of the process during the
            stage (MB, :class:`PeakMemory`).
        cached: the stages loaded from the cache (their seconds: the loading).
    """

    def __init__(self, names: list[str], *, show: bool):
        self.names = names
        self.show = show
        self.seconds: dict[str, float] = {}
        self.peak_mb: dict[str, float] = {}
        self.cached: list[str] = []

    @contextlib.contextmanager
    def stage(self, name: str):
        from tqdm import tqdm

        index = self.names.index(name) + 1
        bar = tqdm(total=1, desc=f"[{index}/{len(self.names)}] {name:<12}", disable=not self.show,
                   file=sys.stderr, leave=True, bar_format="{desc} {bar:20} {elapsed}")
        sampler = PeakMemory()
        started = time.perf_counter()
        try:
            with sampler:
                yield
        finally:
            self.seconds[name] = time.perf_counter() - started
            self.peak_mb[name] = sampler.peak_mb
            if name in self.cached:
                bar.set_description_str(f"[{index}/{len(self.names)}] {name:<12} (cache)")
            bar.update(1)
            bar.close()


class PeakMemory:
    """Context manager: the largest resident set size (MB) seen while it is open."""

    def __init__(self):
        self.peak_mb = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def __enter__(self):
        self._record()
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self._record()
        return False

    def _sample(self) -> None:
        while not self._stop.wait(RSS_INTERVAL):
            self._record()

    def _record(self) -> None:
        self.peak_mb = max(self.peak_mb, resident_mb())


def resident_mb() -> float:
    """The process's resident set size in MB (the peak so far where the current
    size cannot be read)."""
    try:
        with open("/proc/self/statm", encoding="ascii") as statm:
            pages = int(statm.read().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):  # not Linux: ru_maxrss (KB on Linux/BSD)
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


class Ranks:
    """Which stages ran over all ranks of ``comm`` and which on rank 0 alone.

    Attributes:
        comm: the communicator.
        stages: the :class:`StageRecorder` timing every stage.
        count: stage name -> number of ranks it ran over.
    """

    def __init__(self, comm: MPI.Comm, stages: StageRecorder, cache: StageCache | None = None):
        self.comm, self.stages, self.cache = comm, stages, cache
        self.count: dict[str, int] = {}

    @property
    def root(self) -> bool:
        """True on rank 0 (the rank that holds the results)."""
        return self.comm.rank == 0

    def distributed(self, name: str, compute: Callable[[], T]) -> T:
        """``compute()`` on every rank (a collective solver stage)."""
        with self.stages.stage(name):
            value = self._run(name, compute)
        self.count[name] = self.comm.size
        return value

    def on_root(self, name: str, compute: Callable[[], T], *, share: bool = False) -> T | None:
        """``compute()`` on rank 0 only; ``None`` on the other ranks unless ``share``."""
        with self.stages.stage(name):
            value = self._run(name, lambda: compute_on_root(self.comm, compute, share=share))
        self.count[name] = 1
        return value

    def _run(self, name: str, compute: Callable[[], T]) -> T:
        if self.cache is None or self.comm.size > 1:
            return compute()
        hit, value = self.cache.fetch(name, compute)
        if hit:
            self.stages.cached.append(name)
        return value


class StageCache:
    """Each stage's result stored under its own key: a stage whose entry exists is
    loaded, not run (serial runs; under MPI every stage runs).

    Args:
        keys: stage name -> cache key (:func:`~lbshape.pipeline.precompute_key.stage_keys`).
        read: look entries up (False: recompute every stage, ``--force``).
        write: store each computed stage's result (atomically).
    """

    def __init__(self, keys: dict[str, str], *, read: bool = True, write: bool = True):
        self.keys, self.read, self.write = keys, read, write

    def fetch(self, name: str, compute: Callable[[], T]) -> tuple[bool, T]:
        """(True, the stored result) or (False, ``compute()``, then stored)."""
        key = self.keys.get(name)
        if key is None:
            return False, compute()
        if self.read:
            hit, value = load_stage(name, key)
            if hit:
                return True, value
        value = compute()
        if self.write:
            save_stage(name, key, value)
        return False, value
