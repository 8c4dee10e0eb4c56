"""The X display the live window needs: the user's, or a virtual one (``Xvfb``) started for
a block (headless runs, tests and the live benchmark)."""

from __future__ import annotations

import contextlib
import gc
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator

from lbshape.errors import LbshapeError


def display_available() -> bool:
    """Whether an X display is set (``DISPLAY``); other platforms are assumed to have one."""
    return not sys.platform.startswith("linux") or bool(os.environ.get("DISPLAY"))


@contextlib.contextmanager
def virtual_display(screen: str = "1280x1024x24") -> Iterator[str]:
    """An X display for the block: ``$DISPLAY`` when set, else a virtual X server
    (``Xvfb``, Debian ``xvfb``) started for the block on a free display number and
    stopped after it (``DISPLAY`` restored). Yields the display's name.

    Raises:
        LbshapeError: no ``DISPLAY`` and no ``Xvfb``, or a server that did not start.
    """
    if display_available():
        yield os.environ.get("DISPLAY", "")
        return
    xvfb = shutil.which("Xvfb")
    if xvfb is None:
        raise LbshapeError("no DISPLAY and no Xvfb: install the Debian package xvfb "
                           "(scripts/setup does)")
    read, write = os.pipe()
    server = subprocess.Popen([xvfb, "-displayfd", str(write), "-screen", "0", screen,
                               "-nolisten", "tcp"], pass_fds=(write,),
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              preexec_fn=_die_with_parent)
    os.close(write)
    with os.fdopen(read) as pipe:
        number = pipe.readline().strip()
    if not number:
        server.kill()
        server.wait()
        raise LbshapeError("the virtual X server (Xvfb) did not start")
    os.environ["DISPLAY"] = f":{number}"
    try:
        yield os.environ["DISPLAY"]
    finally:
        gc.collect()  # windows left unclosed let go of the server first
        del os.environ["DISPLAY"]
        server.terminate()
        server.wait(timeout=10)


def _die_with_parent() -> None:
    """In the child before exec (Linux): SIGTERM when the parent dies, so a killed run
    leaves no server behind."""
    with contextlib.suppress(OSError, AttributeError):
        import ctypes
        import signal

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def require_display() -> None:
    """Raise a one-line :class:`~lbshape.errors.LbshapeError` without a display."""
    if not display_available():
        raise LbshapeError("lbshape live needs a display: DISPLAY is not set (on a headless "
                           "machine run it under a virtual X server: xvfb-run -a lbshape live "
                           "...)")

