"""What a reader looks at: off-screen renders, plots, movies and figure layouts of runs it is
given (drawing only: nothing here precomputes or simulates)."""

__all__ = [
    "figures",
    "movie",
    "plots",
    "render",
]
