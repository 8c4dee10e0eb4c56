"""The examples of a scene with local examples, each built once, and their parts.

:class:`ExampleParts` serves the ``regions`` stage
(:func:`lbshape.shapespace.local_build.build_local_space`): each example's rest and posed
meshes (:func:`~lbshape.pipeline.meshes.example_meshes`, built once each), the part of
an example a region selects, and an example's pose on the object's own region.
"""

from __future__ import annotations

import functools

import numpy as np

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.pipeline.meshes import build_mesh, example_meshes, posed_part
from lbshape.pipeline.precompute_key import example_label
from lbshape.scene.schema import Scene
from lbshape.shapespace.local_build import RegionSpec
from lbshape.shapespace.local_regions import region_cells, submesh


class ExampleParts:
    """The examples' meshes, built once each, and their parts selected by a region."""

    def __init__(self, scene: Scene, mesh: TetMesh):
        self.poses = scene.examples.poses
        self.mesh = mesh
        self._meshes: dict[int, tuple[TetMesh, TetMesh]] = {}  # example -> (rest, posed)
        self._build = functools.cache(build_mesh)  # examples often pose one mesh

    def meshes(self, k: int) -> tuple[TetMesh, TetMesh]:
        """Example k's (rest, posed) meshes."""
        if k not in self._meshes:
            try:
                self._meshes[k] = example_meshes(self.poses[k], self.mesh, build=self._build)
            except LbshapeError as exc:
                raise LbshapeError(
                    f"example {k} ({example_label(self.poses[k])}): {exc}") from None
        return self._meshes[k]

    def example_part(self, k: int, spec: RegionSpec) -> tuple[TetMesh, np.ndarray]:
        """The region's part of example k's rest mesh and its posed positions."""
        rest, posed = self.meshes(k)
        what = f"region '{spec.name}' on example {k} ({example_label(self.poses[k])})"
        cells = region_cells(rest, group=spec.group, region=spec.region, what=what)
        part, vertices = submesh(rest, cells, what=what)
        return part, posed_part(self.poses[k], part, vertices, posed)

    def object_pose(self, k: int, part: TetMesh, vertices: np.ndarray) -> np.ndarray:
        """Example k's pose on the object's own region (representation measurement):
        an analytic pose applied to the region, a posed copy of the object's positions,
        or the region at rest for an example at rest.

        Raises:
            LbshapeError: an example whose pose lives on its own mesh only (a posed file
                with its own rest, or an example posed part by part).
        """
        pose = self.poses[k]
        if pose.parts or (pose.is_posed_file and pose.rest is not None):
            raise LbshapeError("an example posed on its own mesh (a posed file with its "
                               "rest, or part by part) has no pose on the object's mesh")
        if pose.pose is None and not pose.is_posed_file:
            return part.points
        _, posed = self.meshes(k)
        return posed_part(pose, part, vertices, posed)
