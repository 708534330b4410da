"""Drake's realisations split across worker processes: the same numbers for any split."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pydrake")

from cipcore.params import BalanceParams
from cipcore.registry import get_engine


@pytest.mark.parametrize("model", ["single", "coupled"])
def test_any_process_split_is_bit_identical(model):
    engine = get_engine("drake")
    params = BalanceParams(beta=20.0, alpha=22.0, gamma=50.0, nu=0.6, tau=0.01, dt=1e-3)
    runs = {
        p: engine.simulate(model, params, 0.025, 3, seed=7, threads=p, progress=False)
        for p in (1, 2, 3)
    }
    assert np.isfinite(runs[1]["balancing_error"]).all()
    for p in (2, 3):
        assert set(runs[p].data) == set(runs[1].data)
        for name in runs[1].data:
            assert np.array_equal(runs[p][name], runs[1][name]), (p, name)


def test_processes_follow_threads_and_end_with_the_rollout():
    import gc

    from cip.drake import DrakeRollout
    from cip.model import CIPParams, build

    model = build("coupled", CIPParams())
    rollout = DrakeRollout(model, 3, threads=2)
    procs = list(rollout.workers.procs)
    assert rollout.processes == 2 and all(p.is_alive() for p in procs)
    assert DrakeRollout(model, 1, threads=4).processes == 1  # at most one per realisation
    del rollout
    gc.collect()
    for p in procs:
        p.join(timeout=10)
        assert not p.is_alive()


def test_workers_fork_only_without_a_threaded_runtime(monkeypatch):
    import sys

    from cip import drake

    monkeypatch.delitem(sys.modules, "jax", raising=False)
    monkeypatch.delitem(sys.modules, "warp", raising=False)
    monkeypatch.delitem(sys.modules, "torch", raising=False)
    assert drake._start_method() == "fork"
    monkeypatch.setitem(sys.modules, "jax", sys)
    assert drake._start_method() == "forkserver"


def test_engine_threads_reach_the_worker_processes(monkeypatch):
    """``threads`` of ``simulate`` and ``lyapunov`` become Drake's worker processes (one
    driver block): stepping blocks on threads gained nothing, the step holding the GIL."""
    from cip import drake

    built = []
    init = drake.DrakeRollout.__init__

    def spy(self, model, n_realizations, threads):
        init(self, model, n_realizations, threads)
        built.append((n_realizations, self.processes))

    monkeypatch.setattr(drake.DrakeRollout, "__init__", spy)
    engine = get_engine("drake")
    params = BalanceParams(beta=20.0, tau=0.01, dt=1e-3)
    engine.simulate("single", params, 0.02, 4, seed=3, threads=2, progress=False)
    assert built == [(4, 2)]
    built.clear()
    lam = engine.lyapunov("single", params, 0.05, 2, seed=3, threads=2, transient=0.0)
    assert built and all(p == 2 for _, p in built), built
    assert np.isfinite(lam.per_realization).all()
