"""docs/scenes.md's section on scenes built in code: its example builds a scene, and its
table explains every keyword of ``Scene.from_mesh``."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

from lbshape.scene.build import scene_from_mesh

ROOT = Path(__file__).resolve().parents[2]
TEXT = (ROOT / "docs" / "scenes.md").read_text(encoding="utf-8")
HEADING = "## 6. A scene built in code"


def _section() -> str:
    assert HEADING in TEXT, f"docs/scenes.md has no section {HEADING!r}"
    section = TEXT[TEXT.index(HEADING):]
    end = section.find("\n## ", len(HEADING))
    return section if end < 0 else section[:end]  # up to the next section


def test_the_example_builds_the_scene_it_describes():
    block = re.search(r"```python\n(.*?)```", _section(), flags=re.DOTALL)
    assert block is not None, "the section has no Python example"
    namespace: dict = {}
    exec(compile(block.group(1), "docs/scenes.md", "exec"), namespace)  # noqa: S102
    scene = namespace["scene"]
    assert scene.name == "my-bar"
    assert len(scene.examples.poses) == 2
    assert scene.simulation.dt == 0.005 and scene.simulation.steps == 200


def test_the_table_explains_every_keyword():
    keywords = list(inspect.signature(scene_from_mesh).parameters)
    rows = set(re.findall(r"^\| `(\w+)` \|", _section(), flags=re.MULTILINE))
    missing = [name for name in keywords if name not in rows]
    assert not missing, f"docs/scenes.md section 6 does not explain {missing}"
    unknown = sorted(rows - set(keywords))
    assert not unknown, f"docs/scenes.md section 6 explains keywords that do not exist: {unknown}"
