"""BLAS on one thread for every command (:mod:`cipcore.blas`)."""

from __future__ import annotations

import os

from threadpoolctl import threadpool_info, threadpool_limits

from cipcore.blas import BLAS_THREAD_VARIABLES, one_blas_thread


def _blas_threads() -> set[int]:
    return {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}


def _blas_counts() -> list[int]:
    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


def test_the_loaded_libraries_run_one_thread_inside_and_theirs_after() -> None:
    """Inside, one thread each; after, what each had (2, or 1 for a library that loaded
    with OPENBLAS_NUM_THREADS=1 and cannot grow)."""
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_counts()
        assert 2 in before
        with one_blas_thread():
            assert _blas_threads() == {1}
            assert all(os.environ[v] for v in BLAS_THREAD_VARIABLES)
        assert _blas_counts() == before


def test_a_command_runs_inside_it(monkeypatch, capsys) -> None:
    """``cip-validate stability`` computes characteristic roots (scipy's eig): its BLAS
    had one thread while it ran."""
    import reduced.stability as stability
    from validation.cli.main import main

    seen: list[set[int]] = []
    real = stability.characteristic_roots

    def recorded(*args, **kwargs):
        seen.append(_blas_threads())
        return real(*args, **kwargs)

    monkeypatch.setattr(stability, "characteristic_roots", recorded)
    with threadpool_limits(limits=2, user_api="blas"):
        assert 2 in _blas_counts()  # a library the command would run on two threads
        assert main(["stability", "--model", "single", "--beta", "21"]) == 0
    assert seen and all(s == {1} for s in seen)


def test_a_blas_loaded_later_reads_the_variables() -> None:
    """A fresh process that loads numpy, enters the limit, then loads scipy's own BLAS:
    both on one thread."""
    import subprocess
    import sys

    code = ("import numpy\nfrom cipcore.blas import one_blas_thread\n"
            "from threadpoolctl import threadpool_info\n"
            "with one_blas_thread():\n    import scipy.linalg\n"
            "    print(sorted({i['num_threads'] for i in threadpool_info()"
            " if i['user_api'] == 'blas'}))\n")  # fmt: skip
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True)  # fmt: skip
    assert out.stdout.strip() == "[1]"
