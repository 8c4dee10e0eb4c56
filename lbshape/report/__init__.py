"""What a reader looks at: benchmarks, tables, figures, off-screen renders and the demo job."""

__all__ = [
    "bench",
    "demo",
    "figures",
    "machine",
    "plots",
    "render",
    "tables",
]
