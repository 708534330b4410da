"""Realisations split across worker processes, for backends whose step holds the GIL.

pydrake, pybullet, Exudyn and OpenSim (Simbody) step from Python calls that hold
the interpreter lock: two threads stepping two realisation blocks take as long
as one thread stepping both.  :class:`ProcessBlocks` wraps such a
:class:`cip.runner.RolloutBackend`: the R realisations are split into
consecutive blocks, and each block is stepped by its own instance of the backend
in a worker process.  The engines (:class:`cip.engines.rigid_body.RigidBodyEngine`) give each
of the driver's blocks a ``ProcessBlocks`` of one worker (``one_in_process=False``),
so that the blocks, each on its own thread, never wait for each other: one
``ProcessBlocks`` of several workers meets them all at every delay chunk, and a
core that stalls in one chunk holds up every block (Drake, 2 cores: 1.51 to 1.55
times one process against 1.73 to 1.75 for independent blocks).  Every realisation
of these backends has its own world (context, client, system or manager) and
element-wise forces, so a split changes no number: the result is bit-identical for
any worker count (tested per engine).

Each delay chunk costs one round trip per worker: the block's states and
controls out, its recorded states back (R/W x n x nstate float64: 100 steps of 8
coupled realisations are about 0.1 MB).

Workers are forked where the platform allows (the child inherits the loaded
engine and the model: no import, no pickling).  A backend whose engine library is
imported lazily (on building its first world) names that import in an optional
``preload()`` static method: the parent runs it before forking (an import, free
after the first), so that the workers inherit the library instead of each importing
it at every call (pydrake 0.25 s, OpenSim 0.47 s, Exudyn 0.13 s, pybullet 0.08 s on
the development machine; a Drake or Simbody call's worker start-up took 0.22 to
0.24 s before, 0.02 s after).  A process that has loaded a runtime with threads of
its own (JAX, warp, torch) must not fork; the workers then start from a fork
server, which needs the backend class and the model picklable.  A backend built
inside a function (a fault of :mod:`validation.faults.catalogue`) is not: it then steps in
this process, and :attr:`ProcessBlocks.workers` says how many processes ran.

Workers end with their rollout object, at the parent's exit, or, when the
parent is killed outright (no clean-up runs), within :data:`ORPHAN_POLL_S` of
its death: no orphaned worker keeps a core.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import pickle
import signal
import sys
import weakref
from multiprocessing.connection import Connection
from typing import Any

import numpy as np

#: modules that start threads of their own: forking a process that loaded one can deadlock
#: the child, so the workers then start from a fork server instead (each imports)
THREADED_RUNTIMES = ("jax", "warp", "torch")


#: s between a waiting worker's checks that its parent is alive (a forked worker
#: inherits the pipes' other ends, so a killed parent shows no end-of-file there)
ORPHAN_POLL_S = 1.0


def start_method() -> str:
    """``fork`` (cheap: the child has the engine loaded) unless a threaded runtime is
    loaded or the platform has no fork; then ``forkserver`` or ``spawn``."""
    methods = mp.get_all_start_methods()
    if "fork" in methods and not any(m in sys.modules for m in THREADED_RUNTIMES):
        return "fork"
    return "forkserver" if "forkserver" in methods else "spawn"


def _serve(conn: Connection, backend: type, model: Any, n_realizations: int) -> None:
    """A worker: step its block for every (state, ctrl) received, until None.  An
    exception is sent back and raised in the parent."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and ends us
    # read before "ready" is sent: the parent may be killed as soon as it has that
    # answer, and a pid read later would already be the reaper's
    parent = os.getppid()
    try:
        block = backend(model, n_realizations, 1)
    except Exception as exc:
        conn.send(exc)
        return
    conn.send("ready")
    while True:
        try:
            if not conn.poll(ORPHAN_POLL_S):
                if os.getppid() != parent:  # the parent died (killed): end with it
                    return
                continue
            job = conn.recv()
        except (EOFError, OSError):
            return
        if job is None:
            return
        state, ctrl = job
        out = np.empty((*ctrl.shape[:2], state.shape[1]))
        try:
            block(state, ctrl, out)
        except Exception as exc:
            conn.send(exc)
            continue
        conn.send((out, block.warnings()))


