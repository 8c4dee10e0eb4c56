"""The reduced engines' shared pieces: the scheme table every engine reads, the named
views the free-body kernels take (one buffer each, the same layout compiled and in
Python), and the free-body step without per-step arrays."""

from __future__ import annotations

import os
import tracemalloc

import numpy as np
import pytest
from test_free_body import Body, _contact, _gravity

try:
    from numba import literal_unroll
except ImportError:  # pragma: no cover - plain Python: a tuple is iterated as it is
    def literal_unroll(values):
        return values

from lbshape._jit import njit, py_func
from lbshape.dynamics.fictitious import FrameArrays, frame_arrays
from lbshape.dynamics.free_body_kernels import (
    BodyState,
    DeformationSolve,
    RigidKick,
    Scratch,
    body_state,
    deformation_solve,
    end_rates_into,
    rigid_kick,
    scratch,
)
from lbshape.dynamics.integrators import make_stepper
from lbshape.dynamics.kernels import predict
from lbshape.dynamics.schemes import INTEGRATORS, SCHEMES, get_scheme
from lbshape.errors import LbshapeError

R = 5
STRUCTURES = {
    "BodyState": (BodyState, body_state, {"c": (3,), "p": (3,), "R": (3, 3), "L": (3,),
                                          "q": (R,), "qd": (R,), "qa": (R,),
                                          "f_elastic": (R,)}),
    "RigidKick": (RigidKick, rigid_kick, {"K6": (6, 6), "theta": (1,)}),
    "DeformationSolve": (DeformationSolve, deformation_solve,
                         {"scheme": (5,), "D": (R, R), "b": (R,), "norms": (2,)}),
    "Scratch": (Scratch, scratch, {"m33": (8, 3, 3), "v6": (4, 6), "m66": (4, 6, 6),
                                   "q_mid": (R,), "energies": (3,)}),
    "FrameArrays": (FrameArrays, frame_arrays, {"mass": (1,), "Y0": (3, 3), "G9": (R, 9),
                                                "C9": (R * R, 9), "C_trace": (R, R)}),
}


def _buffer(cls) -> np.ndarray:
    return np.zeros(cls.size() if cls is RigidKick else cls.size(R))


def _views(cls, function, data):
    return py_func(function)(data) if cls is RigidKick else py_func(function)(data, R)


@njit
def _mark_fields(structure):
    """Field i of a structure (its buffer, field 0, aside) filled with i."""
    i = 0
    for field in literal_unroll(structure):
        if i > 0:
            field[...] = i
        i += 1


@njit
def _mark_compiled(kind, data, r):
    """The compiled views of ``data`` (kind: 0 BodyState, …, 4 FrameArrays) marked."""
    if kind == 0:
        _mark_fields(body_state(data, r))
    elif kind == 1:
        _mark_fields(rigid_kick(data))
    elif kind == 2:
        _mark_fields(deformation_solve(data, r))
    elif kind == 3:
        _mark_fields(scratch(data, r))
    else:
        _mark_fields(frame_arrays(data, r))


@pytest.mark.parametrize("name", STRUCTURES)
def test_the_views_of_a_structure_tile_its_buffer(name):
    """Every float of the buffer belongs to exactly one field, in field order, and the
    fields have their documented shapes."""
    cls, function, shapes = STRUCTURES[name]
    data = _buffer(cls)
    views = _views(cls, function, data)
    assert views.data is data
    data[:] = np.arange(data.size)
    covered = np.concatenate([np.ravel(getattr(views, field)) for field in cls._fields[1:]])
    np.testing.assert_array_equal(covered, np.arange(data.size))
    for field, shape in shapes.items():
        assert getattr(views, field).shape == shape, field


@pytest.mark.parametrize("kind, name", list(enumerate(STRUCTURES)))
def test_compiled_and_python_views_share_one_layout(kind, name):
    cls, function, _ = STRUCTURES[name]
    compiled, python = _buffer(cls), _buffer(cls)
    _mark_compiled(kind, compiled, R)
    py_func(_mark_fields)(_views(cls, function, python))
    np.testing.assert_array_equal(compiled, python)
    assert compiled.min() >= 1  # nothing left out


