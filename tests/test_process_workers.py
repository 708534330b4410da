"""Realisations of GIL-holding engines split across worker processes
(:class:`cip.workers.ProcessBlocks`): the same numbers for any split, errors raised
in the parent, workers ended with the rollout."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import engine_or_skip, running

from cipcore.params import BalanceParams

#: engines whose ``threads`` are worker processes (their step holds the GIL)
WORKER_ENGINES = ("drake", "bullet", "exudyn", "simbody", "pinocchio", "dart", "physx")


@pytest.fixture
def always_workers(monkeypatch):
    """Worker processes however small the run (the tests' runs are below the threshold)."""
    import cip.engines.rigid_body

    monkeypatch.setattr(cip.engines.rigid_body, "MIN_WORKER_STEPS", 0)


@pytest.mark.parametrize("name", WORKER_ENGINES)
@pytest.mark.parametrize("model", [pytest.param("single", marks=pytest.mark.slow), "coupled"])
def test_any_process_split_is_bit_identical(name, model, always_workers):
    """Every split of 3 realisations over 1, 2 and 3 worker processes gives the numbers of
    one process, to the bit.  The coupled model (its two balancers and the rod's
    constraint: every path of the single one and more) by default; the single model
    also with ``-m slow``."""
    engine = engine_or_skip(name)
    assert engine.backend_workers
    params = BalanceParams(beta=20.0, alpha=22.0, gamma=50.0, nu=0.6, tau=0.01, dt=1e-3)
    runs = {
        p: engine.simulate(model, params, 0.025, 3, seed=7, threads=p, progress=False)
        for p in (1, 2, 3)
    }
    assert np.isfinite(runs[1]["balancing_error"]).all()
    for p in (2, 3):
        assert set(runs[p].data) == set(runs[1].data)
        for field in runs[1].data:
            assert np.array_equal(runs[p][field], runs[1][field]), (p, field)


def test_a_split_from_the_fork_server_is_bit_identical(monkeypatch, always_workers):
    """The workers of a process that has loaded a threaded runtime start from a fork
    server (each imports the engine): the same numbers as the in-process run.  (The test
    above forks: pytest-xdist runs this module first on a fresh worker, tests/conftest.py.)"""
    from cip import workers

    engine = engine_or_skip("drake")
    params = BalanceParams(beta=20.0, alpha=22.0, gamma=50.0, nu=0.6, tau=0.01, dt=1e-3)
    one = engine.simulate("coupled", params, 0.025, 3, seed=7, threads=1, progress=False)
    monkeypatch.setattr(workers, "start_method", lambda: "forkserver")
    started = []
    init = workers.ProcessBlocks.__init__

    def spy(self, *args, **kwargs):
        init(self, *args, **kwargs)
        started.extend(p._popen.__class__.__module__ for p in self.procs)

    monkeypatch.setattr(workers.ProcessBlocks, "__init__", spy)
    two = engine.simulate("coupled", params, 0.025, 3, seed=7, threads=2, progress=False)
    assert started == ["multiprocessing.popen_forkserver"] * 2  # one per driver block
    for field in one.data:
        assert np.array_equal(two[field], one[field]), field


def test_workers_follow_threads_and_end_with_the_rollout():
    import gc

    from cip.engines.drake import DrakeRollout
    from cip.model import CIPParams, build
    from cip.workers import ProcessBlocks

    engine_or_skip("drake")
    model = build("coupled", CIPParams())
    rollout = ProcessBlocks(DrakeRollout, model, 3, workers=2)
    procs = list(rollout.procs)
    assert rollout.workers == 2 and all(p.is_alive() for p in procs)
    assert ProcessBlocks(DrakeRollout, model, 1, workers=4).workers == 1  # one per realisation
    del rollout
    gc.collect()
    for p in procs:
        p.join(timeout=10)
        assert not p.is_alive()


class _Failing:
    """A backend whose step raises: the worker's error must reach the parent."""

    def __init__(self, model, n_realizations, threads):
        self.n = n_realizations

    def __call__(self, state, ctrl, out):
        raise FloatingPointError(f"step failed in a block of {self.n}")

    def warnings(self) -> int:
        return 0


def test_an_error_in_a_worker_is_raised_in_the_parent():
    from cip.model import CIPParams, build
    from cip.workers import ProcessBlocks

    model = build("single", CIPParams())
    rollout = ProcessBlocks(_Failing, model, 4, workers=2)
    state = np.zeros((4, 10))
    with pytest.raises(FloatingPointError, match="block of 2"):
        rollout(state, np.zeros((4, 3, 1)), np.empty((4, 3, 10)))
    rollout.close()


#: what the parent of the workers has loaded (:class:`_Preloading`)
_LOADED: list[str] = []


class _Preloading:
    """A backend whose library is loaded by ``preload()``: each block writes how many
    loads its worker found, at its building, into every state."""

    @staticmethod
    def preload() -> None:
        _LOADED.append("library")

    def __init__(self, model, n_realizations, threads):
        self.found = len(_LOADED)

    def __call__(self, state, ctrl, out):
        out[...] = self.found

    def warnings(self) -> int:
        return 0


def test_forked_workers_inherit_the_library_the_parent_preloaded():
    """The parent runs the backend's ``preload()`` before forking, so no worker imports
    the engine's library at each call; not for a run in this process (the backend
    imports it when it needs it)."""
    from cip import workers
    from cip.model import CIPParams, build

    if workers.start_method() != "fork":
        pytest.skip(f"workers start from {workers.start_method()} here (a runtime with "
                    "threads is loaded): the preload is for forked workers")  # fmt: skip
    model = build("single", CIPParams())
    _LOADED.clear()
    workers.ProcessBlocks(_Preloading, model, 3, workers=1)
    assert _LOADED == []
    rollout = workers.ProcessBlocks(_Preloading, model, 3, workers=2)
    assert _LOADED == ["library"] and rollout.workers == 2
    out = np.empty((3, 2, 10))
    rollout(np.zeros((3, 10)), np.zeros((3, 2, 1)), out)
    assert (out == 1).all()  # every worker found it loaded when it built its block
    rollout.close()


def test_one_block_steps_in_a_process_of_its_own_when_asked():
    """``one_in_process=False``: a driver block in a worker process even alone (the
    engines run one such block per thread); by default one block steps here."""
    import os

    from cip import workers
    from cip.model import CIPParams, build

    class Pid(_Preloading):
        def __call__(self, state, ctrl, out):
            out[...] = os.getpid()

    model = build("single", CIPParams())
    here = workers.ProcessBlocks(Pid, model, 2, 1)
    assert here.local is not None and here.procs == []
    if workers.start_method() != "fork":
        pytest.skip("a local class reaches no fork server: it steps here (tested below)")
    away = workers.ProcessBlocks(Pid, model, 2, 1, one_in_process=False)
    assert away.local is None and len(away.procs) == 1 and away.workers == 1
    out = np.empty((2, 3, 10))
    away(np.zeros((2, 10)), np.zeros((2, 3, 1)), out)
    assert (out == away.procs[0].pid).all() and away.procs[0].pid != os.getpid()
    away.close()


def test_a_fork_server_runs_an_unpicklable_backend_in_process(monkeypatch):
    """With a threaded runtime loaded the workers cannot fork; a backend built inside a
    function (a fault's) cannot travel to a fork server, so it steps in this process."""
    from cip import workers
    from cip.model import CIPParams, build

    monkeypatch.setattr(workers, "start_method", lambda: "forkserver")

    class Local(_Failing):
        pass

    assert workers.ProcessBlocks(Local, build("single", CIPParams()), 4, 2).workers == 1


def test_workers_fork_only_without_a_threaded_runtime(monkeypatch):
    import sys

    from cip import workers

    monkeypatch.delitem(sys.modules, "jax", raising=False)
    monkeypatch.delitem(sys.modules, "warp", raising=False)
    monkeypatch.delitem(sys.modules, "torch", raising=False)
    assert workers.start_method() == "fork"
    monkeypatch.setitem(sys.modules, "jax", sys)
    assert workers.start_method() == "forkserver"


def test_engine_threads_reach_the_worker_processes(monkeypatch):
    """``threads`` of ``simulate`` and ``lyapunov`` become Drake's worker processes, one
    per driver block (stepping blocks on threads gained nothing, the step holding the
    GIL), each started before the driver's threads.  A run below ``MIN_WORKER_STEPS``
    realisation-steps starts none."""
    import threading

    import cip.engines.rigid_body
    from cip import workers

    engine = engine_or_skip("drake")
    built = []
    init = workers.ProcessBlocks.__init__

    def spy(self, *args, **kwargs):
        init(self, *args, **kwargs)
        built.append((args[2], len(self.procs), threading.current_thread().name))

    monkeypatch.setattr(workers.ProcessBlocks, "__init__", spy)
    params = BalanceParams(beta=20.0, tau=0.01, dt=1e-3)
    engine.simulate("single", params, 0.02, 4, seed=3, threads=2, progress=False)
    assert built == []  # 80 realisation-steps: cheaper than starting a worker
    monkeypatch.setattr(cip.engines.rigid_body, "MIN_WORKER_STEPS", 80)
    engine.simulate("single", params, 0.02, 4, seed=3, threads=2, progress=False)
    main = threading.main_thread().name
    assert built == [(2, 1, main), (2, 1, main)]  # two blocks, a process each
    built.clear()
    lam = engine.lyapunov("single", params, 0.05, 2, seed=3, threads=2, transient=0.0)
    assert built == [(1, 1, main), (1, 1, main)], built
    assert np.isfinite(lam.per_realization).all()


def test_a_pool_worker_steps_its_realisations_on_one_thread(monkeypatch, always_workers):
    """In a pool's worker (daemonic: a sweep point), which may not start processes, the
    driver runs one block on one thread (threads sharing the interpreter lock gain
    nothing there) and builds no worker process; the numbers are those of any split."""
    import multiprocessing as mp
    import threading

    from cip import workers

    engine = engine_or_skip("drake")
    params = BalanceParams(beta=20.0, tau=0.01, dt=1e-3)
    reference = engine.simulate("single", params, 0.02, 4, seed=3, threads=2, progress=False)
    built, threads = [], []
    init = workers.ProcessBlocks.__init__
    monkeypatch.setattr(
        workers.ProcessBlocks,
        "__init__",
        lambda self, *a, **k: built.append(a) or init(self, *a, **k),
    )
    real_thread = threading.Thread.__init__
    monkeypatch.setattr(
        threading.Thread,
        "__init__",
        lambda self, *a, **k: threads.append(k) or real_thread(self, *a, **k),
    )
    monkeypatch.setattr(mp.current_process(), "daemon", True)
    pooled = engine.simulate("single", params, 0.02, 4, seed=3, threads=2, progress=False)
    assert built == [] and threads == []
    for field in reference.data:
        assert np.array_equal(pooled[field], reference[field]), field


def test_the_worker_engines_are_every_installed_engine_that_declares_workers():
    from cipcore.registry import availability, engine_names, get_engine

    declared = {
        n
        for n in engine_names()
        if availability(n) is None and getattr(get_engine(n), "backend_workers", False)
    }
    assert declared == {n for n in WORKER_ENGINES if availability(n) is None}


@pytest.mark.parametrize("slow_worker", [False, True], ids=["prompt", "slow-after-ready"])
def test_workers_end_when_their_parent_is_killed(tmp_path, slow_worker):
    """SIGKILL of the run (no clean-up in it) leaves no orphaned worker behind, also
    when the parent dies while a worker is still between "ready" and its first wait
    (the worker must know its parent before it answers)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    slow = (
        "import multiprocessing.connection as mc\n"
        "_send = mc.Connection.send\n"
        "def send(self, obj):\n"
        "    _send(self, obj)\n"
        "    if isinstance(obj, str) and obj == 'ready':\n"
        "        time.sleep(1)\n"
        "mc.Connection.send = send\n"
    )
    code = (
        "import sys, time\n"
        + (slow if slow_worker else "")
        + "from cip.model import CIPParams, build\n"
        "from cip.workers import ProcessBlocks\n"
        "from test_process_workers import _Failing\n"
        "r = ProcessBlocks(_Failing, build('single', CIPParams()), 4, 2)\n"
        "print(*[p.pid for p in r.procs], flush=True)\n"
        "time.sleep(60)\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([os.getcwd(), os.path.dirname(__file__)])}
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=env
    )
    pids = [int(p) for p in proc.stdout.readline().split()]
    assert len(pids) == 2
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    deadline = time.monotonic() + 10
    alive = pids
    while alive and time.monotonic() < deadline:
        time.sleep(0.1)
        alive = [p for p in pids if running(p)]
    for pid in alive:  # leave no orphan behind on failure either
        os.kill(pid, signal.SIGKILL)
    assert not alive, f"workers {alive} outlived their killed parent"
