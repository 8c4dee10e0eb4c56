"""The reduced method at real-time step sizes against the full method.

Usage: ``.venv/bin/python scripts/bench_large_steps.py [--out-dir results]``.

Runs :func:`lbshape.studies.large_steps.large_step_study` on the demo, the paper's bar
scenes (bar-cuboid, bar-cylinder, and the free bar-s-cuboid of Figure 4) and a user's own
mesh (the ``l-beam`` shape read from a ``.msh`` file) at 1000, 60, 50 and 20 Hz, and
writes ``large_steps.md``, ``large_steps.json`` and ``large_steps.png`` atomically.
"""

from __future__ import annotations

import os

if __name__ == "__main__":  # single-threaded BLAS for the timings, set before numpy loads
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import argparse
import logging
import sys
import tempfile
from pathlib import Path

from lbshape.io.atomic import write_json_atomic, write_text_atomic
from lbshape.io.machine import machine_description
from lbshape.pipeline.precompute import precompute
from lbshape.scene import load_scene
from lbshape.studies.bench import DEFAULT_OUT
from lbshape.studies.large_steps import (
    large_step_study,
    large_steps_markdown,
    large_steps_payload,
    large_steps_plot,
)
from lbshape.studies.user_meshes import user_mesh_scene

log = logging.getLogger(__name__)

#: scene → simulated time (s), the same at every step rate
DURATIONS = {"demo": 0.3, "bar-cuboid": 0.4, "bar-cylinder": 0.4, "bar-s-cuboid": 1.0,
             "l-beam": 0.4}


def main(argv: list[str] | None = None) -> list[Path]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out-dir", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        for name, duration in DURATIONS.items():
            scene = user_mesh_scene(Path(folder)) if name == "l-beam" else load_scene(name)
            log.info("large steps: %s", name)
            rows += large_step_study(scene, precompute(scene, progress=False),
                                     duration=duration)
    command = "python scripts/bench_large_steps.py " + " ".join(argv or sys.argv[1:])
    return [
        write_text_atomic(args.out_dir / "large_steps.md", large_steps_markdown(
            rows, duration=DURATIONS, machine=machine_description(), command=command.strip())),
        write_json_atomic(args.out_dir / "large_steps.json", large_steps_payload(rows)),
        large_steps_plot(rows, args.out_dir / "large_steps.png"),
    ]


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for path in main():
        print(path)
