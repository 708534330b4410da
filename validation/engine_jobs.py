"""Engines side by side: each engine's checks in a process of its own, ``jobs`` at a time.

One job.  :func:`run_side_by_side` calls ``work(name)`` once per job and returns
the values and wall seconds by name.  A job runs in a fresh process (started by a forkserver, so no
process forks a loaded JAX or warp runtime), or in this one where it must
(:attr:`EngineJob.here`: an engine registered at run time, which another process
does not know).  The results do not depend on where or beside what a job ran:
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
interrupt or an error the processes still running are terminated, so nothing
keeps computing after the command ends.  A job's exception is raised here as it
was raised there (its message and type, where it pickles; else a
:class:`EngineJobError` with its message); a process that dies without an answer
(a segfault, the kernel's OOM killer) raises :class:`EngineJobError` naming the
engine and the signal.  With ``kept``, an error that ``kept(error)`` accepts becomes
that job's value instead, and the other jobs go on: one engine that crashes costs
the run nothing else.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from typing import Any

from validation.sweeps.lifeline import die_with_parent

__all__ = ["EngineJob", "EngineJobError", "run_side_by_side"]

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


def _child(conn: Connection, work: Callable[[str], Any], name: str) -> None:
    """A job's process: ``work(name)`` sent back as ("ok", value) or ("error", exception)."""
    die_with_parent()
    for key, value in SHARED_DEVICE_ENV.items():
        os.environ.setdefault(key, value)
    try:
        out: tuple = ("ok", work(name))
    except BaseException as exc:  # every failure goes back to the parent
        out = ("error", exc)
    try:
        conn.send(out)
    except Exception:  # the exception (or value) does not pickle: its text does
        conn.send(("error", EngineJobError(f"{type(out[1]).__name__}: {out[1]}")))
    finally:
        conn.close()


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
    the module docstring); ``seconds``: from the job's start (its process's included) to
    its value here.

    ``work`` must pickle (a module-level function or a :func:`functools.partial` of
    one).  ``started(name)`` is called as each job starts.  ``kept(error)``: True where a
    job's error (an :class:`Exception` it raised, or :class:`EngineJobError` for a
    process that died) is to be its value rather than end the run; an interrupt always
    ends it.  ``finished(name, value, seconds)`` is called as each value arrives, so that a
    caller interrupted later keeps what finished.  ``workers`` 1 runs every job here, one
    after the other, in the given order.

    The function is long because it owns the processes from their start to their end:
    starting, collecting and stopping share its state.
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
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["validation.sweeps.forkserver_lifeline"])
    pending = sorted((j for j in jobs if not j.here), key=lambda j: -j.cost)
    here = [j for j in jobs if j.here]
    running: dict[Connection, tuple[EngineJob, Any, float]] = {}
    out: dict[str, tuple[Any, float]] = {}

    def start(slots: int) -> None:
        while len(running) < slots and pending:
            job = _next(pending, [r[0] for r in running.values()])
            if job is None:
                return
            pending.remove(job)
            parent, child = ctx.Pipe(duplex=False)
            proc = ctx.Process(target=_child, args=(child, work, job.name),
                               name=f"cipval-engine-{job.name}", daemon=False)  # fmt: skip
            say(job.name)
            t0 = time.perf_counter()
            proc.start()
            child.close()  # the child's end lives in the child: its exit closes the pipe
            running[parent] = (job, proc, t0)

    def collect(conn: Connection) -> None:
        job, proc, t0 = running.pop(conn)
        try:
            kind, value = conn.recv()
        except EOFError:
            proc.join()
            kind, value = "error", _died(job.name, proc.exitcode)
        finally:
            conn.close()
        proc.join()
        if kind == "error":
            value = failed(value)
        out[job.name] = (value, time.perf_counter() - t0)
        done(job.name, *out[job.name])

    try:
        start(workers - 1 if here else workers)
        for j in here:  # the jobs beside it keep running; their answers wait in the pipes
            out[j.name] = _here(j, work, say, failed)
            done(j.name, *out[j.name])
        start(workers)
        while running:
            for conn in wait(list(running)):
                collect(conn)  # type: ignore[arg-type]
            start(workers)
    finally:
        _stop([r[1] for r in running.values()])
    return {j.name: out[j.name] for j in jobs}


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
