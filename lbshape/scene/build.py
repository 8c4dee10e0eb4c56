"""Scenes built in code: a mesh in memory and keyword settings to a validated :class:`Scene`.

:func:`scene_from_mesh` (also ``Scene.from_mesh``) writes nothing and reads no file: the
object's mesh is held in the scene (:attr:`MeshSource.mesh`, keyed in the precompute's
cache by its arrays' digest). The settings take the shapes of the scene file's tables
(:mod:`lbshape.scene.schema`), as Python values, and are validated by the same code as a
file (:func:`lbshape.scene.reader.scene_from_dict`): one set of checks, the same one-line
:class:`~lbshape.errors.LbshapeError` naming the setting, e.g.
``scene clip: 'material.poisson' must be ...``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.scene.reader import scene_from_dict
from lbshape.scene.schema import Scene, Simulation

__all__ = ["as_tet_mesh", "scene_from_mesh"]

#: what an example may be in :func:`scene_from_mesh`'s ``examples``
ExampleSpec = Mapping[str, Any] | TetMesh | np.ndarray | tuple


def scene_from_mesh(
    mesh: TetMesh | tuple[np.ndarray, np.ndarray],
    *,
    name: str = "mesh",
    description: str = "",
    fixed: str | Mapping[str, str] | None = None,
    material: Any = None,
    damping: Any = None,
    reduced: Any = None,
    examples: Sequence[ExampleSpec] = (),
    example_stiffness: float | str = "auto",
    loads: Sequence[Mapping[str, Any]] = (),
    planes: Sequence[Mapping[str, Any]] = (),
    regions: Sequence[Mapping[str, Any]] = (),
    initial: Any = None,
    dt: float = Simulation.dt,
    steps: int = Simulation.steps,
    integrator: str = Simulation.integrator,
    contact_dt: float | None = None,
    flight_dt: float | None = None,
) -> Scene:
    """A scene built in code around a mesh in memory (no file needed).

    Args:
        mesh: the object: a :class:`~lbshape.geometry.mesh.TetMesh`, or ``(points, tets)``
            arrays, (n, 3) float in m and (t, 4) int; checked as a mesh file is
            (:func:`~lbshape.geometry.mesh.check_mesh`). There is no ``units``: the
            arrays are already in metres (scale them before, e.g. ``points * 1e-3``
            for millimetres; ``lbshape.read_mesh(path, units="mm")`` reads a file so).
        name, description: the scene's name (outputs, messages) and free text.
        fixed: the fixed vertices: a region expression in x, y, z (m), e.g.
            ``"z < 0.01"``, or ``{"group": name}`` (a vertex group of ``mesh``) /
            ``{"region": expression}``; ``None``: a free body.
        material: a :class:`~lbshape.elastic.materials.Material` or a mapping of its
            fields (``model``, ``young`` Pa, ``poisson``, ``density`` kg/m³); ``None``:
            the defaults.
        damping: Rayleigh ``{"alpha": 1/s, "beta": s}`` (or a ``Damping``); ``None``: none.
        reduced: ``{"m", "r", "s", ...}`` (or a ``Reduced``), the scene file's ``[reduced]``.
        examples: the example poses, each one of
            * a mapping as a scene file's ``[[examples.pose]]`` table; without ``shape``
              or ``mesh`` it poses the object's own mesh, e.g.
              ``{"pose": "twist", "parameters": {"angle": 1.2}}`` (poses of
              :data:`lbshape.geometry.poses.POSES`: ``twist``, ``arc``, ``s-bend``);
              its ``mesh``/``rest`` may be meshes in memory;
            * a posed copy of the object: a ``TetMesh`` with the object's tetrahedra,
              ``(points, tets)``, or the posed points alone, (n, 3) m.
        example_stiffness: k_ex in 1/s² (>= 0), or ``"auto"`` (the default: set by the
            precompute, :mod:`lbshape.shapespace.auto_stiffness`).
        loads: mappings as ``[[loads]]``, e.g. ``{"type": "gravity", "vector": [0, 0, -9.81]}``.
        planes: mappings as ``[[planes]]`` (contact planes).
        regions: mappings as ``[[regions]]`` (local examples).
        initial: a free body's ``{"velocity": m/s, "angular_velocity": rad/s}``.
        dt, steps, integrator: the time step (s), the scene's number of steps (the CLI's
            default run length), ``"newmark"`` or ``"backward-euler"``.
        contact_dt, flight_dt: a free body's longest step in contact (``None``: 1/3 ms)
            and in flight (``None``: the one that resolves its highest frequency), s.

    Raises:
        LbshapeError: one line naming the bad setting (the scene file's key path).
    """
    label = f"scene {name}"
    obj = as_tet_mesh(mesh, what=f"{label}: mesh")
    data: dict[str, Any] = {
        "name": name, "description": description, "object": {"mesh": obj},
        "simulation": _simulation_table(dt, steps, integrator, contact_dt, flight_dt),
    }
    for key, value in (("material", material), ("damping", damping), ("reduced", reduced),
                       ("initial", initial)):
        if value is not None:
            data[key] = _plain(value)
    if fixed is not None:
        data["fixed"] = {"region": fixed} if isinstance(fixed, str) else _plain(fixed)
    if isinstance(examples, Mapping | TetMesh | np.ndarray):
        raise LbshapeError(f"{label}: 'examples' must be a list of example poses")
    if examples or example_stiffness != "auto":
        data["examples"] = _examples_table(examples, example_stiffness, obj, label)
    for key, value in (("loads", loads), ("planes", planes), ("regions", regions)):
        if value:
            data[key] = _plain(list(value))
    return scene_from_dict(data, name=name, label=label)


def _simulation_table(dt, steps, integrator: str, contact_dt, flight_dt) -> dict[str, Any]:
    """The scene file's ``[simulation]`` table of :func:`scene_from_mesh`'s keywords."""
    table = {"dt": _plain(dt), "steps": _plain(steps), "integrator": integrator}
    for key, value in (("contact_dt", contact_dt), ("flight_dt", flight_dt)):
        if value is not None:
            table[key] = _plain(value)
    return table


def _examples_table(examples: Sequence[ExampleSpec], example_stiffness, obj: TetMesh,
                    label: str) -> dict[str, Any]:
    """The scene file's ``[examples]`` table of :func:`scene_from_mesh`'s keywords."""
    if example_stiffness is None:  # the keyword's name, not the file's key path
        raise LbshapeError(f"{label}: example_stiffness must be a number >= 0 or \"auto\"")
    return {"stiffness": _plain(example_stiffness),
            "pose": [_example(entry, obj, f"{label}: examples[{k}]")
                     for k, entry in enumerate(examples)]}


def as_tet_mesh(value: Any, *, what: str = "mesh") -> TetMesh:
    """A :class:`TetMesh` from a mesh or ``(points, tets)`` arrays (not yet checked).

    Raises:
        LbshapeError: anything else, or arrays that are not numbers.
    """
    if isinstance(value, TetMesh):
        return value
    if isinstance(value, tuple | list) and len(value) == 2:
        try:
            points = np.asarray(value[0], dtype=np.float64)
            tets = np.asarray(value[1])
        except (TypeError, ValueError) as exc:
            raise LbshapeError(f"{what}: (points, tets) must be numeric arrays ({exc})") from None
        if tets.dtype.kind not in "iu" or tets.ndim != 2 or tets.shape[1:] != (4,):
            raise LbshapeError(f"{what}: tets must be a (t, 4) integer array, got "
                               f"{tets.dtype} {tets.shape}")
        return TetMesh(points, tets.astype(np.int64))
    raise LbshapeError(f"{what}: expected a TetMesh or (points, tets) arrays, got "
                       f"{type(value).__name__}")


def _example(entry: ExampleSpec, obj: TetMesh, what: str) -> dict:
    """A ``[[examples.pose]]`` table of an example given in code."""
    if isinstance(entry, Mapping):
        table = {key: (value if key in ("mesh", "rest") else _plain(value))
                 for key, value in entry.items()}
        for key in ("mesh", "rest"):
            if key in table and not isinstance(table[key], str):
                table[key] = _posed_mesh(table[key], obj, f"{what}.{key}")
        if "mesh" not in table and "shape" not in table:
            table["mesh"] = obj
        return table
    return {"mesh": _posed_mesh(entry, obj, what)}


def _posed_mesh(value: Any, obj: TetMesh, what: str) -> TetMesh:
    """A posed mesh: a mesh, ``(points, tets)``, or (n, 3) points on the object's tets."""
    if isinstance(value, np.ndarray) and value.ndim == 2 and value.shape[1:] == (3,):
        if value.shape != obj.points.shape:
            raise LbshapeError(f"{what}: posed points must have the object's shape "
                               f"{obj.points.shape}, got {value.shape}")
        return obj.with_points(value)
    return as_tet_mesh(value, what=what)


def _plain(value: Any) -> Any:
    """Python values as a parsed scene file holds them: dataclasses and mappings as dicts,
    tuples and arrays as lists, numpy scalars as numbers (meshes kept)."""
    if isinstance(value, TetMesh):
        return value
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        return {str(key): _plain(item) for key, item in value.items()}
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, list | tuple):
        return [_plain(item) for item in value]
    if isinstance(value, np.generic):
        return value.item()
    return value
