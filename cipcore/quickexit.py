"""End a finished command's process without tearing down every imported module.

A process ending through ``sys.exit`` first joins its non-daemon threads, then runs its
``atexit`` handlers (multiprocessing's pool and forkserver shutdown, the finalizers of
``weakref.finalize`` such as a ``TemporaryDirectory``'s clean-up, ``logging``'s flush),
then flushes stdout and stderr, and then clears every imported module one by one.  The
last part is the costly one after a run that imported scipy, xarray, pandas, numba and
MuJoCo. On 2 cores (7 December 2026), ``python -c "import xarray, scipy.stats,
scipy.signal, numba, mujoco, pandas, validation.run, validation.checks.anchors"`` took
1.40 s, and 1.11 s when it ended with ``os._exit(0)``. A smoke run ended 0.35-0.4 s after
its last line was written.

:func:`arm` registers, as the process's first ``atexit`` handler, one that runs last. It
flushes stdout and stderr and then calls ``os._exit`` with the status given to
:func:`exit`. So everything that ``sys.exit`` does before the module teardown still
happens, in the same order. The handler does nothing when the process ends any other
way, for example by an uncaught exception, which is printed and ends with status 1 as
usual. Only a process's entry point should use this (the console script, the figure
worker): the outputs have all been written and closed by then (:mod:`cipcore.atomic`).
"""

from __future__ import annotations

import atexit
import os
import sys
from typing import NoReturn

#: the status :func:`exit` was given; empty until then
_STATUS: list[int] = []
#: whether :func:`arm` has registered the handler
_ARMED: list[bool] = []


def _end() -> None:
    """The last ``atexit`` handler: flush the standard streams, then ``os._exit``."""
    if not _STATUS:  # the process ends another way: the interpreter's own exit
        return
    for stream in (sys.stdout, sys.stderr, sys.__stdout__, sys.__stderr__):
        try:
            if stream is not None:
                stream.flush()
        except (OSError, ValueError):  # a closed pipe or a closed stream: nothing to keep
            pass
    os._exit(_STATUS[-1])


def arm() -> None:
    """Register the handler that ends the process by ``os._exit`` (see the module's text).

    Call it first in the entry point, before any module registers an ``atexit`` handler
    of its own: handlers run last-registered first, so this one runs after all of them.
    Calling it again does nothing.
    """
    if not _ARMED:
        _ARMED.append(True)
        atexit.register(_end)


def exit(status: int | None) -> NoReturn:
    """``sys.exit(status)``; once the ``atexit`` handlers have run, :func:`arm`'s handler
    ends the process with ``status`` without the module teardown.  A status that is
    not a number (``sys.exit``'s message form) ends the usual way."""
    if status is None or isinstance(status, int):
        _STATUS.append(int(status or 0))
    sys.exit(status)
