"""The interpolation routes: which basis and which elements the target energies use.

See :mod:`lbshape.interpolation` for the three routes (``modal``: the paper's,
through the direct projection and the elastic cubature; ``lb``: a cubature trained
on the LB displacement subspace; ``euclidean``: all elements, the Zhu et al.
baseline). Everything here is set up once per run from a
:class:`~lbshape.precompute.Precomputed`; the objects it returns are m/r/s-sized
at run time (``euclidean`` by design is not).
"""

from __future__ import annotations

from lbshape.errors import LbshapeError
from lbshape.precompute import Precomputed

ROUTES = ("modal", "lb", "euclidean")


def example_driver(pre: Precomputed, *, route: str):
    """The runtime example driver for the ``modal`` (paper) or ``euclidean`` route."""
    from lbshape.example_driver import ExampleDriver
    from lbshape.interpolation import TargetSolver

    k = pre.example_coefficients.shape[0]
    coefficients = pre.example_coefficients.reshape(k, -1)
    rests = [pre.example_rest_points(i) for i in range(k)]
    if route == "modal":
        from lbshape.reduced_forces import ReducedForceModel

        models = [ReducedForceModel(x, pre.mesh.tets, pre.material, pre.U,
                                    pre.cubature_elements, pre.cubature_weights) for x in rests]
        solver = TargetSolver(models, coefficients @ pre.lb_to_reduced.T)
        return ExampleDriver(pre.descriptor_matrix, pre.example_descriptors, solver)
    if route == "euclidean":
        from lbshape.euclidean_energy import EuclideanExampleEnergy

        L = pre.lb_basis()
        models = [EuclideanExampleEnergy(x, pre.mesh.tets, pre.material, L) for x in rests]
        solver = TargetSolver(models, coefficients)
        return ExampleDriver(pre.descriptor_matrix, pre.example_descriptors, solver,
                             to_reduced=pre.lb_to_reduced)
    raise LbshapeError(f"unknown interpolation route {route!r}")
