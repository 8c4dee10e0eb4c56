"""ParaView-readable trajectories: one ``.vtu`` per saved frame plus a ``.pvd`` index.

Each frame holds the deformed positions and a ``displacement`` point field (m).
Frames are written atomically; the ``.pvd`` collection is rewritten (atomically)
on every :meth:`TrajectoryWriter.close`, so a run stopped early still leaves a
valid, readable trajectory of what was computed.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING
from xml.sax.saxutils import quoteattr

import numpy as np

from lbshape.io.atomic import write_atomic, write_text_atomic

if TYPE_CHECKING:  # io sits below every concept package; the mesh type is only an annotation
    from lbshape.geometry.mesh import TetMesh


class TrajectoryWriter:
    """Write frames of a displacement field on a fixed mesh.

    Args:
        folder: output folder (created).
        mesh: the rest mesh (n vertices).
        name: file stem of the ``.pvd`` and frames.
    """

    def __init__(self, folder: str | Path, mesh: TetMesh, *, name: str = "trajectory"):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.mesh = mesh
        self.name = name
        self._frames: list[tuple[float, str]] = []

    @property
    def pvd_path(self) -> Path:
        return self.folder / f"{self.name}.pvd"

    def write(self, time: float, displacement: np.ndarray) -> Path:
        """Save a frame at ``time`` (s) with displacement (n,3) or (3n,) in m."""
        import meshio

        u = np.asarray(displacement, dtype=float).reshape(-1, 3)
        frame = f"{self.name}_{len(self._frames):05d}.vtu"
        data = meshio.Mesh(
            self.mesh.points + u, [("tetra", self.mesh.tets)], point_data={"displacement": u}
        )
        path = write_atomic(self.folder / frame,
                            lambda tmp: meshio.write(tmp, data, file_format="vtu"))
        self._frames.append((float(time), frame))
        return path

    def close(self) -> Path:
        """Write the ``.pvd`` collection of the frames so far; return its path."""
        lines = ['<?xml version="1.0"?>',
                 '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">',
                 "  <Collection>"]
        lines += [f'    <DataSet timestep="{t:.9g}" part="0" file={quoteattr(f)}/>'
                  for t, f in self._frames]
        lines += ["  </Collection>", "</VTKFile>", ""]
        return write_text_atomic(self.pvd_path, "\n".join(lines))

    @property
    def frame_count(self) -> int:
        return len(self._frames)
