"""The cache key of a scene's precompute: everything its result depends on.

:func:`scene_cache_key` digests :meth:`Scene.precompute_key_fields`, the gmsh scripts or
mesh files behind the meshes (their bytes), the package versions, what the basis's
responses depend on (:func:`lbshape.pipeline.responses.response_key`: each load's
type, region and vector — its size sets the static equilibria — and the k_ex the
example responses are shifted by), the precompute's fixed settings
(:data:`CUBATURE_TRAINING_POSES`, :data:`PRECOMPUTE_SEED`) and the artifact's format
(:data:`~lbshape.pipeline.precomputed.PIPELINE_VERSION`). So changing dt, steps, a
load's profile or damping never redoes the precompute, while changing any mesh byte,
material value, m, r, s, example, k_ex, or where, along what and how strongly a load
acts does. The artifact's file is named by the key alone (:data:`ARTIFACT_NAME`), not by
the scene.

:func:`stage_keys` keys each stage's own cache entry on what that stage reads, so a
changed scene re-runs only the stages that read the change and those after them (the
table: ``docs/scenes.md``, section 7).
"""

from __future__ import annotations

import numpy as np

from lbshape import __version__
from lbshape.elastic.basis import default_linear_modes
from lbshape.elastic.polynomial_forces import POLYNOMIAL_BUILD_FLOPS
from lbshape.geometry.hull_directions import GROUP_ANGLE_DEG, MAX_FACES
from lbshape.geometry.shapes import MESHES_DIR, get_shape
from lbshape.io.cache import cache_key, file_digest
from lbshape.pipeline.impact_columns import (
    MIN_THROW_SPEED,
    THROW_CLEAR_STEPS,
    THROW_MAX_STEPS,
    THROW_SPEED_MARGIN,
)
from lbshape.pipeline.precomputed import PIPELINE_VERSION
from lbshape.pipeline.responses import (
    EXAMPLE_RESPONSE_DEPTH,
    example_response_stiffness,
    response_key,
)
from lbshape.scene.schema import ExamplePose, MeshSource, Scene
from lbshape.shapespace.auto_stiffness import AUTO_RULE

#: training poses for the elastic cubature (held-out poses: half as many)
CUBATURE_TRAINING_POSES = 120
#: seed of every random choice of the precompute (training poses, candidates)
PRECOMPUTE_SEED = 20170401


def scene_cache_key(scene: Scene) -> str:
    """The cache key of a scene's precompute (see the module docstring)."""
    import dolfinx

    sources = [_source_digest(scene.object)]
    if scene.examples is not None:
        sources += [_source_digest(p.source) for p in scene.examples.poses]
    return cache_key(
        "precompute", scene.precompute_key_fields(), response_key(scene), sources,
        {"lbshape": __version__, "dolfinx": dolfinx.__version__, "numpy": np.__version__},
        CUBATURE_TRAINING_POSES, PRECOMPUTE_SEED, PIPELINE_VERSION,
    )


def _source_digest(source: MeshSource) -> dict:
    """The mesh source's key plus the digest of the gmsh script behind a shape."""
    key = dict(source.key())
    if source.shape is not None:
        spec = get_shape(source.shape)
        key["script_sha256"] = file_digest(MESHES_DIR / spec.script)
        key["size_used"] = source.size if source.size is not None else spec.default_size
    return key


#: the cache entry's name: the artifact is named by its key alone (a renamed scene of
#: identical content finds it)
ARTIFACT_NAME = "precompute"
#: each stage's code version: bump one when its algorithm changes its result (its entries
#: and those of the stages after it are then recomputed)
STAGE_VERSIONS = {"mesh": 1, "modes": 1, "derivatives": 2, "basis": 1, "lb": 1,
                  "examples": 1, "target-table": 1, "lb-cubature": 1, "regions": 1,
                  "static-equilibria": 1, "example-stiffness": 2, "example-basis": 3,
                  "impact-basis": 3, "cubature": 1, "forces": 1, "projections": 1,
                  "frame": 1, "estimate": 2}


def load_key(scene: Scene) -> list[dict]:
    """What a stage that reads the loads sees of them: type, selection and vector (the
    profile, dt and steps matter only at run time)."""
    return response_key(scene)["loads"]


def example_label(pose: ExamplePose) -> str:
    """How messages and the artifact name an example: its mesh source and pose."""
    source = pose.source.label
    if pose.parts:
        return f"{source}:parts({', '.join(part.pose for part in pose.parts)})"
    return f"{source}:{pose.pose}" if pose.pose else str(source)


