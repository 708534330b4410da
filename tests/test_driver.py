"""The chunked driver: a failure or an interruption stops every block within a chunk."""

from __future__ import annotations

import time

import pytest

from cipcore.driver import run_blocks
from cipcore.noise import GainNoise


def test_a_failing_block_stops_the_others_at_their_next_chunk():
    noise = GainNoise(seed=1, n_realizations=2, n_controllers=1)
    chunks: dict[int, int] = {0: 0, 1: 0}

    def work(block: slice, xi, step: int) -> bool:
        chunks[block.start] += 1
        if block.start == 0:
            raise RuntimeError("block 0 failed")
        time.sleep(0.01)  # block 1: 10 ms per chunk
        return True

    t0 = time.perf_counter()
    with pytest.raises(RuntimeError, match="block 0 failed"):
        run_blocks(noise, 100_000, work, threads=2, chunk_steps=100)  # 1000 chunks each
    assert chunks[1] < 100, chunks  # without cancelling: all 1000 chunks, 10 s
    assert time.perf_counter() - t0 < 5.0


def test_every_chunk_of_draws_is_c_contiguous_the_short_last_one_too():
    """A strided last chunk would make numba compile each kernel again for layout 'A'."""
    import numpy as np

    seen = []

    def work(block, xi, n0):
        seen.append((n0, xi.shape[1], xi.flags.c_contiguous))
        return True

    run_blocks(GainNoise(3, 2, 2), 250, work, threads=1, chunk_steps=100)
    assert [(n0, n) for n0, n, _ in seen] == [(0, 100), (100, 100), (200, 50)]
    assert all(c for _, _, c in seen)
    # and the same draws as one chunk
    parts, whole = [], []
    run_blocks(GainNoise(3, 2, 2), 250, lambda b, xi, n0: parts.append(xi.copy()),
               threads=1, chunk_steps=100)  # fmt: skip
    run_blocks(GainNoise(3, 2, 2), 250, lambda b, xi, n0: whole.append(xi.copy()), threads=1)
    assert np.array_equal(np.concatenate(parts, axis=1), whole[0])
