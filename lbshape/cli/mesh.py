"""``lbshape mesh NAME|SCRIPT.py|FILE [--size H] [-o PATH]``: mesh a shape, a user's gmsh
script or a file, write ``.msh``."""

from __future__ import annotations

from pathlib import Path

from lbshape.api import (
    CAD_FORMATS,
    LENGTH_UNITS,
    SHAPES,
    SURFACE_FORMATS,
    get_shape,
    mesh_source,
    write_mesh,
)


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "mesh",
        help="mesh a built-in shape, your gmsh script or a mesh/surface file and write a "
             ".msh file",
        description="Run the gmsh script of a built-in shape or your own gmsh Python script "
        "(a .py file defining build(model, h) as the scripts in meshes/ do, and optionally "
        "DEFAULT_SIZE in metres), tetrahedralise a closed "
        f"surface ({', '.join(SURFACE_FORMATS)}; repaired, and remeshed at --size when "
        f"given), mesh a CAD solid ({', '.join(CAD_FORMATS)}) at --size or convert "
        "a volume mesh that meshio reads (.vtu, .vtk, .mesh, ...), and write the "
        "tetrahedral mesh as gmsh .msh (format 4.1). "
        f"Shapes: {', '.join(SHAPES)}.",
    )
    parser.add_argument("name", metavar="NAME|SCRIPT.py|FILE",
                        help="built-in shape name, gmsh script (.py) or mesh file")
    parser.add_argument("--size", type=float, default=None, metavar="H",
                        help="mesh size h in metres (default: the shape's default, the "
                        "script's DEFAULT_SIZE; a surface is kept as given; a CAD solid: 5%% of "
                        "its diagonal)")
    parser.add_argument("--units", choices=tuple(LENGTH_UNITS), default="m",
                        help="unit of the file's numbers (default m; a STEP file converts "
                        "from its own); --size stays in metres")
    parser.add_argument("--piece", default=None, metavar="K|largest",
                        type=lambda text: text if text == "largest" else int(text),
                        help="a surface or CAD file of several pieces: the one to mesh")
    parser.add_argument("--fill-holes", action="store_true",
                        help="close the holes of an open surface file")
    parser.add_argument("-o", "--output", type=Path, default=None, metavar="PATH",
                        help="output file (default: NAME.msh in the current folder)")
    parser.set_defaults(func=run)


def run(args) -> int:
    source = Path(args.name)
    if args.name not in SHAPES and not (source.suffix or source.exists()):
        get_shape(args.name)  # an unknown name fails (listing the shapes) before any output
    origin = mesh_source(args.name, size=args.size, units=args.units, piece=args.piece,
                         fill_holes=args.fill_holes)
    stem = origin.shape or Path(origin.label).stem
    path = args.output if args.output is not None else Path(f"{stem}.msh")
    mesh = write_mesh(origin, path)
    print(f"{args.name}: {mesh.n_vertices} vertices, {mesh.n_tets} tets -> {path}")
    return 0
