"""Schedulers: compute every missing grid point, locally or on Dask, persist each at once."""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from pathlib import Path

from cipcore.params import ParameterError
from cipcore.registry import get_engine

from .evaluate import evaluate_point
from .gains import point_gains
from .gpu import evaluate_points as evaluate_gpu_points
from .lifeline import die_with_parent
from .store import DirectoryLock, Store, write_dataset
from .study import Study, point_key


@dataclass
class SweepReport:
    """What a sweep did: points computed here, reused from the directory, the dataset,
    and the points where a realisation diverged (point -> realisations)."""

    computed: int
    reused: int
    dataset_path: Path
    diverged: list[dict] = field(default_factory=list)


def run_sweep(
    study: Study,
    out_dir: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = False,
    on_point: Callable[[dict], None] | None = None,
    wait_for_lock: bool = False,
) -> SweepReport:
    """Compute every missing grid point, persist each, assemble ``sweep.nc``.

    A study with a ``[gain]`` target first finds beta* of every point
    (:func:`validation.sweeps.gains.point_gains`, cached in ``DIR/gains``).
    ``workers`` single-threaded processes (default: one per core; 1 runs in
    this process), or the Dask cluster at ``scheduler``.  The directory is
    locked for the whole sweep (:class:`validation.sweeps.store.DirectoryLock`):
    a second sweep into it fails at once naming the holder, or with
    ``wait_for_lock`` waits and then reuses the finished points.
    """
    from tqdm.auto import tqdm

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

        try:
            if not todo:
                pass
            elif packs:  # one batch of every point x realisation
                for p, r in zip(todo, evaluate_gpu_points(sd, todo), strict=True):
                    finished(p, r)
            elif scheduler:
                _run_dask(scheduler, sd, todo, finished, gains)
            elif (workers or os.cpu_count() or 1) <= 1:
                for p in todo:
                    finished(p, evaluate_point(sd, p, 1, gains.get(point_key(p))))
            else:
                _run_local(workers or os.cpu_count() or 1, sd, todo, finished, gains)
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
    return SweepReport(computed=len(todo), reused=reused, dataset_path=path, diverged=diverged)


def _run_local(workers: int, sd: dict, todo: list[dict], finished, gains: dict) -> None:
    # forkserver, not fork: forking a process that has loaded a multithreaded
    # runtime (JAX/XLA for mjx, warp) can deadlock the child
    # every process of the pool dies with this one (validation.sweeps.lifeline)
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["validation.sweeps.forkserver_lifeline"])
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=die_with_parent)
    try:
        futs = {pool.submit(evaluate_point, sd, p, 1, gains.get(point_key(p))): p for p in todo}
        pending = set(futs)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                finished(futs[f], f.result())
    except BaseException:
        # interrupted or a point failed: drop the queued points, keep the finished ones
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


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
