"""Scripted input of ``lbshape live`` (``--events``): what a user does, at what time.

:func:`read_events` reads a JSON list of :class:`LiveEvent` (drag, move, release,
toggle the examples, pause, step, reset, screenshot); the window
(:class:`lbshape.live.window.LiveWindow`) applies them as it applies the mouse and keys.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

from lbshape.errors import LbshapeError

#: scripted event types (:func:`read_events`)
EVENT_TYPES = ("drag", "move", "release", "toggle-examples", "pause", "step", "reset",
               "screenshot")


@dataclass(frozen=True)
class LiveEvent:
    """A scripted user action at ``t`` seconds of wall time after the first frame.

    Attributes:
        t: when (s).
        type: one of :data:`EVENT_TYPES`.
        vertex: the vertex a ``drag`` grabs.
        to: (3,) world point (m) a ``drag`` or ``move`` pulls towards.
        file: the PNG a ``screenshot`` writes.
        steps: how many steps a ``step`` takes (default 1).
    """

    t: float
    type: str
    vertex: int | None = None
    to: tuple[float, float, float] | None = None
    file: str | None = None
    steps: int = 1


def read_events(path: str | Path) -> list[LiveEvent]:
    """Scripted events from a JSON file: a list of objects ``{"t": seconds, "type": ...}``
    (``drag`` needs ``vertex`` and ``to`` [x, y, z]; ``move`` needs ``to``; ``screenshot``
    needs ``file``, relative to the events file; ``step`` takes ``steps``, default 1),
    sorted by time (events at the same time keep their order).

    Raises:
        LbshapeError: an unreadable file or a malformed event (one line).
    """
    path = Path(path)
    try:
        items = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise LbshapeError(f"cannot read events file {path}: {exc.strerror}") from None
    except json.JSONDecodeError as exc:
        raise LbshapeError(f"events file {path} is not JSON: {exc.msg} (line {exc.lineno})"
                           ) from None
    if not isinstance(items, list):
        raise LbshapeError(f"events file {path} must hold a list of events")
    return sorted((_event(item, index, path) for index, item in enumerate(items)),
                  key=lambda event: event.t)


def _event(item, index: int, path: Path) -> LiveEvent:
    where = f"events file {path}, event {index}"
    if not isinstance(item, dict):
        raise LbshapeError(f"{where}: must be an object")
    allowed = {"t", "type", "vertex", "to", "file", "steps"}
    unknown = sorted(set(item) - allowed)
    if unknown:
        raise LbshapeError(f"{where}: unknown keys {unknown} (allowed: {sorted(allowed)})")
    kind, t = item.get("type"), item.get("t")
    if kind not in EVENT_TYPES:
        raise LbshapeError(f"{where}: type must be one of {EVENT_TYPES}, got {kind!r}")
    if isinstance(t, bool) or not isinstance(t, int | float) or not math.isfinite(t) or t < 0:
        raise LbshapeError(f"{where}: t must be a number of seconds >= 0, got {t!r}")
    vertex, to, file = item.get("vertex"), item.get("to"), item.get("file")
    steps = item.get("steps", 1)
    if kind == "step" and (isinstance(steps, bool) or not isinstance(steps, int) or steps < 1):
        raise LbshapeError(f"{where}: steps must be an integer >= 1, got {steps!r}")
    if kind == "drag" and (isinstance(vertex, bool) or not isinstance(vertex, int)):
        raise LbshapeError(f"{where}: a drag needs an integer vertex, got {vertex!r}")
    if kind in ("drag", "move"):
        if not (isinstance(to, list) and len(to) == 3 and all(
                isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                for v in to)):
            raise LbshapeError(f"{where}: a {kind} needs to = [x, y, z] in m, got {to!r}")
        to = tuple(float(v) for v in to)
    if kind == "screenshot":
        if not isinstance(file, str) or not file:
            raise LbshapeError(f"{where}: a screenshot needs a file name")
        file = str(path.parent / file)
    return LiveEvent(float(t), kind, vertex if kind == "drag" else None,
                     to if kind in ("drag", "move") else None,
                     file if kind == "screenshot" else None, steps if kind == "step" else 1)

