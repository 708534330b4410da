"""Engines side by side: each engine's checks in a process of its own, ``jobs`` at a time.

One job.  :func:`run_side_by_side` calls ``work(name)`` once per job and returns
the values and wall seconds by name.  A job runs in a fresh process (started by a
forkserver, so that no process forks a loaded JAX or warp runtime), or in this one
where it must (:attr:`EngineJob.here`: an engine registered at run time, which
another process does not know).  The results do not depend on where or beside what a job ran:
every draw is fixed by the profile's seed and each engine's checks are
independent of the threads they get.

Scheduling, from what was measured before:

* the jobs start in the order of their cost (longest first; the caller measures
  it), which keeps the slowest engine off the end of the run;
* at most one job that uses an accelerator (``device`` other than ``"cpu"``) runs at
  a time: such engines take the device's memory when they start;
* the jobs that must run here run in this process while the first others run
  beside them.

Every process dies with this one (:mod:`validation.sweeps.lifeline`); on an
interrupt or an error the answers already in are handed over (``finished``) and
the processes still running are terminated, so nothing keeps computing after the
command ends.  A job's exception is raised here as it
was raised there (its message and type, where it pickles; else a
:class:`EngineJobError` with its message); a process that dies without an answer
(a segfault, the kernel's OOM killer) raises :class:`EngineJobError` naming the
engine and the signal.  With ``kept``, an error that ``kept(error)`` accepts becomes
that job's value instead, and the other jobs go on: one engine that crashes costs
the run nothing else.
"""

from __future__ import annotations

import os
import pickle
import signal
import time
from collections.abc import Callable, MutableMapping
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from typing import Any

from validation.sweeps.lifeline import die_with_parent, forkserver_context

__all__ = ["EngineJob", "EngineJobError", "run_side_by_side", "share_device"]

#: seconds a terminated process has to exit before it is killed
TERMINATE_GRACE_S = 5.0


class EngineJobError(RuntimeError):
    """An engine's process failed without an exception this process can rebuild."""


@dataclass(frozen=True)
class EngineJob:
    """One engine to check.

    name : its registry name.  cost : what orders the start (larger first; any unit).
    device : its capabilities' device ("cpu", "gpu").  here : it must run in this
    process (registered at run time).
    """

    name: str
    cost: float = 0.0
    device: str = "cpu"
    here: bool = False


#: Set in every job's process unless the user set it: JAX takes 75 % of a GPU's memory when
#: it starts (an engine that declares the CPU, MJX, runs on JAX's device, a GPU where there
#: is one), which would starve an engine beside it on the same device.
SHARED_DEVICE_ENV = {"XLA_PYTHON_CLIENT_PREALLOCATE": "false"}


def share_device(environ: MutableMapping[str, str]) -> None:
    """Add :data:`SHARED_DEVICE_ENV` to ``environ`` where it does not say otherwise: for a
    process whose engines share an accelerator with others (a job's, or the command's
    that starts them)."""
    for key, value in SHARED_DEVICE_ENV.items():
        environ.setdefault(key, value)


def _child(conn: Connection, work: Callable[[str], Any], name: str, env: dict) -> None:
    """A job's process: ``work(name)`` sent back as ("ok", value, seconds) or ("error",
    exception, seconds); ``seconds``: the work's wall time here.

    ``env`` is the starting process's environment when the job started, which the job
    gets (a forkserver's children would otherwise have the environment the forkserver
    started with), plus :data:`SHARED_DEVICE_ENV` where it does not say otherwise.

    Only what this process can rebuild from its pickle is sent as it is: an exception
    whose class cannot be rebuilt (a two-argument ``__init__``), or one that is not an
    :class:`Exception` (``SystemExit``, a ``KeyboardInterrupt`` from a signal to this
    process alone), goes back as an :class:`EngineJobError` with its text.
    """
    die_with_parent()
    os.environ.clear()
    os.environ.update(env)
    share_device(os.environ)
    t0 = time.perf_counter()
    try:
        out: tuple = ("ok", work(name))
    except BaseException as exc:  # every failure goes back to the parent
        out = ("error", exc if isinstance(exc, Exception) else _text(name, exc))
    out = (*out, time.perf_counter() - t0)
    try:
        data = pickle.dumps(out)
        pickle.loads(data)  # what the parent will do: a class it cannot rebuild fails here
    except Exception:
        data = pickle.dumps(("error", _text(name, out[1]), out[2]))
    try:
        conn.send_bytes(data)
    finally:
        conn.close()