def _replies(conns: list[Connection]) -> list[Any]:
    """One reply from every worker (so that no answer is left in a pipe), then the
    first error among them raised here."""
    replies = [conn.recv() for conn in conns]
    for reply in replies:
        if isinstance(reply, BaseException):
            raise reply
    return replies


def _picklable(*objs: object) -> bool:
    try:
        pickle.dumps(objs)
    except Exception:  # local classes, lambdas, unpicklable engine objects
        return False
    return True


class ProcessBlocks:
    """:class:`cip.runner.RolloutBackend` stepping consecutive realisation blocks of
    ``backend`` in worker processes (one block per worker; see the module docstring).

    Parameters
    ----------
    backend : the engine's backend class, built as ``backend(model, n, 1)`` per block.
    model : the compiled MuJoCo CIP.
    n_realizations : number of realisations R.
    workers : worker processes asked for; at most R.  1 (unless ``one_in_process`` is
        False), a daemonic process (a pool's worker, which may not start processes) or
        a fork server that cannot carry ``backend`` steps every realisation in this
        process.
    one_in_process : with one worker, step in this process (True) or in one worker
        process (False: the caller runs several such blocks on threads, each thread
        waiting on its own process, :class:`cip.engines.rigid_body.RigidBodyEngine`).
    """

    def __init__(
        self,
        backend: type,
        model: Any,
        n_realizations: int,
        workers: int,
        *,
        one_in_process: bool = True,
    ) -> None:
        workers = max(1, min(int(workers), n_realizations))
        method = start_method()
        remote = workers > 1 or not one_in_process
        if remote and mp.current_process().daemon:
            remote = False  # a pool's worker (a sweep point) may not start processes
        if remote and method != "fork" and not _picklable(backend, model):
            remote = False
        self.workers = workers if remote else 1
        sizes = [len(b) for b in np.array_split(np.arange(n_realizations), self.workers)]
        self.bounds = np.cumsum([0, *sizes])
        self.conns: list[Connection] = []
        self.procs: list[Any] = []
        self.local = None if remote else backend(model, n_realizations, 1)
        if self.local is not None:
            return
        if method == "fork" and hasattr(backend, "preload"):
            backend.preload()  # imported here once, inherited by every fork from now on
        ctx = mp.get_context(method)
        for size in sizes:
            parent, child = ctx.Pipe()
            proc = ctx.Process(target=_serve, args=(child, backend, model, size), daemon=True)
            proc.start()
            child.close()
            self.conns.append(parent)
            self.procs.append(proc)
        self._finalizer = weakref.finalize(self, ProcessBlocks._stop, self.conns, self.procs)
        _replies(self.conns)  # "ready", or the error of building a block
        self._warnings = [0] * self.workers

    @staticmethod
    def _stop(conns: list[Connection], procs: list) -> None:
        for conn in conns:
            with contextlib.suppress(OSError, ValueError):
                conn.send(None)
        for proc in procs:
            proc.join(timeout=5)
            if proc.is_alive():
                proc.terminate()

    def close(self) -> None:
        """End the workers now (they also end when this object is collected)."""
        if self.local is None:
            self._finalizer()

    def __call__(self, state: np.ndarray, ctrl: np.ndarray, out: np.ndarray) -> None:
        if self.local is not None:
            self.local(state, ctrl, out)
            return
        b = self.bounds
        for i, conn in enumerate(self.conns):
            conn.send((state[b[i] : b[i + 1]], ctrl[b[i] : b[i + 1]]))
        for i, (states, warned) in enumerate(_replies(self.conns)):
            out[b[i] : b[i + 1]], self._warnings[i] = states, warned

    def warnings(self) -> int:
        """The backend's warnings (failed steps), summed over the blocks."""
        if self.local is not None:
            return self.local.warnings()
        return sum(self._warnings)
