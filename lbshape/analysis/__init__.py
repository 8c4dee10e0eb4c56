"""Metrics on arrays: mass norms and trajectory errors (:mod:`.norms`), example influence
ratios, visible change and nearest shape (:mod:`.influence`), a free body's
rigid-motion/deformation split (:mod:`.free_body`), a bar's end twist (:mod:`.twist`).
Nothing here knows a scene, a precompute or a run."""

__all__ = [
    "free_body",
    "influence",
    "norms",
    "twist",
]
