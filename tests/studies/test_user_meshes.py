"""The user's-own-mesh scene lives in the package: the tests and the large-steps script
build it from :mod:`lbshape.studies.user_meshes`, neither loads the tests' helpers."""

from __future__ import annotations

from pathlib import Path

import conftest

from lbshape.studies.user_meshes import user_mesh_scene

ROOT = Path(__file__).resolve().parents[2]


def test_user_mesh_scene_reads_its_written_file(tmp_path):
    scene = user_mesh_scene(tmp_path)
    assert scene.object.mesh_file == (tmp_path / "l-beam.msh").resolve()
    assert scene.object.mesh_file.is_file()
    assert [pose.pose for pose in scene.examples.poses] == ["twist", "arc"]


def test_one_builder_for_the_tests_and_the_script():
    assert conftest.user_mesh_scene is user_mesh_scene
    script = (ROOT / "scripts" / "bench_large_steps.py").read_text(encoding="utf-8")
    assert "conftest" not in script
    assert "from lbshape.studies.user_meshes import user_mesh_scene" in script
