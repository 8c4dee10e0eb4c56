"""docs/scenes.md's section on scenes built in code: its example builds a scene, and its
table explains every keyword of ``Scene.from_mesh``; its CAD scene in millimetres runs."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import pytest

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


OCCT = Path("/usr/share/opencascade/data")


@pytest.mark.slow
@pytest.mark.skipif(not OCCT.is_dir(), reason="Debian package occt-misc not installed "
                    "(scripts/setup installs it): the wedge's BREP file is missing")
def test_the_millimetre_cad_scene_runs_end_to_end_with_auto_stiffness(tmp_path, capsys):
    from lbshape.cli.main import main as cli_main

    block = re.search(r"```toml\n(# wedge\.toml.*?)```", TEXT, flags=re.DOTALL)
    assert block is not None, "docs/scenes.md has no wedge.toml example"
    scene = tmp_path / "wedge.toml"
    scene.write_text(block.group(1), encoding="utf-8")
    assert 'units = "mm"' in block.group(1) and 'stiffness = "auto"' in block.group(1)
    assert "lbshape precompute wedge.toml" in TEXT
    assert cli_main(["precompute", str(scene)]) == 0
    out = capsys.readouterr()
    printed = out.out + out.err
    assert "n=302 vertices, 962 tets" in printed  # 8 x 10 x 10 mm at h = 2 mm, in metres
    assert "example stiffness auto: k_ex = " in printed
    assert cli_main(["simulate", str(scene), "--out", str(tmp_path / "run")]) == 0
    out = capsys.readouterr()
    printed = out.out + out.err
    change = re.search(r"visible change ([\d.]+) % of the bounding-box diagonal, closest: "
                       r"example 0", printed)
    assert change is not None, printed[-2000:]
    assert float(change.group(1)) >= 5.0
