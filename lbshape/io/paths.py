"""Where the repository's folders are: gmsh scripts and committed results.

lbshape is installed editable from its repository; these paths are the defaults
for outputs that belong beside the source (``results/``) and for the gmsh
scripts of the built-in shapes (``meshes/``). Every command that writes takes an
explicit output folder as well.
"""

from __future__ import annotations

from pathlib import Path

#: the repository folder that holds ``lbshape/``, ``meshes/`` and ``results/``
REPOSITORY = Path(__file__).resolve().parents[2]
#: committed small outputs: tables, plots, renders
RESULTS_DIR = REPOSITORY / "results"
#: gmsh scripts, one ``build(model, h)`` per shape
MESHES_DIR = REPOSITORY / "meshes"
