"""Metrics on arrays: mass norms and trajectory errors, example influence ratios, visible
change, nearest shape, a free body's rigid-motion/deformation split, a bar's end twist.
Nothing here knows a scene, a precompute or a run."""
