"""MJX compiles one executable per chunk shape: batch sizes share a padded bucket."""

from __future__ import annotations

import numpy as np
import pytest

from cipcore.params import BalanceParams
from cipcore.registry import get_engine


@pytest.fixture(autouse=True)
def _needs_mjx() -> None:
    """Skip without JAX or MJX; imported when a test runs, not at collection (about 6 s
    that every pytest process would pay)."""
    pytest.importorskip("jax")
    pytest.importorskip("mujoco.mjx")


LOWERING = "/jax/core/compile/jaxpr_to_mlir_module_duration"


def test_bucket_sizes():
    from cip.mjx import bucket

    assert [bucket(n) for n in (1, 3, 4, 5, 8, 9, 1024, 1025, 3000)] == [
        4, 4, 4, 8, 8, 16, 1024, 2048, 3072,
    ]  # fmt: skip


def test_second_batch_size_compiles_nothing_new_and_padding_is_exact(monkeypatch):
    import jax

    from cip import mjx

    engine = get_engine("mjx")
    if engine.unavailable():
        pytest.skip(engine.unavailable())
    # a small delay (10 steps) and two whole chunks: one chunk shape per bucket
    params = BalanceParams(beta=20.0, alpha=22.0, gamma=50.0, nu=0.6, tau=0.01, dt=1e-3)
    duration = 0.02
    lowered: list[str] = []

    def listener(event: str, duration_secs: float, **kw) -> None:
        if event == LOWERING:
            lowered.append(event)

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        three = engine.simulate("single", params, duration, 3, seed=5, progress=False)
        first = len(lowered)
        four = engine.simulate("single", params, duration, 4, seed=5, progress=False)
        assert first >= 1 and len(lowered) == first, "batch size 4 compiled again"
        assert any(r["rows"] == 4 for r in mjx.COMPILE_LOG)
        # unpadded: 3 rows compiled as they are; the real rows are bit-identical
        monkeypatch.setattr(mjx, "bucket", lambda n: n)
        exact = engine.simulate("single", params, duration, 3, seed=5, progress=False)
        assert len(lowered) > first
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert set(three.data) == set(exact.data)
    for name in exact.data:
        assert np.array_equal(three[name], exact[name]), name
    assert np.isfinite(four["balancing_error"]).all()
