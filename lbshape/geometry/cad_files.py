"""CAD solids (STEP, IGES, BREP) to a tetrahedral mesh through gmsh's OpenCASCADE kernel.

:func:`read_cad_file` imports the file with ``gmsh.model.occ.importShapes``, keeps its
solids (one, or the one ``piece`` chooses) and fills it with tetrahedra at the target
size h (m). A file without a solid (only faces, a shell, curves) is refused in one
line: lbshape needs a closed volume, and a surface file (STL…) with ``fill_holes`` is
the way for an open one.

gmsh can crash (a segmentation fault) on some solids at some sizes: the OCC sample
``MODERN_Table_1.brep`` does at h = 7.6 mm and meshes at 5 mm. The meshing therefore
runs in a child process, so that a crash is a one-line error that suggests another
size instead of ending the program.

Units. ``units`` (or ``scale``) says what the file's numbers are; the solid is scaled
to metres and the target size h divided by the same factor for gmsh, so the mesh is
the same at any unit. BREP and IGES files are read as their numbers are written
(OpenCASCADE's unit conversion does not act on IGES here). A STEP file records its
length unit (:func:`step_unit`): with the default ``units = "m"`` OpenCASCADE converts
it to metres; another ``units``, or a ``scale``, applies to the numbers as written and
so overrides a wrong record (a warning names the recorded unit when ``units``
disagrees with it).
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import re
import sys
from pathlib import Path

import numpy as np

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh, check_mesh, gmsh_model, mesh_from_gmsh_model
from lbshape.geometry.surface_repair import select_piece

__all__ = ["CAD_FORMATS", "LENGTH_UNITS", "is_cad_file", "read_cad_file", "step_unit"]

log = logging.getLogger(__name__)

#: CAD formats read by OpenCASCADE (through gmsh)
CAD_FORMATS: tuple[str, ...] = (".step", ".stp", ".iges", ".igs", ".brep", ".brp")
#: length units of the ``units`` key: metres per unit
LENGTH_UNITS: dict[str, float] = {"m": 1.0, "mm": 1e-3, "cm": 1e-2, "in": 0.0254}
#: OpenCASCADE's name of each unit (its ``Geometry.OCCTargetUnit``)
_OCC_UNITS = {"m": "M", "mm": "MM", "cm": "CM", "in": "INCH"}
#: with no size given, h is this fraction of the solid's bounding-box diagonal
DEFAULT_SIZE_FRACTION = 0.05


def is_cad_file(path: str | Path) -> bool:
    """True for a CAD format (:data:`CAD_FORMATS`)."""
    return Path(path).suffix.lower() in CAD_FORMATS


def read_cad_file(path: str | Path, *, size: float | None = None, units: str = "m",
                  scale: float | None = None, piece: int | str | None = None) -> TetMesh:
    """Tetrahedralise the solid of a STEP, IGES or BREP file (in a child process:
    module docstring); arguments and errors as :func:`mesh_cad_solid`, plus a crash of
    gmsh reported as an :class:`LbshapeError`."""
    import json
    import subprocess
    import tempfile

    options = {"path": str(path), "size": size, "units": units, "scale": scale,
               "piece": piece}
    package_root = str(Path(__file__).resolve().parents[2])  # this lbshape, in the child
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [package_root] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])}
    with tempfile.TemporaryDirectory(prefix="lbshape-cad-") as folder:
        out = Path(folder) / "mesh.npz"
        done = subprocess.run(
            [sys.executable, "-c", "from lbshape.geometry.cad_files import _child; _child()",
             json.dumps(options), str(out)],
            env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE, text=True)
        if done.returncode == 0:
            for line in done.stderr.splitlines():  # the child's warnings, said here
                if line.startswith(_WARNING):
                    log.warning("%s", line[len(_WARNING):])
            with np.load(out) as data:
                return TetMesh(data["points"], data["tets"])
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    if done.returncode == _ERROR_EXIT and lines:
        raise LbshapeError(lines[-1])
    at = "its default size" if size is None else f"h = {size:g} m"
    detail = lines[-1] if lines else f"exit status {done.returncode}"
    raise LbshapeError(f"{path}: gmsh crashed while meshing the solid at {at} ({detail}); "
                       "try another size (e.g. 0.7x or 1.5x)")


#: exit status of the child process for an LbshapeError (its message on stderr)
_ERROR_EXIT = 2
#: prefix of a warning line of the child process on its stderr
_WARNING = "lbshape warning: "


def _child() -> None:
    """Child process of :func:`read_cad_file`: argv = JSON options, output .npz path."""
    import json

    options = json.loads(sys.argv[1])
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(_WARNING + "%(message)s"))
    handler.setLevel(logging.WARNING)
    logging.getLogger("lbshape").addHandler(handler)
    try:
        mesh = mesh_cad_solid(options.pop("path"), **options)
    except LbshapeError as exc:
        print(str(exc), file=sys.stderr)
        sys.exit(_ERROR_EXIT)
    np.savez(sys.argv[2], points=mesh.points, tets=mesh.tets)


def mesh_cad_solid(path: str | Path, *, size: float | None = None, units: str = "m",
                   scale: float | None = None, piece: int | str | None = None) -> TetMesh:
    """Tetrahedralise the solid of a STEP, IGES or BREP file.

    Args:
        path: the CAD file.
        size: target edge length h in metres (after unit conversion); None takes
            :data:`DEFAULT_SIZE_FRACTION` of the solid's bounding-box diagonal.
        units: the unit of the file's numbers (:data:`LENGTH_UNITS`; a STEP file
            converts from its own recorded unit, see the module docstring).
        scale: metres per file number instead of ``units`` (a multiplier).
        piece: which solid to mesh when the file has several (index as listed in the
            error, or ``"largest"``).

    Raises:
        LbshapeError: unreadable file, no solid in it, several solids without
            ``piece``, or gmsh failing to mesh the solid.
    """
    path = Path(path)
    if units not in LENGTH_UNITS:
        raise LbshapeError(f"{path}: unknown units {units!r} (choose one of "
                           f"{', '.join(LENGTH_UNITS)}, or give a numeric scale)")
    target, factor = _read_unit(path, units, scale)
    with gmsh_model("lbshape-cad") as gmsh:
        saved = gmsh.option.getString("Geometry.OCCTargetUnit")
        gmsh.option.setString("Geometry.OCCTargetUnit", target)
        try:
            with _quiet_stdout():  # OpenCASCADE's IGES reader prints to the terminal
                gmsh.model.occ.importShapes(str(path))
            gmsh.model.occ.synchronize()
        except Exception as exc:  # gmsh raises a bare Exception
            detail = " ".join(str(exc).split()) or "OpenCASCADE read nothing"
            raise LbshapeError(f"{path}: cannot read the CAD file ({detail})") from None
        finally:
            gmsh.option.setString("Geometry.OCCTargetUnit", saved)
        solids = [tag for _, tag in gmsh.model.getEntities(3)]
        if not solids:
            found = {dim: len(gmsh.model.getEntities(dim)) for dim in (2, 1, 0)}
            kinds = ", ".join(f"{n} {name}" for (n, name) in
                              ((found[2], "faces"), (found[1], "curves"), (found[0], "points"))
                              if n) or "nothing"
            raise LbshapeError(f"{path}: no solid in the CAD file (found {kinds}); lbshape "
                               "needs a closed volume")
        volumes = [gmsh.model.occ.getMass(3, tag) * factor ** 3 for tag in solids]
        if len(solids) > 1 or piece is not None:
            keep = solids[select_piece(volumes, piece, source=str(path), what="CAD file",
                                        kind="solids")]
            gmsh.model.occ.remove([(3, t) for t in solids if t != keep], recursive=True)
            gmsh.model.occ.synchronize()
            solids = [keep]
        if size is None:
            box = np.asarray(gmsh.model.getBoundingBox(3, solids[0]))
            size = DEFAULT_SIZE_FRACTION * factor * float(np.linalg.norm(box[3:] - box[:3]))
            log.info("%s: no size given; meshing at h = %.3g m", path.name, size)
        elif not (math.isfinite(size) and size > 0):
            raise LbshapeError(f"{path}: mesh size must be a positive number of metres, "
                               f"got {size}")
        gmsh.option.setNumber("Mesh.MeshSizeMax", size / factor)
        try:
            gmsh.model.mesh.generate(3)
        except Exception as exc:
            detail = " ".join(str(exc).split()) or "unknown error"
            raise LbshapeError(f"{path}: gmsh could not mesh the solid ({detail})") from None
        if not len(gmsh.model.mesh.getElementsByType(4)[0]):
            raise LbshapeError(f"{path}: gmsh generated no tetrahedra for the solid")
        mesh = mesh_from_gmsh_model(gmsh.model, source=str(path))
    mesh = check_mesh(TetMesh(mesh.points * factor, mesh.tets), source=str(path))
    log.info("%s: meshed to %d vertices, %d tets", path, mesh.n_vertices, mesh.n_tets)
    return mesh


def step_unit(path: str | Path) -> str | None:
    """The length unit a STEP file records (a key of :data:`LENGTH_UNITS`), or None when
    its header names none that lbshape knows."""
    with open(path, "rb") as handle:
        text = handle.read().decode("latin-1")
    if re.search(r"CONVERSION_BASED_UNIT\s*\(\s*'INCH'", text, re.IGNORECASE):
        return "in"
    found = re.search(r"LENGTH_UNIT\s*\(\s*\)[^;]*?SI_UNIT\s*\(\s*(\.\w+\.|\$)\s*,"
                      r"\s*\.METRE\.", text)
    if found is None:
        return None
    return {"$": "m", ".MILLI.": "mm", ".CENTI.": "cm"}.get(found.group(1).upper())


def _read_unit(path: Path, units: str, scale: float | None) -> tuple[str, float]:
    """(OpenCASCADE's target unit, metres per number it gives) for a CAD file.

    BREP and IGES numbers arrive as written: times ``scale`` or the factor of ``units``.
    A STEP file records its unit: with ``units = "m"`` (the default) OpenCASCADE
    converts to metres; another ``units`` or a ``scale`` takes the numbers as written
    (converted to the recorded unit, i.e. unchanged) times that factor, so that they
    override a wrong record — with a warning when ``units`` disagrees with it.
    """
    factor = float(scale) if scale is not None else LENGTH_UNITS[units]
    if path.suffix.lower() not in (".step", ".stp"):
        return "", factor
    if scale is None and units == "m":
        return _OCC_UNITS["m"], 1.0
    recorded = step_unit(path)
    if recorded is None:
        raise LbshapeError(f"{path}: the STEP file records no length unit lbshape knows, so "
                           "units and scale cannot say what its numbers are; leave them out "
                           "(OpenCASCADE converts to metres)")
    if scale is None and units != recorded:
        log.warning("%s records its numbers in %s; read as %s (units = %r)", path.name,
                    recorded, units, units)
    return _OCC_UNITS[recorded], factor


@contextlib.contextmanager
def _quiet_stdout():
    """Silence what C++ code writes to file descriptor 1 (not Python's own output)."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # a captured stream without a descriptor
        yield
        return
    sys.stdout.flush()
    saved = os.dup(fd)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), fd)
            yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)
