"""Run many realisations in time chunks across threads.

Realisations are split into contiguous blocks, one task per block; a block
advances chunk by chunk, drawing its own noise (each realisation has its own
stream, see :class:`reduced.noise.GainNoise`) and calling a compiled kernel
that releases the GIL.  Results therefore do not depend on the number of
threads or on the chunk length.
"""

from __future__ import annotations

import itertools
import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from tqdm.auto import tqdm

from .noise import GainNoise

#: Steps per chunk: small enough for the noise buffer to stay in cache-sized
#: pieces, large enough for the Python call overhead to vanish.
CHUNK_STEPS = 8192

BlockFn = Callable[[slice, np.ndarray, int], "bool | None"]


def default_threads() -> int:
    return max(1, os.cpu_count() or 1)


def realization_blocks(n_realizations: int, threads: int | None = None) -> list[slice]:
    """The contiguous realisation blocks :func:`run_blocks` runs, one per thread:
    ``min(threads, n_realizations)`` of them (``threads`` None: every core), sizes
    differing by at most one.  A caller that builds per-block state before the threads
    start (a backend that forks worker processes must not fork beside running threads)
    builds it for these."""
    threads = min(threads or default_threads(), n_realizations)
    bounds = np.linspace(0, n_realizations, threads + 1).astype(int)
    return [slice(int(a), int(b)) for a, b in itertools.pairwise(bounds) if b > a]


def run_blocks(
    noise: GainNoise,
    n_steps: int,
    work: BlockFn,
    *,
    threads: int | None = None,
    chunk_steps: int | None = None,
    progress: bool | str = False,
) -> None:
    """Call ``work(block, xi, n0)`` for each realisation block and time chunk.

    ``block`` is a slice of realisation indices, ``xi`` the draws
    (len(block), n, C) for global steps ``n0 .. n0 + n - 1``.  Chunks of one
    block are called in order; blocks run concurrently on ``threads`` threads.
    A block stops early when ``work`` returns False.  When the caller is
    interrupted (Ctrl-C, SIGTERM) or a block raises, the other blocks stop at
    their next chunk, so the exception reaches the caller within one chunk.
    """
    chunk_steps = chunk_steps or CHUNK_STEPS
    nreal = noise.n_realizations
    blocks = realization_blocks(nreal, threads)
    bar = tqdm(
        total=n_steps * nreal,
        unit="step",
        unit_scale=True,
        disable=not progress,
        desc=progress if isinstance(progress, str) else None,
        leave=False,
    )

    cancel = threading.Event()  # set when any block fails or the run is interrupted

    def run(block: slice) -> None:
        nb = block.stop - block.start
        buf = np.empty((nb, min(chunk_steps, n_steps), noise.n_controllers))
        for n0 in range(0, n_steps, chunk_steps):
            if cancel.is_set():
                return
            n = min(chunk_steps, n_steps - n0)
            # C-contiguous draws in every chunk, the last (shorter) one too: a strided
            # view would have numba compile each kernel a second time, for layout 'A'
            # (1.4 s of a first run after install), for the same numbers
            xi = buf if n == buf.shape[1] else np.empty((nb, n, noise.n_controllers))
            for j in range(nb):
                noise.fill(block.start + j, xi[j])
            if work(block, xi, n0) is False:
                break
            bar.update(n * nb)

    try:
        if len(blocks) == 1:
            run(blocks[0])
        else:
            with ThreadPoolExecutor(len(blocks)) as pool:
                futures = [pool.submit(run, b) for b in blocks]
                try:
                    for fut in futures:
                        fut.result()
                except BaseException:  # Ctrl-C, SIGTERM or a failed block: the other
                    cancel.set()  # blocks stop at their next chunk, not at their end
                    raise
    finally:
        bar.close()
    noise.position += n_steps
