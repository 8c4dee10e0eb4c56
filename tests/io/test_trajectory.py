"""Trajectory files are ParaView-readable and hold what was written."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import meshio
import numpy as np

from lbshape.geometry.primitives import structured_box
from lbshape.io.trajectory import TrajectoryWriter


def test_frames_and_collection_round_trip(tmp_path):
    mesh = structured_box((1, 1, 2), (1, 1, 2))
    writer = TrajectoryWriter(tmp_path / "run", mesh)
    fields = [np.full((mesh.n_vertices, 3), 0.1 * k) for k in range(3)]
    for k, u in enumerate(fields):
        writer.write(0.01 * k, u.ravel())
    pvd = writer.close()
    entries = ET.parse(pvd).getroot().findall("./Collection/DataSet")
    assert [float(e.get("timestep")) for e in entries] == [0.0, 0.01, 0.02]
    last = meshio.read(pvd.parent / entries[-1].get("file"))
    np.testing.assert_allclose(last.point_data["displacement"], fields[-1])
    np.testing.assert_allclose(last.points, mesh.points + fields[-1])
    assert not list((tmp_path / "run").glob("tmp*"))
