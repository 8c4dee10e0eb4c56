"""``lbshape mesh NAME [--size H] [-o PATH]``: mesh a built-in shape, write ``.msh``."""

from __future__ import annotations

from pathlib import Path

from lbshape.geometry.shapes import SHAPES, get_shape, write_shape


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "mesh",
        help="mesh a built-in shape with its gmsh script and write a .msh file",
        description="Run the gmsh script of a built-in shape and write the tetrahedral "
        "mesh as gmsh .msh (format 4.1) with its named physical groups. "
        f"Shapes: {', '.join(SHAPES)}.",
    )
    parser.add_argument("name", metavar="NAME", help="built-in shape name")
    parser.add_argument("--size", type=float, default=None, metavar="H",
                        help="mesh size h in metres (default: the shape's default)")
    parser.add_argument("-o", "--output", type=Path, default=None, metavar="PATH",
                        help="output file (default: NAME.msh in the current folder)")
    parser.set_defaults(func=run)


def run(args) -> int:
    get_shape(args.name)  # an unknown name fails before any path is touched
    path = args.output if args.output is not None else Path(f"{args.name}.msh")
    mesh = write_shape(args.name, path, size=args.size)
    print(f"{args.name}: {mesh.n_vertices} vertices, {mesh.n_tets} tets -> {path}")
    return 0
