"""Where the repository's folders are, and where outputs go by default.

lbshape is installed editable from its repository: the gmsh scripts of the built-in
shapes live in ``meshes/``, the project's committed results in ``results/``.
Commands that write pictures, tables or runs (``render``, ``demo``, ``tune``,
``simulate``) default to :func:`output_root`: ``results/`` when lbshape runs from the
repository's root folder (the project regenerating its own results), else
``./lbshape-results/`` in the current folder, so that a user's runs never land in the
checkout. Every such command takes an explicit output folder as well.
"""

from __future__ import annotations

from pathlib import Path

#: the repository folder that holds ``lbshape/``, ``meshes/`` and ``results/``
REPOSITORY = Path(__file__).resolve().parents[2]
#: committed small outputs: tables, plots, renders
RESULTS_DIR = REPOSITORY / "results"
#: gmsh scripts, one ``build(model, h)`` per shape
MESHES_DIR = REPOSITORY / "meshes"
#: the default output folder of a run outside the repository, in the current folder
USER_RESULTS = "lbshape-results"


def in_repository(folder: str | Path | None = None) -> bool:
    """True if ``folder`` (default: the current folder) is the root of the lbshape
    repository this package was imported from."""
    folder = Path.cwd() if folder is None else Path(folder)
    if not (REPOSITORY / "pyproject.toml").is_file():
        return False  # installed as a package: no checkout to protect or to write into
    try:
        return folder.resolve() == REPOSITORY
    except OSError:
        return False


def output_root(folder: str | Path | None = None) -> Path:
    """The default root of a command's outputs: :data:`RESULTS_DIR` when run from the
    repository's root, else ``<folder>/lbshape-results`` (``folder``: the current one)."""
    folder = Path.cwd() if folder is None else Path(folder)
    return RESULTS_DIR if in_repository(folder) else folder / USER_RESULTS
