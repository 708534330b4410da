"""Import a package whose C extension writes to the process's stdout or stderr.

pybullet 3.2.7 writes ``pybullet build time: ...`` from C when imported (to
file descriptor 2 in the PyPI wheel); neither that line nor any other C-level
import banner may reach ``cip-validate`` output, whose ``--json`` is parsed
from stdout.  Python-level errors of the import still raise as usual.
"""

from __future__ import annotations

import contextlib
import ctypes
import importlib
import os
import sys
from collections.abc import Iterator
from types import ModuleType


def quiet_import(name: str) -> ModuleType:
    """``importlib.import_module(name)``, file descriptors 1 and 2 sent to /dev/null meanwhile."""
    if name in sys.modules:
        return sys.modules[name]
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        return importlib.import_module(name)
    finally:
        ctypes.CDLL(None).fflush(None)  # C stdio may buffer the banner: flush it into /dev/null
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)


@contextlib.contextmanager
def stdout_to_stderr() -> Iterator[None]:
    """Send whatever is written to file descriptor 1 (Python or C) to descriptor 2 meanwhile.

    For commands whose stdout carries one JSON object: an engine package that
    announces itself when first used (warp prints its device banner) then
    writes to stderr instead of corrupting the JSON.
    """
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        with contextlib.redirect_stdout(sys.stderr):  # sys.stdout need not write to fd 1
            yield
    finally:
        sys.stdout.flush()
        ctypes.CDLL(None).fflush(None)
        os.dup2(saved, 1)
        os.close(saved)
