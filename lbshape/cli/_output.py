"""Shared output helpers for sub-commands."""

from __future__ import annotations

import json
import sys

#: the help of a command's MESH argument (``lbshape eigen``, ``modes``): one resolver,
#: :func:`lbshape.scene.mesh_source`, for every command that takes a mesh
MESH_HELP = ("built-in shape name, gmsh script (.py, defining build(model, h)), gmsh .msh, "
             "a volume mesh meshio reads (.vtu, .vtk, .mesh, ...) or a closed surface "
             "(.stl, .obj, .ply, .off; tetrahedralised)")


def print_json(payload: dict) -> None:
    """Print a JSON object on stdout (one document, sorted keys off: contract order)."""
    json.dump(payload, sys.stdout, indent=2)
    sys.stdout.write("\n")