def impact_throw_key(scene: Scene) -> dict:
    """What the ``impact-basis`` stage's throws read of the scene besides the mesh,
    material, shape space and k_ex: the planes, gravity and initial motion (the throw
    speed), the step, integrator and damping, the example ramp, and the throws'
    constants."""
    runtime = scene.runtime_fields()
    return {name: runtime[name] for name in ("planes", "initial", "dt", "integrator",
                                             "damping")} | {
        "gravity": [list(load.vector) for load in scene.loads if load.type == "gravity"],
        "ramp": 0.0 if scene.examples is None else float(scene.examples.ramp),
        "constants": [THROW_MAX_STEPS, THROW_CLEAR_STEPS, MIN_THROW_SPEED,
                      THROW_SPEED_MARGIN, GROUP_ANGLE_DEG, MAX_FACES]}


def stage_keys(scene: Scene, names: list[str], settings: list) -> dict[str, str]:
    """The cache key of each stage in ``names`` (:func:`~lbshape.pipeline.precompute.
    stage_names`): a digest of exactly the scene inputs the stage reads, the keys of the
    stages whose results it takes, the stage's code version and the packages' versions;
    ``settings``: the precompute's constants (``[CLAMPED_TARGETS, MAX_APPENDED_BASIS,
    MAX_APPENDED_FREE_BODY, MIN_APPENDED_FREE_BODY, STATIC_EQUILIBRIA_MAX_VERTICES]`` of
    :mod:`lbshape.pipeline.precompute`), read by the stages after the basis and the targets.

    So a new load re-runs ``derivatives`` (the static responses share its factorisation)
    and the stages after the basis; dt, steps, a load's profile and damping re-run none.
    """
    import dolfinx

    versions = {"lbshape": __version__, "dolfinx": dolfinx.__version__,
                "numpy": np.__version__, "pipeline": PIPELINE_VERSION}
    keys: dict[str, str] = {}

    def key(name: str, *reads) -> str:
        if name in names:
            keys[name] = cache_key("stage", name, STAGE_VERSIONS[name], versions, list(reads))
        return keys.get(name)

    fields, reduced, loads = scene.precompute_key_fields(), scene.reduced, load_key(scene)
    material = fields["material"]
    examples = [] if scene.examples is None else [
        {**pose.key(), "source": _source_digest(pose.source)} for pose in scene.examples.poses]
    mesh = key("mesh", _source_digest(scene.object), fields["fixed"])
    modes = key("modes", mesh, material, reduced.linear_modes or default_linear_modes(reduced.r))
    derivatives = key("derivatives", mesh, modes, material, None if scene.is_free else loads)
    basis = key("basis", modes, derivatives, reduced.r)
    lb = key("lb", mesh, reduced.m)
    embedded = key("examples", mesh, lb, examples)
    targets = key("target-table", mesh, lb, embedded, material, settings[0])
    shape = [lb, embedded, targets, key(
        "lb-cubature", mesh, lb, embedded, targets, material, reduced.s,
        reduced.cubature_tolerance, PRECOMPUTE_SEED), key(
        "regions", mesh, lb, material, examples, fields["regions"])]
    current = key("static-equilibria", basis, modes, derivatives, material, loads,
                  settings) or basis
    auto = key("example-stiffness", current, modes, derivatives, material, loads, shape,
               list(AUTO_RULE))
    k_ex = auto or example_response_stiffness(scene)
    current = key("example-basis", current, modes, derivatives, material, shape, k_ex,
                  settings, EXAMPLE_RESPONSE_DEPTH, POLYNOMIAL_BUILD_FLOPS,
                  reduced.forces) or current
    arrangement = [reduced.impact_columns_per] if reduced.sets_per_feature else []
    current = key("impact-basis", current, mesh, material, reduced.impact_columns,
                  impact_throw_key(scene), shape, k_ex, *arrangement) or current
    cubature = key("cubature", current, mesh, material, reduced.s,
                   reduced.cubature_tolerance, CUBATURE_TRAINING_POSES, PRECOMPUTE_SEED)
    key("forces", cubature, mesh, material, reduced.forces)
    key("projections", cubature, mesh, material, shape,
        [] if scene.examples is None else [example_label(p) for p in scene.examples.poses])
    key("frame", cubature, mesh, material)
    # the error estimate's operators: the final U (out of the cubature stage), the mesh
    # and its fixed vertices, the material and the loads' patterns
    key("estimate", cubature, mesh, material, loads)
    return keys
