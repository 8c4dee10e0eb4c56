"""``lbshape mesh NAME|FILE [--size H] [-o PATH]``: mesh a shape or a file, write ``.msh``."""

from __future__ import annotations

from pathlib import Path

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh_files import SURFACE_FORMATS, read_mesh_file, write_msh
from lbshape.geometry.shapes import SHAPES, get_shape, write_shape


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "mesh",
        help="mesh a built-in shape or a mesh/surface file and write a .msh file",
        description="Run the gmsh script of a built-in shape, tetrahedralise a closed "
        f"surface ({', '.join(SURFACE_FORMATS)}; remeshed at --size when given) or convert "
        "a volume mesh that meshio reads (.vtu, .vtk, .mesh, ...), and write the "
        "tetrahedral mesh as gmsh .msh (format 4.1). "
        f"Shapes: {', '.join(SHAPES)}.",
    )
    parser.add_argument("name", metavar="NAME|FILE", help="built-in shape name or mesh file")
    parser.add_argument("--size", type=float, default=None, metavar="H",
                        help="mesh size h in metres (default: the shape's default; a "
                        "surface is kept as given)")
    parser.add_argument("-o", "--output", type=Path, default=None, metavar="PATH",
                        help="output file (default: NAME.msh in the current folder)")
    parser.set_defaults(func=run)


def run(args) -> int:
    source = Path(args.name)
    if args.name in SHAPES or not (source.suffix or source.exists()):
        get_shape(args.name)  # an unknown name fails before any path is touched
        path = args.output if args.output is not None else Path(f"{args.name}.msh")
        mesh = write_shape(args.name, path, size=args.size)
    else:
        path = args.output if args.output is not None else Path(f"{source.stem}.msh")
        if path.suffix.lower() != ".msh":
            raise LbshapeError(f"{path}: output must be a .msh file")
        if path.resolve() == source.resolve():
            raise LbshapeError(f"{path}: output would overwrite the input file")
        mesh = read_mesh_file(source, size=args.size)
        write_msh(mesh, path)
    print(f"{args.name}: {mesh.n_vertices} vertices, {mesh.n_tets} tets -> {path}")
    return 0
