"""lbshape: real-time example-based elastic materials in Laplace-Beltrami shape space.

Conventions used throughout the package:

* SI units (metres, kilograms, seconds, pascals).
* A mesh is a :class:`lbshape.geometry.mesh.TetMesh`: linear tetrahedra, positively oriented.
* Nodal fields are stored in the mesh's *input vertex order*. A vector field on n
  vertices is a ``(n, 3)`` array, or flattened node-major as ``(3n,)`` with
  ``u[3*i + c]`` the component ``c`` of vertex ``i``.
"""

__version__ = "0.1.0"
