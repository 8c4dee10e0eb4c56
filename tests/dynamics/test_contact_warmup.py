"""A free body's contact kernels load at its set-up (:mod:`lbshape.dynamics.contact_warmup`):
in a fresh process, a bar dropped onto a floor loads no compiled kernel from its first
step on, where without the probe its first contact loads them (a stall of a live run);
the run is the same bit for bit with and without the probe."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from lbshape.pipeline import simulate
from lbshape.pipeline.precompute import precompute
from lbshape.scene.reader import scene_from_dict

#: a bar 5 cm above a floor with friction, falling onto it at 1 m/s
DROPPED = {
    "object": {"shape": "demo-bar"},
    "material": {"young": 1e6, "density": 1000.0},
    "reduced": {"m": 4, "r": 8, "s": 20},
    "planes": [{"point": [0.0, 0.0, -0.05], "normal": [0.0, 0.0, 1.0], "stiffness": 1e5,
                "friction": 0.4}],
    "initial": {"velocity": [0.0, 0.0, -1.0]},
    "simulation": {"dt": 1e-3, "steps": 150},
}

#: run in a fresh process: the kernels of lbshape.dynamics that the run itself loads
_CHILD = """
import importlib, json, pkgutil, sys
import lbshape.dynamics
from lbshape.pipeline import simulate
from lbshape.pipeline.precompute import precompute
from lbshape.scene.reader import scene_from_dict

if sys.argv[1] == "off":
    simulate.warm_contact = lambda body: None
scene = scene_from_dict(json.loads(sys.argv[2]), name="dropped")
pre = precompute(scene, progress=False)
engine = simulate.reduced_simulation(scene, pre)

def loaded():
    out = {}
    for info in pkgutil.iter_modules(lbshape.dynamics.__path__):
        module = importlib.import_module("lbshape.dynamics." + info.name)
        for name, value in vars(module).items():
            if hasattr(value, "py_func") and hasattr(value, "signatures"):
                out[info.name + "." + name] = len(value.signatures)
    return out

before = loaded()
touched = 0
for _ in range(scene.simulation.steps):
    engine.step()
    touched += engine.contact.scalars[1] > 0
after = loaded()
print(json.dumps({"touched": int(touched),
                  "loaded": sorted(k for k in after if after[k] > before.get(k, 0))}))
"""


def _kernels_the_run_loads(probe: bool) -> dict:
    out = subprocess.run([sys.executable, "-c", _CHILD, "on" if probe else "off",
                          json.dumps(DROPPED)], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_the_first_contact_loads_no_kernel_after_the_probe():
    pytest.importorskip("numba")
    without, with_probe = _kernels_the_run_loads(False), _kernels_the_run_loads(True)
    assert without["touched"] > 10 and with_probe["touched"] == without["touched"]
    assert any("contact" in name for name in without["loaded"]), without
    assert with_probe["loaded"] == [], with_probe


def test_the_probe_leaves_the_run_bit_for_bit(monkeypatch):
    scene = scene_from_dict(DROPPED, name="dropped")
    pre = precompute(scene, progress=False)
    runs = []
    for probe in (False, True):
        if not probe:
            monkeypatch.setattr(simulate, "warm_contact", lambda body: None)
        else:
            monkeypatch.undo()
        engine = simulate.reduced_simulation(scene, pre)
        record = engine.run(scene.simulation.steps)
        assert record.stable, record.message
        runs.append((np.asarray(record.states), engine.displacements(record),
                     engine.steps_taken, engine.time))
    for a, b in zip(*runs, strict=True):
        assert np.array_equal(a, b)