def _text(name: str, error: object) -> EngineJobError:
    return EngineJobError(f"engine {name}: {type(error).__name__}: {error}")


def _died(name: str, code: int | None) -> EngineJobError:
    if code is not None and code < 0:
        try:
            why = f"killed by {signal.Signals(-code).name}"
        except ValueError:
            why = f"killed by signal {-code}"
    else:
        why = f"exited with status {code} without a result"
    return EngineJobError(f"engine {name}: its process {why}")


def _next(pending: list[EngineJob], running: list[EngineJob]) -> EngineJob | None:
    """The first pending job that may start beside ``running`` (one accelerator job at a
    time)."""
    busy = any(j.device != "cpu" for j in running)
    return next((j for j in pending if not (busy and j.device != "cpu")), None)


def run_side_by_side(
    jobs: list[EngineJob], work: Callable[[str], Any], workers: int,
    started: Callable[[str], None] | None = None,
    kept: Callable[[BaseException], bool] | None = None,
    finished: Callable[[str, Any, float], None] | None = None,
) -> dict[str, tuple[Any, float]]:  # fmt: skip
    """``{job.name: (work(job.name), seconds)}``, at most ``workers`` jobs at a time (see
    the module docstring); ``seconds``: the wall time of ``work`` (in the job's process;
    0 for one that died).

    ``work`` must pickle (a module-level function or a :func:`functools.partial` of
    one).  ``started(name)`` is called as each job starts.  ``kept(error)``: True where a
    job's error (an :class:`Exception` it raised, or :class:`EngineJobError` for a
    process that died) is to be its value rather than end the run; an interrupt always
    ends it.  ``finished(name, value, seconds)`` is called as each value arrives, so that a
    caller interrupted later keeps what finished.  ``workers`` 1 runs every job here, one
    after the other, in the given order.
    """
    say = started or (lambda name: None)
    done = finished or (lambda name, value, seconds: None)

    def failed(error: BaseException) -> BaseException:
        if isinstance(error, Exception) and kept is not None and kept(error):
            return error
        raise error

    if workers <= 1:
        out = {}
        for j in jobs:
            out[j.name] = _here(j, work, say, failed)
            done(j.name, *out[j.name])
        return out
    pool = _Processes(work, say, failed, done)
    here = [j for j in jobs if j.here]
    pool.pending = sorted((j for j in jobs if not j.here), key=lambda j: -j.cost)
    try:
        pool.start(workers - 1 if here else workers)
        for j in here:  # the jobs beside it keep running; their answers wait in the pipes
            pool.out[j.name] = _here(j, work, say, failed)
            done(j.name, *pool.out[j.name])
        pool.start(workers)
        while pool.running:
            for conn in wait(list(pool.running)):
                pool.collect(conn)  # type: ignore[arg-type]
            pool.start(workers)
    except BaseException:
        pool.drain()  # the answers already here are kept (``finished``), then every
        raise  # process still running is stopped
    finally:
        _stop([r[1] for r in pool.running.values()])
    return {j.name: pool.out[j.name] for j in jobs}


