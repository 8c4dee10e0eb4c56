"""What a reader looks at: benchmarks, tables, figures, off-screen renders and the demo job."""

__all__ = [
    "animation",
    "bench",
    "demo",
    "figures",
    "machine",
    "movie",
    "pareto",
    "plots",
    "render",
    "tables",
]
