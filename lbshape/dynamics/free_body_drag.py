"""A user's point pull on a free body (:class:`FreeBodyDrag`, a part of
:class:`~lbshape.dynamics.free_body.FreeBodySimulation`): a
:class:`~lbshape.dynamics.drag.DragSpring` on the dragged vertex's rows of the basis, a
world point force at the body point, evaluated at the start of each step and held over
it, one more load of the step's load stack."""

from __future__ import annotations

import numpy as np

from lbshape.dynamics.drag import DragSpring, explicit_stiffness_limit
from lbshape.dynamics.engine import Drag, basis_rows
from lbshape.dynamics.free_body_loads import FreeLoad, LoadStack
from lbshape.dynamics.loads import TimeProfile
from lbshape.errors import LbshapeError


class FreeBodyDrag:
    """The drag of :class:`~lbshape.dynamics.free_body.FreeBodySimulation` (which holds the
    arrays the methods read: ``basis``, ``rest_points``, ``frame``, ``loads``, ``_loads``,
    ``_now`` …)."""

    def set_drag(self, drag: Drag | None) -> None:
        """A user's point pull (:class:`~lbshape.dynamics.engine.Drag`) from the next step
        on, or ``None`` to release it (needs ``basis`` and ``rest_points``): a
        :class:`~lbshape.dynamics.drag.DragSpring` on the vertex's rows of the basis, a world
        point force at the body point evaluated at the start of each step and held over it,
        its stiffness capped at :func:`~lbshape.dynamics.drag.explicit_stiffness_limit`
        (:attr:`drag` holds the capped spring). A drag on the same vertex with the same
        stiffness moves the spring's target. The first drag adds one load to the stack
        (zero while released)."""
        if drag is None:
            self._set_drag_spring(None)
            return
        if (self.drag is not None and self.drag.vertex == drag.vertex
                and self._drag_stiffness == drag.stiffness):
            self.drag.move(drag.target)
            return
        rows = basis_rows(self.basis, drag.vertex, "a drag")
        if self.rest_points is None:
            raise LbshapeError("a drag needs the rest points (give rest_points=...)")
        body_point = self.rest_points[drag.vertex] - self.frame.center
        limit = explicit_stiffness_limit(
            rows, self.dt, mass=self.frame.mass, arm=float(np.linalg.norm(body_point)),
            inertia=float(np.linalg.eigvalsh(self.frame.inertia0)[0]))
        self._set_drag_spring(DragSpring(drag.vertex, rows, body_point,
                                         min(drag.stiffness, limit), drag.target))
        self._drag_stiffness = drag.stiffness

    def _set_drag_spring(self, drag: DragSpring | None) -> None:
        """The drag spring (or ``None``) into the load stack."""
        if drag is not None and self.drag is None and len(self._loads.profiles) == len(
                self.loads):
            slot = FreeLoad(np.zeros(3), np.zeros((self.r, 3, 3)), np.zeros((3, 3)),
                            np.zeros((self.r, 3, 3)), TimeProfile())
            self._loads = LoadStack([*self.loads, slot], self.r)
        self.drag = drag
        if drag is None and len(self._loads.profiles) > len(self.loads):
            self._loads.forces[-1] = 0.0
            self._loads.P[-1] = self._loads.Z0[-1] = self._loads.Z1[-1] = 0.0

    def _drag_load(self) -> None:
        """The drag's point force at the current state into its load slot."""
        state, stack = self._now, self._loads
        force = self.drag.point_force(state.c, state.R, state.q)
        P, Z0, Z1 = self.drag.load_arrays(force)
        stack.forces[-1], stack.P[-1], stack.Z0[-1], stack.Z1[-1] = force, P, Z0, Z1
