"""Sub-commands of the ``lbshape`` CLI; each module defines ``register(subparsers)``."""
