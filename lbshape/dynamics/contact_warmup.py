"""A free body's contact kernels loaded at set-up, not at its first contact
(:func:`warm_contact`).

numba compiles lbshape's kernels once and keeps them on disk (:mod:`lbshape._jit`), but a
process loads a kernel's machine code at its first call: the contact kernels at the
body's first contact, and the step's own kernels at its first step. The car's first
step took 36 ms and its first hit 13.7 ms (12.6 of them loading code): stalls a live
run shows, and the run's largest steps. :func:`warm_contact` takes
one throwaway step of each kind of engine the body steps on, pressed :data:`PROBE_DEPTH`
into its first plane and moving into it at :data:`PROBE_SPEED`, and puts the engine back
to the state it had (:meth:`~lbshape.dynamics.free_body.FreeBodySimulation.reset`): the
run that follows is the same bit for bit.
"""

from __future__ import annotations

from lbshape._jit import HAVE_NUMBA
from lbshape.errors import LbshapeError
from lbshape.geometry.hull_directions import hull_points

#: how deep the probe step starts inside the first plane (m)
PROBE_DEPTH = 1e-3
#: the probe's speed into the plane (m/s)
PROBE_SPEED = 0.1


def warm_contact(body) -> None:
    """Load the contact kernels of ``body`` (a
    :class:`~lbshape.dynamics.free_body.FreeBodySimulation`, or an
    :class:`~lbshape.dynamics.impact_switch.ImpactSwitchedBody`: its plain engine and its
    first set's, whose kernels every set shares) by one probe step each; nothing without
    contact planes or without numba. A probe that fails (a body the probe cannot step)
    leaves the loading to the first contact; the engine is put back either way."""
    if not HAVE_NUMBA:  # pragma: no cover - plain Python has nothing to load
        return
    engines = getattr(body, "engines", [body])[:2]
    for engine in engines:
        if engine.contact is not None and engine.rest_points is not None:
            _probe(engine)


def _probe(engine) -> None:
    """One step of ``engine`` from its state now moved into its first plane, then the
    state back."""
    saved = engine.state
    now, planes = engine._now, engine.contact
    normal, point = planes.normals[0], planes.points[0]
    hull = hull_points(engine.rest_points) - engine.frame.center
    gap = float(((now.c + hull @ now.R.T - point) @ normal).min())
    now.c[:] -= (gap + PROBE_DEPTH) * normal
    now.p[:] = -PROBE_SPEED * float(engine.frame.mass) * normal
    engine._contact_calls = -1  # the contact evaluated afresh at the moved state
    try:
        engine.step()
    except LbshapeError:
        pass  # the first contact loads the kernels instead
    finally:
        engine.reset(saved)
