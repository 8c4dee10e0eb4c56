"""The interactive simulation: the session that steps a scene (:mod:`.session`), the window
that draws it (:mod:`.window`), the recorded input events (:mod:`.events`) and the X
display the window needs (:mod:`.display`)."""

__all__ = [
    "display",
    "events",
    "session",
    "window",
]
