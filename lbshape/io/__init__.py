"""Files: atomic output, the artifact cache, trajectories and the repository's folders."""

__all__ = [
    "atomic",
    "cache",
    "paths",
    "toml_writer",
    "trajectory",
]
