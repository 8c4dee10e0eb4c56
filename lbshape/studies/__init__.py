"""Experiment drivers that precompute and simulate, and their markdown/JSON writers:
Table 2 (:mod:`.bench`, :mod:`.tables`), speed/error and Pareto sweeps (:mod:`.sweep`,
:mod:`.pareto`), tuning, scaling, large steps, the Newton study and the free-body step
(:mod:`.realtime`), the runs behind the figures (:mod:`.figures`), the movie
(:mod:`.animation`), the demo job and a user's own mesh as a scene
(:mod:`.user_meshes`). Only the command line and the scripts import them."""

__all__ = [
    "animation",
    "bench",
    "demo",
    "figures",
    "large_steps",
    "pareto",
    "realtime",
    "scaling",
    "sweep",
    "tables",
    "tune",
    "user_meshes",
]
