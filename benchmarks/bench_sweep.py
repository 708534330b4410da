"""Sweep throughput: 1 and 2 workers, local process pool and a local Dask cluster.

One run, the same study (coupled MuJoCo CIP, 8 grid points); prints grid points
per second for each configuration.  Worker start-up is counted (a fresh pool or
cluster per configuration), as a user would see it.
Usage:  python benchmarks/bench_sweep.py [--points 8] [--duration 5]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from validation.sweep import Study, SweepPool, run_sweep


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, default=8)
    ap.add_argument("--duration", type=float, default=30.0)
    a = ap.parse_args()
    study = Study(name="bench", model="coupled", engine="mujoco", metrics=("rms", "max_angle"),
                  realizations=8, duration=a.duration, seed=1,
                  grid={"rod_length_ratio": [0.5 + 0.25 * k for k in range(a.points)]})  # fmt: skip
    run_sweep(study, Path(tempfile.mkdtemp()), pool=SweepPool(workers=1))  # warm the numba cache
    rows = []
    for workers in (1, 2):
        t = time.perf_counter()
        run_sweep(study, Path(tempfile.mkdtemp()), pool=SweepPool(workers=workers))
        rows.append((f"local, {workers} worker(s)", time.perf_counter() - t))
    from dask.distributed import LocalCluster

    for workers in (1, 2):
        t = time.perf_counter()
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster:  # fmt: skip
            run_sweep(
                study, Path(tempfile.mkdtemp()), pool=SweepPool(scheduler=cluster.scheduler_address)
            )
        rows.append((f"dask LocalCluster, {workers} worker(s)", time.perf_counter() - t))
    steps = a.points * 8 * round(a.duration / 1e-3)
    print(f"sweep of {a.points} points x 8 realisations x {a.duration:g} s (coupled MuJoCo CIP)")
    for name, t in rows:
        print(f"  {name:32s} {a.points / t:6.2f} points/s  {steps / t / 1e3:7.1f} k steps/s  "
              f"({t:.1f} s)")  # fmt: skip
    print(f"  speed-up 1 -> 2 workers: local x{rows[0][1] / rows[1][1]:.2f}, "
          f"dask x{rows[2][1] / rows[3][1]:.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
