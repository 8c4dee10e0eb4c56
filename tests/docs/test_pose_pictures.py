"""scripts/pose_pictures.py draws one picture per pose, and docs/scenes.md shows each."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from lbshape.geometry.poses import POSE_PARAMETERS, POSES

ROOT = Path(__file__).resolve().parents[2]


def _script():
    spec = importlib.util.spec_from_file_location("pose_pictures",
                                                  ROOT / "scripts" / "pose_pictures.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_scenes_doc_shows_and_explains_every_pose():
    text = (ROOT / "docs" / "scenes.md").read_text(encoding="utf-8")
    for name in POSES:
        assert f"images/pose_{name}.png" in text, f"docs/scenes.md shows no picture of {name}"
        assert (ROOT / "docs" / "images" / f"pose_{name}.png").exists()
    for name in {p for params in POSE_PARAMETERS.values() for p in params}:
        assert f"| `{name}` |" in text, f"docs/scenes.md does not explain pose parameter {name}"


def test_pose_pictures_are_drawn(tmp_path):
    written = _script().draw(tmp_path)
    assert sorted(p.name for p in written) == sorted(f"pose_{name}.png" for name in POSES)
    for path in written:
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
