"""Worker processes die with their parent: no orphan keeps computing after a ``kill -9``.

One job.  :func:`die_with_parent`, called in a child process, arranges two
things:

* on Linux, ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` (through :mod:`ctypes`): the
  kernel kills the child the moment its parent dies;
* everywhere, a daemon watchdog thread that polls ``os.getppid()`` and ends the
  child (``os._exit``) once it changes, i.e. once the parent died and the child
  was handed to another process.

A local sweep's pool runs under a *forkserver*: the forkserver imports
:mod:`validation.sweeps.forkserver_lifeline` at its start (so it dies with the
sweep), and every worker runs :func:`die_with_parent` as its initializer (so it
dies with the forkserver).  Python's resource tracker then sees its pipe closed
and exits too.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time

#: linux/prctl.h
PR_SET_PDEATHSIG = 1
#: seconds between two looks at the parent in the watchdog thread
POLL_S = 0.5


def _pdeathsig() -> bool:
    """Ask the Linux kernel for SIGKILL when the parent dies; False where unavailable."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def forkserver_context():
    """The multiprocessing context of a pool whose processes die with this one: a
    forkserver (not fork: forking a process that has loaded a multithreaded runtime,
    JAX/XLA or warp, can deadlock the child) that imports
    :mod:`validation.sweeps.forkserver_lifeline` at its start; each process it starts
    calls :func:`die_with_parent`."""
    import multiprocessing

    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["validation.sweeps.forkserver_lifeline"])
    return ctx


def die_with_parent(poll_s: float = POLL_S) -> None:
    """End this process when its parent dies (see the module docstring)."""
    parent = os.getppid()
    _pdeathsig()
    if os.getppid() != parent or parent == 1:  # the parent died before prctl took effect
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll_s)
        os._exit(1)

    threading.Thread(target=watch, name="die-with-parent", daemon=True).start()
