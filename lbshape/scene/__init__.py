"""Scenes: the validated schema, the TOML reader and the built-in scenes."""

__all__ = [
    "schema",
]
