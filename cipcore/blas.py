"""BLAS on one thread for everything the suite computes.

The suite spreads its work over threads and processes itself (realisation blocks on
numba kernels, MuJoCo's rollout, engine worker processes), and its matrices are small
(the characteristic roots' 196 x 196 generator, Welch's linear detrending of 10 s
segments).  A multithreaded BLAS on them only spins: measured on 2 cores, seed-free
``reduced.stability.characteristic_roots("coupled", ...)`` took 83 ms with OpenBLAS's
2 threads and 19.5 ms with one, idle, and 337 ms beside another busy process (the
selftest's stability anchors, 14 of its 32 s); Welch's detrending took 15 times the
CPU time with two threads on a loaded machine.

:func:`one_blas_thread` limits the BLAS libraries already loaded (threadpoolctl) and,
through ``OPENBLAS_NUM_THREADS`` / ``MKL_NUM_THREADS`` (unless the caller set them),
those loaded later and those of child processes.  The command line runs every command
under it; so does the test suite.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager

#: the variables that set a BLAS's thread count when it loads
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """Run the block with every BLAS on one thread (module docstring); restores the
    loaded libraries' thread counts on exit (the environment variables stay set)."""
    for name in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(name, "1")
    if "numpy" not in sys.modules:  # nothing loaded yet: the variables cover it
        yield
        return
    # the loaded libraries; one loaded later (scipy ships its own) reads the variables
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield
