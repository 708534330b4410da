"""Fixtures shared across test modules, and how pytest-xdist spreads the tests over workers."""

from __future__ import annotations

import os
import re

import pytest

from cipcore.blas import one_blas_thread


@pytest.fixture(scope="session", autouse=True)
def _one_blas_thread():
    """Every worker's BLAS on one thread, as the command line runs (:mod:`cipcore.blas`):
    the libraries loaded, and through the environment those loaded later and those of
    child processes."""
    with one_blas_thread():
        yield


#: Work units of pytest-xdist (``-n auto``, pyproject's addopts) that hold more than one test:
#: one worker runs a group's tests one after another.  "realtime": the experiment's 50 Hz
#: tests, which must not run beside each other; the others share a session or module
#: fixture that each worker running one of their tests would compute again (a smoke run,
#: a selftest run, a compared sweep...).  A key is a test file, or a file and a test
#: (parameters dropped); every other test is a unit of its own.  (The ``xdist_group``
#: mark would say this in the tests, but xdist 3.8's ``--dist loadgroup`` ignores it
#: under pytest 9.2's node ids: pytest-xdist issue 1386.)
XDIST_GROUPS = {
    "test_experiment_server.py": "realtime",
    "test_experiment_browser.py": "realtime",
    "test_server_load.py": "realtime",
    "test_harness.py": "smoke",
    "test_report_browser.py": "smoke",
    "test_ci_gate.py::test_selftest_junit_has_the_unmodified_model_and_each_fault": "selftest",
    "test_schemas.py::test_selftest_json_follows_its_schema": "selftest",
    "test_regression_instrument.py::test_selftest_flags_every_catalogued_fault": "selftest",
    "test_regression_instrument.py::test_selftest_cli": "selftest",
    "test_case_exchange.py": "case_exchange",
    "test_engine_families.py": "engine_families",
    "test_engine_twins.py": "engine_twins",
    "test_experiment_analyze.py": "experiment_analyze",
    "test_paper_table.py": "paper_table",
    "test_sweep_studies.py": "sweep_studies",
    "test_process_workers.py": "fork",
}


#: engines whose import costs seconds in every process that runs one of their tests: a
#: test naming one (in its file, its name or a parameter) not grouped above joins the
#: engine's group, so one worker imports it.  MJX: JAX, and with it MJX's Warp backend
#: wherever warp is installed (``mujoco.mjx`` imports ``warp`` and ``mujoco_warp`` when
#: it can): 3 to 4 s per process, paid by both workers when the MJX tests were spread
ENGINE_GROUPS = ("mjx",)


def xdist_unit(nodeid: str) -> str:
    """The work unit of a test: its group in :data:`XDIST_GROUPS`, else its engine's in
    :data:`ENGINE_GROUPS`, else the test itself."""
    path, _, name = nodeid.partition("::")
    module = path.rsplit("/", 1)[-1]
    group = XDIST_GROUPS.get(f"{module}::{name.split('[')[0]}") or XDIST_GROUPS.get(module)
    if group:
        return group
    words = set(re.split(r"[^a-z0-9]+", f"{module} {name}".lower()))
    return next((g for g in ENGINE_GROUPS if g in words), nodeid)


#: the worker that runs the "realtime" group, first; the other workers run at a lower
#: priority (``os.nice``), so their CPU-bound tests yield the cores to its 50 Hz loop,
#: server and browser
REALTIME_WORKER = "gw0"

#: groups a worker takes before any other unit: "realtime" (above); "fork", the engines'
#: worker processes (``cip.workers``), first on a fresh worker, where no test has loaded
#: JAX yet, so that they fork (0.1 to 0.4 s a split) instead of starting from a fork
#: server that imports the engine in every process (2 to 3 s a split, every one of them
#: importing the engine again); a test of their own runs the fork server on purpose
FIRST_ON = {"realtime": REALTIME_WORKER, "fork": "gw1"}


def pytest_configure(config) -> None:
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if worker is not None and worker != REALTIME_WORKER:
        os.nice(10)


@pytest.hookimpl(optionalhook=True)  # a hook of pytest-xdist: unknown without it
def pytest_xdist_auto_num_workers(config) -> int:
    """``-n auto``: one worker per core, and one more.  A fifth of the tests' time is spent
    waiting (engine timeouts, the experiment's 50 Hz real time, the browser, processes
    starting), which the extra worker fills (the README's install on 2 cores, 7 December:
    131 s with 2 workers, 122 s with 3, 124 s with 4)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0)) + 1
    return (os.cpu_count() or 1) + 1


@pytest.hookimpl(optionalhook=True)  # a hook of pytest-xdist: unknown without it
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadgroup`` with the groups of :data:`XDIST_GROUPS` (pytest-xdist's scope
    scheduler: the largest groups first, then one test at a time to whichever worker is
    free), each group of :data:`FIRST_ON` first on its worker."""
    if config.getoption("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class Grouped(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return xdist_unit(nodeid)

        def _assign_work_unit(self, node) -> None:
            queue = self.workqueue
            pinned = [g for g in FIRST_ON if g in queue]
            if pinned and len(pinned) < len(queue):
                # a pinned group's worker takes it first; the others take any other unit
                for group in pinned:
                    queue.move_to_end(group, last=FIRST_ON[group] != node.gateway.id)
            super()._assign_work_unit(node)

    return Grouped(config, log)


@pytest.fixture
def mujoco_nan_after(monkeypatch):
    """``nan_after(at, row=0)``: from now on in this test, MuJoCo's rollout
    (:class:`cip.runner.MujocoRollout`) returns non-finite states for realisation ``row``
    of each of its blocks from global step ``at`` on (each rollout counts its own steps):
    an engine whose state goes non-finite mid-run, wherever the suite steps MuJoCo."""
    import numpy as np

    from cip.runner import MujocoRollout

    real = MujocoRollout.__call__

    def nan_after(at: int, row: int = 0) -> None:
        def call(self, state, ctrl, out):
            real(self, state, ctrl, out)
            done = getattr(self, "nan_steps", 0)
            self.nan_steps = done + ctrl.shape[1]
            if at - done < ctrl.shape[1] and row < out.shape[0]:
                out[row, max(at - done, 0) :] = np.nan

        monkeypatch.setattr(MujocoRollout, "__call__", call)

    return nan_after


@pytest.fixture(scope="session")
def smoke_run_once(tmp_path_factory):
    """One ``cip-validate run --profile smoke`` (figures included) for the whole session:
    (exit status, output directory).  Read it only; copy what a test changes."""
    from validation.cli.main import main

    out = tmp_path_factory.mktemp("smoke")
    return main(["run", "--profile", "smoke", "--out", str(out)]), out


@pytest.fixture(scope="session")
def selftest_run(tmp_path_factory):
    """One ``cip-validate selftest --json --junit FILE`` for the whole session: the whole
    catalogue at its listed sizes, seed 1, 2 realisations (the defaults): (exit status,
    its JSON document, its JUnit file, the arguments ``run_selftest`` got, what it
    returned).  The catalogue test and the tests of the JSON, JUnit and text outputs read
    this one run (about 7 s of CPU each otherwise).  One pytest-xdist worker runs them
    (``XDIST_GROUPS``)."""
    import contextlib
    import io
    import json

    from validation.cli.main import main
    from validation.faults import selftest

    junit = tmp_path_factory.mktemp("selftest") / "s.xml"
    calls = []
    real = selftest.run_selftest

    def recorded(*args):
        calls.append((args, real(*args)))
        return calls[-1][1]

    out = io.StringIO()
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(out):
        mp.setattr(selftest, "run_selftest", recorded)
        code = main(["selftest", "--json", "--junit", str(junit), "--quiet"])
    ((args, result),) = calls
    return code, json.loads(out.getvalue()), junit, args, result


# Hypothesis profiles of the fuzz test generated from the parser (tests/test_fuzz_cli.py):
# "ci", its default here (a fixed seed and a budget under 60 s), and "long"
# (``pytest tests/test_fuzz_cli.py --hypothesis-profile=long``: 10,000 examples).
# Registered only: the other tests keep Hypothesis's default profile.
from hypothesis import settings as _hypothesis_settings  # noqa: E402

_hypothesis_settings.register_profile(
    "ci", derandomize=True, max_examples=130, deadline=None, database=None
)
_hypothesis_settings.register_profile("long", max_examples=10_000, deadline=None)
