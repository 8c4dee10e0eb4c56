"""``[examples] stiffness = "auto"``: the default of new scenes, read and validated."""

from __future__ import annotations

import pytest

import lbshape
from lbshape.errors import LbshapeError
from lbshape.geometry.primitives import structured_box
from lbshape.scene import builtin_scene_names, load_scene
from lbshape.scene.reader import scene_from_dict
from lbshape.scene.schema import AUTO_STIFFNESS

#: the scenes whose numbers must stay (their results are the published ones)
FIXED_SCENES = ("bar-cuboid", "bar-cylinder", "cross", "teddy-global", "teddy-local", "demo")


def _document(**examples) -> dict:
    return {"object": {"shape": "demo-bar"}, "fixed": {"region": "z > 0.999"},
            "examples": {**examples, "pose": [{"shape": "demo-bar", "pose": "twist",
                                               "parameters": {"angle": 1.0}}]}}


def test_a_scene_without_a_stiffness_gets_auto():
    scene = scene_from_dict(_document(), name="new")
    assert scene.examples.stiffness == AUTO_STIFFNESS == "auto"
    assert scene.examples.auto and scene.examples.acts
    assert scene.runtime_fields()["k_ex"] == "auto"


def test_auto_is_spelled_out_and_a_number_stays_a_number():
    assert scene_from_dict(_document(stiffness="auto"), name="new").examples.auto
    numbered = scene_from_dict(_document(stiffness=300.0), name="new").examples
    assert numbered.stiffness == 300.0 and not numbered.auto and numbered.acts
    off = scene_from_dict(_document(stiffness=0.0), name="new").examples
    assert not off.auto and not off.acts


@pytest.mark.parametrize("value, message", [
    ("automatic", "'examples.stiffness' must be a number >= 0 (1/s^2) or \"auto\", got "
                  "'automatic'"),
    (-1.0, "'examples.stiffness' must be >= 0"),
    (True, "'examples.stiffness' must be a number"),
])
def test_a_bad_stiffness_is_a_one_line_error(value, message):
    with pytest.raises(LbshapeError) as caught:
        scene_from_dict(_document(stiffness=value), name="new")
    text = str(caught.value)
    assert message in text and "\n" not in text and text.startswith("scene new: ")


@pytest.mark.parametrize("name", FIXED_SCENES)
def test_the_built_in_scenes_keep_their_numbers(name):
    assert name in builtin_scene_names()
    examples = load_scene(name).examples
    assert not examples.auto and examples.stiffness > 0


def test_from_mesh_defaults_to_auto():
    box = structured_box((0.3, 0.05, 0.05), (6, 1, 1))
    arc = {"pose": "arc", "parameters": {"angle": 0.5, "axis": "x"}}
    scene = lbshape.Scene.from_mesh(box, fixed="x < 1e-6", examples=[arc])
    assert scene.examples.auto
    numbered = lbshape.Scene.from_mesh(box, fixed="x < 1e-6", examples=[arc],
                                       example_stiffness=250.0)
    assert numbered.examples.stiffness == 250.0
    assert lbshape.Scene.from_mesh(box, fixed="x < 1e-6").examples is None
