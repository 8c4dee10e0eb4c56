"""Variants of a scene, each written once: the same scene with one setting changed.

* :func:`without_examples` / :func:`with_stiffness` — the example force off (``k_ex = 0``)
  or at another stiffness (same precompute);
* :func:`with_reduced` — other ``[reduced]`` m, r, s (and force model);
* :func:`with_step` — another time step over a given duration;
* :func:`scaled_scene` — a built-in scene's TOML with another object size, written to a file;
* :func:`with_throw`, :func:`with_contact_stiffness`, :func:`with_mesh_size` — a free body
  thrown faster or slower, its contact planes stiffer or softer, its mesh finer (the
  reference's noise floor);
* :func:`impact_scene` — a designed impact: the body thrown at one plane of a given normal.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path

import numpy as np

from lbshape.errors import LbshapeError
from lbshape.geometry.shapes import get_shape
from lbshape.io.toml_writer import dumps
from lbshape.scene.reader import builtin_scene_names, load_scene
from lbshape.scene.schema import IMPACT_COLUMN_SETS, Scene


def without_examples(scene: Scene) -> Scene:
    """The same scene with the example force switched off (``k_ex = 0``, same precompute)."""
    if scene.examples is None:
        return scene
    return dataclasses.replace(scene, examples=dataclasses.replace(scene.examples, stiffness=0.0))


def with_stiffness(scene: Scene, stiffness: float) -> Scene:
    """The same scene with example stiffness ``k_ex`` = ``stiffness`` (1/s²)."""
    if scene.examples is None:
        raise LbshapeError(f"scene {scene.name} has no examples")
    if not (math.isfinite(stiffness) and stiffness >= 0.0):
        raise LbshapeError(f"example stiffness must be finite and >= 0, got {stiffness}")
    return dataclasses.replace(scene, examples=dataclasses.replace(scene.examples,
                                                                   stiffness=float(stiffness)))



def with_reduced(scene: Scene, m: int, r: int, s: int, forces: str | None = None) -> Scene:
    """The scene with ``[reduced]`` m, r, s (and ``forces`` unless None: the scene's); linear
    modes beyond the new r are dropped."""
    red = scene.reduced
    linear = red.linear_modes if red.linear_modes <= r else 0
    return dataclasses.replace(
        scene, reduced=dataclasses.replace(red, m=int(m), r=int(r), s=int(s),
                                           linear_modes=linear,
                                           forces=red.forces if forces is None else forces))


def with_impact_columns(scene: Scene, count: int, per: str = "body") -> Scene:
    """The scene with ``reduced.impact_columns`` = ``count`` (0: none) arranged ``per``
    ``"body"`` (one set), ``"feature"`` (``count`` for each hull feature) or
    ``"feature-pair"`` (both features' for each pair of neighbouring features)."""
    if per not in IMPACT_COLUMN_SETS or count < 0 or (per != "body" and not count):
        raise LbshapeError(f"impact columns: {count} per {per!r} (per one of "
                           f"{IMPACT_COLUMN_SETS}, sets per feature need count > 0)")
    return dataclasses.replace(scene, reduced=dataclasses.replace(
        scene.reduced, impact_columns=int(count), impact_columns_per=per))


def with_step(scene: Scene, dt: float, duration: float) -> Scene:
    """``scene`` stepped at ``dt`` (s) for ``duration`` (s), rounded to whole steps."""
    steps = max(1, int(round(duration / dt)))
    return dataclasses.replace(scene, simulation=dataclasses.replace(
        scene.simulation, dt=float(dt), steps=steps))



def scaled_scene(base: str, size: float, folder: Path, *, r: int | None = None) -> Path:
    """Write the scene ``base`` (a built-in name) with ``[object] size = size`` to
    ``folder`` and return the TOML path (named ``<base>-h<size>``; with ``r``, its
    ``[reduced] r`` set to it and ``-r<r>`` appended to the name).

    Every size keeps the cubature force model (``reduced.forces = "cubature"``): the
    exact polynomial forces' build grows as t r⁴ and ``auto`` leaves them for large
    meshes, so a study of cost against mesh size compares one force model at every size.
    """
    if base not in builtin_scene_names():
        raise LbshapeError(f"--scaling needs a built-in scene, got {base!r}; valid names: "
                           f"{', '.join(builtin_scene_names())}")
    if not (isinstance(size, int | float) and 0 < size < np.inf):
        raise LbshapeError(f"object sizes must be finite and > 0, got {size!r}")
    path = Path(load_scene(base).source)
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    if "shape" not in data.get("object", {}):
        raise LbshapeError(f"scene {base!r}: its object is not a built-in shape with a size")
    data["name"] = f"{base}-h{size:g}" + ("" if r is None else f"-r{int(r)}")
    data["object"]["size"] = float(size)
    data.setdefault("reduced", {})["forces"] = "cubature"
    if r is not None:
        data["reduced"]["r"] = int(r)
    target = folder / f"{data['name']}.toml"
    target.write_text(dumps(data), encoding="utf-8")
    return target



def with_throw(scene: Scene, factor: float) -> Scene:
    """A free body's ``[initial]`` velocity and angular velocity times ``factor``."""
    initial = scene.initial
    return dataclasses.replace(scene, initial=dataclasses.replace(
        initial, velocity=tuple(factor * v for v in initial.velocity),
        angular_velocity=tuple(factor * w for w in initial.angular_velocity)))


def with_contact_stiffness(scene: Scene, factor: float) -> Scene:
    """Every contact plane's penalty stiffness times ``factor`` (> 0)."""
    if not (math.isfinite(factor) and factor > 0):
        raise LbshapeError(f"a stiffness factor must be > 0, got {factor}")
    return dataclasses.replace(scene, planes=tuple(
        dataclasses.replace(plane, stiffness=factor * plane.stiffness)
        for plane in scene.planes))


def with_mesh_size(scene: Scene, factor: float) -> Scene:
    """The scene with its object's built-in shape meshed at ``factor`` (> 0) times its size
    (the scene's, else the shape's default); example poses of the same shape at the same
    size follow (same topology as the object, as in the scene), others keep theirs.

    Raises:
        LbshapeError: the object is not a built-in shape, or the factor is not > 0.
    """
    if not (math.isfinite(factor) and factor > 0):
        raise LbshapeError(f"a mesh size factor must be > 0, got {factor}")
    source = scene.object
    if source.shape is None:
        raise LbshapeError(f"scene {scene.name!r}: its object is not a built-in shape, so "
                           f"it has no mesh size to refine")
    size = source.size if source.size is not None else get_shape(source.shape).default_size
    refined = dataclasses.replace(source, size=factor * size)
    examples = scene.examples
    if examples is not None:
        examples = dataclasses.replace(examples, poses=tuple(
            dataclasses.replace(pose, source=refined) if pose.source == source else pose
            for pose in examples.poses))
    return dataclasses.replace(scene, object=refined, examples=examples)


def impact_scene(scene: Scene, points: np.ndarray, normal, speed: float, gap: float,
                 name: str) -> Scene:
    """A designed impact: the free body of ``scene`` (rest points ``points`` (n, 3), m)
    thrown at ``speed`` (m/s) along −``normal`` at one plane, normal ``normal`` (made
    unit), ``gap`` (m) beyond the body's extreme point in −normal, without loads (no
    gravity: the impact alone) and without spin; the scene's first plane's stiffness and
    friction. The steps and dt are the scene's."""
    normal = np.asarray(normal, dtype=float)
    normal = normal / np.linalg.norm(normal)
    if not scene.planes or not scene.is_free:
        raise LbshapeError(f"scene {scene.name}: a designed impact needs a free body and a plane")
    if not (speed > 0 and gap > 0):
        raise LbshapeError(f"impact speed and gap must be > 0, got {speed} and {gap}")
    support = np.asarray(points, dtype=float) @ normal
    point = tuple(float(v) for v in (support.min() - gap) * normal)
    plane = dataclasses.replace(scene.planes[0], point=point,
                                normal=tuple(float(v) for v in normal))
    initial = dataclasses.replace(scene.initial,
                                  velocity=tuple(float(v) for v in -speed * normal),
                                  angular_velocity=(0.0, 0.0, 0.0))
    return dataclasses.replace(scene, name=name, planes=(plane,), loads=(),
                               initial=initial)
