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
acts does.
"""

from __future__ import annotations

import numpy as np

from lbshape import __version__
from lbshape.geometry.shapes import MESHES_DIR, get_shape
from lbshape.io.cache import cache_key, file_digest
from lbshape.pipeline.precomputed import PIPELINE_VERSION
from lbshape.pipeline.responses import response_key
from lbshape.scene.schema import MeshSource, Scene

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
