"""``lbshape eigen MESH [--m K] [--json]``: LB eigenvalues of a mesh as given.

Runs on ``MPI.COMM_WORLD`` (so ``mpirun -n 2 lbshape eigen …`` distributes the
solve); only rank 0 prints.
"""

from __future__ import annotations

from lbshape.api import build_mesh, lb_spectrum, mesh_source, run_collectively
from lbshape.cli._output import MESH_HELP, print_json

DEFAULT_M = 10


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "eigen",
        help="Laplace-Beltrami eigenvalues of a tet mesh",
        description="The m smallest non-zero LB eigenvalues (1/m^2) of the mesh as given: "
        "no rescaling, consistent mass, Neumann boundary, constant mode excluded.",
    )
    parser.add_argument("mesh", metavar="MESH", help=MESH_HELP)
    parser.add_argument("--size", type=float, default=None, metavar="H",
                        help="mesh size h in metres of a shape, script or surface (default: "
                             "the shape's, the script's DEFAULT_SIZE; a surface as given)")
    parser.add_argument("--m", type=int, default=DEFAULT_M,
                        help=f"number of non-zero eigenvalues (default {DEFAULT_M})")
    parser.add_argument("--json", action="store_true", help="print a JSON object")
    parser.set_defaults(func=run)


def run(args) -> int:
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    mesh, spectrum = run_collectively(
        comm, lambda: _mesh(args), lambda mesh: lb_spectrum(mesh, args.m, comm=comm))
    if comm.rank != 0:
        return 0
    payload = {
        "n_vertices": mesh.n_vertices,
        "n_tets": mesh.n_tets,
        "volume": mesh.volume(),
        "eigenvalues": [float(v) for v in spectrum.eigenvalues],
        "seconds": spectrum.seconds,
    }
    if args.json:
        print_json(payload)
    else:
        print(f"{args.mesh}: {mesh.n_vertices} vertices, {mesh.n_tets} tets, "
              f"volume {payload['volume']:.6g} m^3, {spectrum.seconds:.2f} s")
        print(f"{'i':>4}  {'lambda_i [1/m^2]':>18}  {'residual':>9}")
        rows = zip(spectrum.eigenvalues, spectrum.residuals, strict=True)
        for i, (value, res) in enumerate(rows, 1):
            print(f"{i:>4}  {value:>18.10g}  {res:>9.1e}")
    return 0


def _mesh(args):
    """The mesh the argument names (a shape, a gmsh script or any mesh file), on rank 0."""
    return build_mesh(mesh_source(args.mesh, size=args.size))
