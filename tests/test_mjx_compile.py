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
    from cip.engines.mjx import bucket

    assert [bucket(n) for n in (1, 3, 4, 5, 8, 9, 1024, 1025, 3000)] == [
        4, 4, 4, 8, 8, 16, 1024, 2048, 3072,
    ]  # fmt: skip


def test_second_batch_size_compiles_nothing_new_and_padding_is_exact(monkeypatch):
    import jax

    from cip.engines import mjx

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


def test_a_later_process_reads_the_exported_chunk_instead_of_tracing(monkeypatch, tmp_path):
    """The traced chunk is written once (``jax.export``) and read back by the next process,
    which gets the same numbers; its key holds across processes (no object addresses);
    a damaged file is written again."""
    from cip.engines import mjx

    engine = get_engine("mjx")
    if engine.unavailable():
        pytest.skip(engine.unavailable())
    pytest.importorskip("flatbuffers", reason="jax.export's serialisation needs flatbuffers")
    monkeypatch.setenv("CIPVAL_MJX_EXPORT_DIR", str(tmp_path))
    params = BalanceParams(beta=20.0, alpha=22.0, gamma=50.0, nu=0.6, tau=0.01, dt=1e-3)

    def fresh_run():  # as a new process would: nothing compiled in this one yet
        monkeypatch.setattr(mjx, "_COMPILED", {})
        monkeypatch.setattr(mjx, "COMPILE_LOG", [])
        res = engine.simulate("single", params, 0.02, 3, seed=5, progress=False)
        return res, [r["exported"] for r in mjx.COMPILE_LOG]

    first, log1 = fresh_run()
    (path,) = tmp_path.glob("chunk-*.jaxexport")
    second, log2 = fresh_run()
    assert log1 == ["written"] and log2 == ["read"]
    for name in first.data:
        assert np.array_equal(first[name], second[name]), name
    path.write_bytes(b"not an exported module")
    third, log3 = fresh_run()
    assert log3 == ["written"] and path.stat().st_size > 1000
    assert np.array_equal(third["balancing_error"], first["balancing_error"])
