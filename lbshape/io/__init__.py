"""Files: atomic output, the artifact cache, trajectories, the repository's folders and the
machine a results file was measured on."""

__all__ = [
    "atomic",
    "cache",
    "machine",
    "paths",
    "toml_writer",
    "trajectory",
]
