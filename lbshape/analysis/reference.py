"""The error of a run against a reference run of the same scene (the ``full`` method).

:func:`reference_error` is the one computation of it, used by ``lbshape simulate
--compare full`` (:func:`lbshape.pipeline.simulate.compare`) and by the benchmark's
``error_vs_full`` (:mod:`lbshape.studies.bench`):

* ``error_vs_full`` — :func:`lbshape.analysis.norms.trajectory_error`,
  ``max_t ‖u − u_full‖_M / max_t ‖u_full‖_M`` over the common sample times (Table 2's);
* ``final_error_vs_full`` — the same ratio at the last sample only,
  ``‖u(T) − u_full(T)‖_M / ‖u_full(T)‖_M`` (None where the reference is at rest there);
* a free body (``rest`` given): its centre path / rotation / deformation split,
  :data:`lbshape.analysis.free_body.KEYS` (:func:`~lbshape.analysis.free_body.free_body_error`).
"""

from __future__ import annotations

import numpy as np

from lbshape.analysis.free_body import free_body_error
from lbshape.analysis.norms import m_norms, trajectory_error

#: the keys of :func:`reference_error` for every object (a free body adds
#: :data:`lbshape.analysis.free_body.KEYS`)
KEYS: tuple[str, ...] = ("error_vs_full", "final_error_vs_full")


def reference_error(u: np.ndarray, u_full: np.ndarray, mass, *, times: np.ndarray,
                    times_full: np.ndarray, rest: np.ndarray | None = None) -> dict:
    """A run's error against its reference, both sampled at the same times.

    Args:
        u: (k, n, 3) displacements of the run in m.
        u_full: (k, n, 3) displacements of the reference in m.
        mass: (3n, 3n) consistent elastic mass in kg.
        times, times_full: (k,) sample times of both in s (checked equal).
        rest: (n, 3) rest points in m of a free body (adds its split), else None.

    Returns:
        ``{"error_vs_full", "final_error_vs_full"}`` (dimensionless), plus for a free
        body ``{"com_path_error", "rotation_error_deg", "body_deformation_error"}``.

    Raises:
        LbshapeError: different shapes or sample times, or a reference that never moves.
    """
    error = trajectory_error(u, u_full, mass, times=times, times_full=times_full)
    last = m_norms(np.stack([np.asarray(u[-1]) - np.asarray(u_full[-1]),
                             np.asarray(u_full[-1])]), mass)
    final = float(last[0] / last[1]) if last[1] > 0.0 else None
    result = {"error_vs_full": error, "final_error_vs_full": final}
    if rest is not None:
        result.update(free_body_error(u, u_full, rest, mass).stats())
    return result
