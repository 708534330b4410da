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
