"""Schedulers: compute every missing grid point, locally or on Dask, persist each at once."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path

from cipcore.params import ParameterError
from cipcore.registry import get_engine
from validation.sweeps.evaluate import evaluate_point
from validation.sweeps.gains import point_gains
from validation.sweeps.gpu import evaluate_points as evaluate_gpu_points
from validation.sweeps.lifeline import die_with_parent, forkserver_context
from validation.sweeps.store import DirectoryLock, Store, write_dataset
from validation.sweeps.study import Study, point_key


@dataclass(frozen=True)
class SweepPool:
    """Where a sweep's grid points are computed; never what they compute.

    Attributes
    ----------
    workers : single-threaded worker processes (1: in this process; None: chosen by
        the work, :func:`choose_workers` timed on the first point).
    scheduler : the address of a Dask cluster to compute on instead.
    point_threads : threads of a point computed in this process (its realisations
        split across them).
    """

    workers: int | None = None
    scheduler: str | None = None
    point_threads: int = 1


@dataclass
class SweepReport:
    """What a sweep did: points computed here, reused from the directory, the dataset,
    and the points where a realisation diverged (point -> realisations)."""

    computed: int
    reused: int
    dataset_path: Path
    diverged: list[dict] = field(default_factory=list)
    schedule: str = ""


#: Seconds a local worker process costs before its first point: a fresh interpreter
#: importing numpy, scipy, MuJoCo and the numba kernels took 3.5 s on a 2-core machine at
#: load 29 (``python -c pass``: 0.16 s); 2 s is the estimate for a lightly loaded one.
WORKER_STARTUP_S = 2.0


def choose_workers(cores: int, point_s: float, remaining: int) -> tuple[int, str]:
    """Worker processes for ``remaining`` points that each take about ``point_s`` s.

    Processes pay off when the time they save, remaining x point_s x (1 - 1/w),
    exceeds :data:`WORKER_STARTUP_S`; otherwise the points run in this process.
    Returns the count and a sentence saying why.
    """
    w = max(1, min(cores, remaining))
    saved = remaining * point_s * (1.0 - 1.0 / w)
    if w > 1 and saved > WORKER_STARTUP_S:
        return w, (
            f"{w} worker processes: {remaining} more points of about {point_s:.2g} s "
            f"each save {saved:.2g} s > a process start-up (~{WORKER_STARTUP_S:g} s)"
        )
    return 1, (
        f"in this process: {remaining} more points of about {point_s:.2g} s each "
        f"would save {saved:.2g} s <= a process start-up (~{WORKER_STARTUP_S:g} s)"
    )


def run_sweep(
    study: Study,
    out_dir: str | Path,
    *,
    pool: SweepPool = SweepPool(),
    progress: bool = False,
    on_point: Callable[[dict], None] | None = None,
    wait_for_lock: bool = False,
) -> SweepReport:
    """Compute every missing grid point, persist each, assemble ``sweep.nc``.

    A study with a ``[gain]`` target first finds beta* of every point
    (:func:`validation.sweeps.gains.point_gains`, cached in ``DIR/gains``).
    ``pool`` says where: worker processes or a Dask cluster (:class:`SweepPool`);
    :attr:`SweepReport.schedule` says which was used; the numbers do not depend on
    it.  The directory is locked for the whole sweep
    (:class:`validation.sweeps.store.DirectoryLock`): a second sweep into it fails at
    once naming the holder, or with ``wait_for_lock`` waits and then reuses the
    finished points.  The function is long for a reason: it is the one place that
    picks the schedule and keeps every finished point whatever stops the sweep.
    """
    from tqdm.auto import tqdm

    workers, scheduler, point_threads = pool.workers, pool.scheduler, pool.point_threads

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with DirectoryLock(out, wait=wait_for_lock):
        store = Store(out, study)
        points = study.points()
        todo = [p for p in points if store.load(p) is None]
        reused = len(points) - len(todo)
        packs = get_engine(study.engine).capabilities.packs_points
        if packs and (study.compare or study.gain):
            raise ParameterError(
                f"engine {study.engine}: compare and [gain] studies run on a CPU engine "
                "(this engine packs points into one batch with the study's model and beta)"
            )
        gains = point_gains(study, out) if todo else {}
        bar = tqdm(total=len(points), initial=reused, desc=f"sweep {study.name}",
                   unit="point", disable=not progress)  # fmt: skip
        sd = study.as_dict()

        def finished(point: dict, result: dict) -> None:
            store.save(point, result)
            bar.update(1)
            if on_point:
                on_point(point)

        schedule = ""
        try:
            if not todo:
                pass
            elif packs:  # one batch of every point x realisation
                for p, r in zip(todo, evaluate_gpu_points(sd, todo), strict=True):
                    finished(p, r)
            elif scheduler:
                _run_dask(scheduler, sd, todo, finished, gains)
                schedule = f"on the Dask cluster at {scheduler}"
            else:
                rest = todo
                times: list[float] = []
                while workers is None or (workers > 1 and len(times) == 1 and rest):
                    # time a point here (a second one when the first, which includes
                    # the one-off imports and kernel loads, asks for processes)
                    t0 = time.perf_counter()
                    p0 = rest[0]
                    finished(p0, evaluate_point(sd, p0, 1, gains.get(point_key(p0))))
                    times.append(time.perf_counter() - t0)
                    rest = rest[1:]
                    workers, schedule = choose_workers(os.cpu_count() or 1, min(times), len(rest))
                if not times:
                    schedule = f"{workers} worker process(es), as asked"
                if workers <= 1:
                    for p in rest:
                        finished(p, evaluate_point(sd, p, point_threads,
                                                   gains.get(point_key(p))))  # fmt: skip
                elif rest:
                    _run_local(workers, sd, rest, finished, gains)
        finally:
            bar.close()
        path = write_dataset(study, store)
        diverged = []
        for p in points:
            res = store.load(p) or {}
            if res.get("diverged"):
                times = res.get("divergence_time") or []
                diverged.append({"point": p, "realizations": [
                    r for r, t in enumerate(times) if t is not None], "times_s": [
                    t for t in times if t is not None]})  # fmt: skip
    return SweepReport(computed=len(todo), reused=reused, dataset_path=path, diverged=diverged,
                       schedule=schedule)  # fmt: skip


def _run_local(workers: int, sd: dict, todo: list[dict], finished, gains: dict) -> None:
    # every process of the pool dies with this one (validation.sweeps.lifeline)
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=forkserver_context(),
                               initializer=die_with_parent)  # fmt: skip
    futs: dict = {}
    kept: set = set()
    try:
        futs = {pool.submit(evaluate_point, sd, p, 1, gains.get(point_key(p))): p for p in todo}
        pending = set(futs)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                kept.add(f)  # handed over once, even where its saving is interrupted
                finished(futs[f], f.result())
    except BaseException:
        # interrupted, or a point failed: drop the queued points, keep the finished ones
        try:
            _keep_points_in_progress(futs, kept, finished)
        finally:
            pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


def _keep_points_in_progress(futs: dict, kept: set, finished) -> None:
    """Cancel the queued points and keep each point in progress that finishes.

    The pool waits for its running points in any case, so their results are kept
    rather than thrown away; a point that failed (a Ctrl-C reaches the workers as
    well) is dropped.  Waiting raises only if this process is interrupted again
    where its signals are not the command line's (which count a later signal and
    break off nothing: :func:`validation.cli.args.interrupt_signals`).
    """
    for f in futs:
        f.cancel()
    for f, point in futs.items():
        if f in kept or f.cancelled():
            continue
        kept.add(f)
        if f.exception() is None:
            finished(point, f.result())


def _run_dask(address: str, sd: dict, todo: list[dict], finished, gains: dict) -> None:
    try:
        from dask.distributed import Client, as_completed
    except ImportError:
        raise ParameterError(
            "--scheduler needs dask.distributed: pip install 'cipval[dask]'"
        ) from None
    try:
        client = Client(address, timeout="10s")
    except OSError as exc:
        raise ParameterError(f"--scheduler: cannot reach {address!r} ({exc})") from None
    with client:
        futs = [client.submit(evaluate_point, sd, p, 1, gains.get(point_key(p)), pure=False)
                for p in todo]  # fmt: skip
        point_of = {f.key: p for f, p in zip(futs, todo, strict=True)}
        for fut in as_completed(futs):
            finished(point_of[fut.key], fut.result())