def test_a_buffer_of_the_wrong_size_is_refused():
    with pytest.raises(ValueError, match="do not cover"):
        py_func(body_state)(np.zeros(BodyState.size(R) + 1), R)
    with pytest.raises(ValueError, match="do not cover"):
        _mark_compiled(0, np.zeros(BodyState.size(R) - 1), R)


@pytest.mark.parametrize("name", INTEGRATORS)
def test_every_engine_evaluates_the_one_scheme_table(name):
    """The table's kinematics ``a₁ = c_a/h² Δx − k_v/h v − k_a a``, ``v₁ = c_v/h Δx − j_v v``
    against the general stepper and the free-body kernel, and its predictor
    ``h v + ½ k_a h² a`` against the shared kernel (each evaluates its own form: equal to
    round-off)."""
    scheme, h = SCHEMES[name], 2.5e-3
    rng = np.random.default_rng(3)
    dx, v, a = rng.standard_normal((3, 6))
    ca, kv, ka, cv, jv = scheme.step_rates(h)
    a1, v1 = ca * dx - kv * v - ka * a, cv * dx - jv * v
    # M = I, no force, the load a: the stepper starts from (v, a)
    stepper = make_stepper(name, np.eye(6), lambda x: (np.zeros(6), np.zeros((6, 6))),
                           dt=h, v0=v, external=lambda t: a)
    np.testing.assert_array_equal(stepper.a, a)
    np.testing.assert_allclose(stepper.kinematics(dx), (v1, a1), rtol=1e-12)
    rates_v, rates_a = np.zeros(6), np.zeros(6)
    end_rates_into(scheme.array, h, dx, v, a, rates_v, rates_a)
    np.testing.assert_allclose((rates_v, rates_a), (v1, a1), rtol=1e-12)
    predicted = np.zeros(6)
    predict(v, a, h, predicted, np.array(scheme.step_rates(h)))
    np.testing.assert_allclose(predicted, h * v + 0.5 * ka * h * h * a, rtol=1e-14)
    assert stepper.scheme is get_scheme(name)


def test_an_unknown_integrator_is_refused_by_name():
    with pytest.raises(LbshapeError, match="integrator must be one of"):
        get_scheme("leapfrog")


def test_the_free_body_step_allocates_no_arrays():
    """In contact, with a load and sweeps: traced memory does not grow over 200 steps and
    its transient peak (interpreter frames, argument tuples) stays below half an r × r
    matrix (r = 30)."""
    body = Body(r=30)
    contact = _contact(body, (0.0, 0.0, -0.02), (0.0, 0.0, 1.0), 1e5)
    sim = body.simulation(dt=2e-3, loads=[_gravity(body)], contact=contact, beta=0.001,
                          angular_velocity=(0.3, 0.2, 0.0))
    tracemalloc.start()
    try:
        # warm-up: compilation; then two traced windows of 200 steps. The interpreter's
        # own caches may grow once in either (measured in whole-suite runs: 240 and 248
        # bytes, once, not per step); a per-step allocation grows both
        for _ in range(250):
            sim.step()
        before, _ = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        sweeps = sim.total_sweeps
        for _ in range(200):
            sim.step()
        middle, _ = tracemalloc.get_traced_memory()
        for _ in range(200):
            sim.step()
        after, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert sim.total_sweeps - sweeps > 400  # the contact swept
    r = body.frame.r
    assert min(middle - before, after - middle) < 8 * r, (before, middle, after)
    assert peak - before < 8 * r * r / 2, (before, peak)


def test_compiled_kernels_are_cached_per_source_digest(monkeypatch, tmp_path):
    """Kernels compile into a folder named after a digest of lbshape's sources, so a
    change to any module (a callee's layout) cannot meet stale machine code."""
    import numba

    from lbshape import _jit
    from lbshape.io.cache import cache_root

    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    folder = _jit.kernel_cache_dir()
    assert folder.parent == cache_root() / "numba" and len(folder.name) == 16
    # set at import (under the cache root of that moment), named after the same digest
    assert os.path.basename(numba.config.CACHE_DIR) == folder.name
    monkeypatch.setenv("LBSHAPE_CACHE", str(tmp_path))
    assert _jit.kernel_cache_dir() == tmp_path / "numba" / folder.name
