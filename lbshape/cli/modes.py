"""``lbshape modes MESH [--r K] [--fixed EXPR] [--young E] [--poisson NU] [--density RHO]
[--json]``: the lowest linear elastic vibration modes of a mesh.

Without ``--fixed`` the body is free: its 6 rigid modes are found, counted and left
out of the listed frequencies. Runs on ``MPI.COMM_WORLD`` (``mpirun -n 2 lbshape
modes …`` distributes the solve); only rank 0 prints.
"""

from __future__ import annotations

from lbshape.api import (
    Material,
    build_mesh,
    linear_modes,
    mesh_source,
    region_vertices,
    run_collectively,
)
from lbshape.cli._output import MESH_HELP, print_json

DEFAULT_R = 10


def register(subparsers) -> None:
    defaults = Material()
    parser = subparsers.add_parser(
        "modes",
        help="linear elastic vibration modes of a tet mesh",
        description="The K lowest non-rigid vibration frequencies (Hz) of the mesh as given "
        "(SI units, consistent mass). Free body unless --fixed clamps a region.",
    )
    parser.add_argument("mesh", metavar="MESH", help=MESH_HELP)
    parser.add_argument("--size", type=float, default=None, metavar="H",
                        help="mesh size h in metres of a shape, script or surface (default: "
                             "the shape's, the script's DEFAULT_SIZE; a surface as given)")
    parser.add_argument("--r", type=int, default=DEFAULT_R, metavar="K",
                        help=f"number of non-rigid modes (default {DEFAULT_R})")
    parser.add_argument("--fixed", default=None, metavar="EXPR",
                        help="clamped region, an expression in x, y, z such as 'z < 1e-6'")
    parser.add_argument("--young", type=float, default=defaults.young, metavar="E",
                        help=f"Young's modulus in Pa (default {defaults.young:g})")
    parser.add_argument("--poisson", type=float, default=defaults.poisson, metavar="NU",
                        help=f"Poisson ratio (default {defaults.poisson:g})")
    parser.add_argument("--density", type=float, default=defaults.density, metavar="RHO",
                        help=f"density in kg/m^3 (default {defaults.density:g})")
    parser.add_argument("--json", action="store_true", help="print a JSON object")
    parser.set_defaults(func=run)


def run(args) -> int:
    from mpi4py import MPI

    comm = MPI.COMM_WORLD

    def solve(inputs):
        mesh, material, fixed = inputs if inputs is not None else (None, None, None)
        material = comm.bcast(material, root=0)
        return linear_modes(mesh, material, args.r, fixed_vertices=fixed, comm=comm)

    inputs, modes = run_collectively(comm, lambda: _inputs(args), solve)
    if comm.rank != 0:
        return 0
    mesh, _, fixed = inputs
    payload = {
        "n_vertices": mesh.n_vertices,
        "n_tets": mesh.n_tets,
        "n_rigid": modes.n_rigid,
        "frequencies_hz": [float(f) for f in modes.frequencies_hz],
        "seconds": modes.seconds,
    }
    if args.json:
        print_json(payload)
    else:
        clamp = f"{fixed.size} fixed vertices" if fixed is not None else "free body"
        print(f"{args.mesh}: {mesh.n_vertices} vertices, {mesh.n_tets} tets, {clamp}, "
              f"{modes.n_rigid} rigid modes, {modes.seconds:.2f} s")
        print(f"{'i':>4}  {'f_i [Hz]':>14}  {'omega_i^2 [rad^2/s^2]':>22}  {'residual':>9}")
        rows = zip(modes.frequencies_hz, modes.omega2, modes.residuals, strict=True)
        for i, (freq, omega2, res) in enumerate(rows, 1):
            print(f"{i:>4}  {freq:>14.8g}  {omega2:>22.10g}  {res:>9.1e}")
    return 0


def _inputs(args):
    """(mesh, material, fixed vertices or None) from the arguments, on rank 0."""
    material = Material(young=args.young, poisson=args.poisson, density=args.density)
    mesh = _mesh(args)
    fixed = (None if args.fixed is None
             else region_vertices(args.fixed, mesh.points, what="--fixed region"))
    return mesh, material, fixed


def _mesh(args):
    """The mesh the argument names (a shape, a gmsh script or any mesh file), on rank 0."""
    return build_mesh(mesh_source(args.mesh, size=args.size))