class _Processes:
    """The job processes of one :func:`run_side_by_side` call: started from a forkserver,
    collected as their answers arrive."""

    def __init__(self, work, say, failed, done) -> None:
        self.ctx = forkserver_context()
        self.work, self.say, self.failed, self.done = work, say, failed, done
        self.pending: list[EngineJob] = []
        self.running: dict[Connection, tuple[EngineJob, Any]] = {}
        self.out: dict[str, tuple[Any, float]] = {}

    def start(self, slots: int) -> None:
        """Start pending jobs up to ``slots`` running (one accelerator job at a time)."""
        while len(self.running) < slots and self.pending:
            job = _next(self.pending, [r[0] for r in self.running.values()])
            if job is None:
                return
            self.pending.remove(job)
            parent, child = self.ctx.Pipe(duplex=False)
            env = dict(os.environ)
            proc = self.ctx.Process(target=_child, args=(child, self.work, job.name, env),
                                    name=f"cipval-engine-{job.name}", daemon=False)  # fmt: skip
            self.say(job.name)
            # no interrupt between the fork and the bookkeeping: every started process
            # is in ``running``, where an interrupt stops it
            blocked = _block_interrupts()
            try:
                proc.start()
                child.close()  # the child's end lives in the child: its exit closes the pipe
                self.running[parent] = (job, proc)
            finally:
                _unblock(blocked)

    def collect(self, conn: Connection) -> None:
        """A job's answer (or its death) into ``out``; it stays in ``running`` until read."""
        job, proc = self.running[conn]
        kind, value, seconds = self._receive(job, proc, conn)
        del self.running[conn]
        if kind == "error":
            value = self.failed(value)
        self.out[job.name] = (value, seconds)
        self.done(job.name, value, seconds)

    def drain(self) -> None:
        """After an interrupt or an error: keep the values that have already arrived."""
        try:
            ready = wait(list(self.running), timeout=0)
        except BaseException:
            return
        for conn in ready:
            job, proc = self.running[conn]
            try:
                kind, value, seconds = self._receive(job, proc, conn)
            except BaseException:
                continue
            del self.running[conn]
            if kind == "error":
                try:
                    value = self.failed(value)  # kept: the job's value
                except BaseException:
                    continue
            self.out[job.name] = (value, seconds)
            self.done(job.name, value, seconds)

    @staticmethod
    def _receive(job: EngineJob, proc, conn: Connection) -> tuple[str, Any, float]:
        """(kind, value, seconds) of a job whose pipe is ready; its process reaped."""
        try:
            kind, value, seconds = pickle.loads(conn.recv_bytes())
        except EOFError:  # it died without an answer
            _reap(proc)
            return "error", _died(job.name, proc.exitcode), 0.0
        except Exception as exc:  # an answer that cannot be read
            kind, value, seconds = "error", _text(job.name, exc), 0.0
        finally:
            conn.close()
        _reap(proc)
        return kind, value, seconds


def _block_interrupts() -> set | None:
    """Block SIGINT and SIGTERM in this thread (the main thread: where they are handled);
    the set blocked before, or None where signals cannot be blocked."""
    if not hasattr(signal, "pthread_sigmask"):
        return None
    return signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})


def _unblock(before: set | None) -> None:
    """Restore the mask: a signal that arrived meanwhile is handled now."""
    if before is not None:
        signal.pthread_sigmask(signal.SIG_SETMASK, before)


def _reap(proc) -> None:
    """Wait for a finished job's process to exit: its answer is in, so it has at most
    :data:`TERMINATE_GRACE_S` (threads it left behind) before it is stopped."""
    proc.join(TERMINATE_GRACE_S)
    if proc.exitcode is None:
        _stop([proc])


def _here(job: EngineJob, work: Callable[[str], Any], say: Callable[[str], None],
          failed: Callable[[BaseException], BaseException]) -> tuple[Any, float]:  # fmt: skip
    """A job run in this process: its value (or its kept error) and wall seconds."""
    say(job.name)
    t0 = time.perf_counter()
    try:
        value = work(job.name)
    except Exception as exc:
        value = failed(exc)
    return value, time.perf_counter() - t0


def _stop(procs: list) -> None:
    """Terminate the processes still running (an interrupt or another job's error)."""
    for p in procs:
        p.terminate()
    for p in procs:
        p.join(TERMINATE_GRACE_S)
        if p.exitcode is None:
            p.kill()
            p.join()
