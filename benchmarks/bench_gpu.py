"""GPU throughput of the mujoco-warp engine with the delayed random-gain control on the device.

Prints, for 1, 128, 1024, 8192 and 65536 worlds (coupled CIP, paper parameters,
one delay chunk of d = tau/dt steps captured as one CUDA graph, the draws made
by GainNoise on the host and uploaded once per chunk):

* world-steps/s, and the ratio to MuJoCo on the CPU (``mujoco.rollout`` across
  all cores, host control) measured in the same run;
* the host's draw rate alone (the draws are made while the GPU runs the previous chunk);
* the wall time of the paper workload (100 realisations x 1200 s) and of a
  64-point x 1024-realisation x 30 s sweep (rod length x amplitude packed into
  one batch of 65536 worlds, recording every 5th step and fetching it each
  chunk), projected from a measured stretch unless ``--full`` runs them whole.

Without a CUDA device it prints "no CUDA device: skipped" and exits 0;
``--cpu-smoke`` then runs small sizes on warp's CPU device, labelled as such:
those numbers are a smoke test of the code path, not GPU numbers.

    python benchmarks/bench_gpu.py [--full] [--cpu-smoke] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from cipcore.models import get_model
from cipcore.noise import GainNoise
from cipcore.params import BalanceParams

PAPER = BalanceParams(beta=21.032)  # coupled model near threshold; dt = 1 ms, tau = 0.1 s


def _batch(worlds: int, device: str, models=None, controls=None, every: int = 0):
    from cip.engines.warp import point_control
    from cip.engines.warp_batch import WarpBatch
    from cip.model import CIPParams, build

    if models is None:
        phys = CIPParams.from_reduced(PAPER)
        models, controls = [build("coupled", phys)], [point_control(PAPER, phys, 1e-3)]
    P = len(models)
    return WarpBatch(models, controls, worlds // P, 2, device, max_chunk=PAPER.delay_steps,
                     every=every)  # fmt: skip


def gpu_rate(worlds: int, device: str, chunks: int, seed: int, **kw) -> tuple[float, float]:
    """(world-steps/s with host draws and upload, host draw rate in draws/s)."""
    b = _batch(worlds, device, **kw)
    d = PAPER.delay_steps
    noise = GainNoise(seed, b.W, 2)
    b.advance(noise.next_chunk(d), fetch=False)  # compiles / captures the graph
    b.synchronize()
    t_draw = 0.0
    t0 = time.perf_counter()
    for _ in range(chunks):
        t1 = time.perf_counter()
        xi = noise.next_chunk(d)
        t_draw += time.perf_counter() - t1
        b.advance(xi, fetch=bool(b.every))
    b.synchronize()
    wall = time.perf_counter() - t0
    return b.W * d * chunks / wall, b.W * d * 2 * chunks / t_draw


def cpu_rate(worlds: int, chunks: int, seed: int) -> float:
    """MuJoCo on the CPU (host control, mujoco.rollout over all cores), world-steps/s."""
    from cip.model import CIPParams
    from cip.runner import CIPRunner

    threads = os.cpu_count() or 1
    r = CIPRunner("coupled", PAPER, CIPParams.from_reduced(PAPER), worlds, 1e-3, threads=threads)
    noise = GainNoise(seed, worlds, get_model("coupled").n_controllers)
    d = PAPER.delay_steps
    r.advance(noise.next_chunk(d))
    t0 = time.perf_counter()
    for _ in range(chunks):
        r.advance(noise.next_chunk(d))
    return worlds * d * chunks / (time.perf_counter() - t0)


def sweep_grid(n_points: int):
    """rod length x amplitude, sqrt(n_points) values each: models and device controls."""
    from cip.engines.warp import point_control
    from cip.model import CIPParams, build

    k = round(np.sqrt(n_points))
    models, controls = [], []
    for ratio in np.linspace(0.5, 4.0, k):
        phys = CIPParams.from_reduced(PAPER, rod_length=float(ratio) * 9.81 / PAPER.alpha)
        m = build("coupled", phys)
        for amp in np.geomspace(1e-5, 1e-2, k):
            models.append(m)
            controls.append(point_control(PAPER, phys, float(amp)))
    return models, controls


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--full", action="store_true", help="run the two workloads whole")
    smoke = "without CUDA: small sizes on warp's CPU device (not GPU numbers)"
    ap.add_argument("--cpu-smoke", action="store_true", help=smoke)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    from cipcore.gpu import DEVICE_ENV, warp_unavailable

    os.environ.pop(DEVICE_ENV, None)
    reason = warp_unavailable(("warp", "mujoco_warp"))
    if reason is None:
        device, sizes, chunks, label = "cuda:0", (1, 128, 1024, 8192, 65536), 20, "GPU"
    elif not args.cpu_smoke:
        print(f"no CUDA device: skipped ({reason})")
        return 0
    else:
        device, sizes, chunks, label = "cpu", (1, 8, 32), 2, "SMOKE RUN on warp's CPU device"
        print("no CUDA device: GPU benchmark skipped; smoke run on warp's CPU device follows.")
        print("These are NOT GPU numbers: they only show that the code path runs.")
    print(f"# {label}: coupled CIP, d = {PAPER.delay_steps} steps per chunk, seed {args.seed}")
    cpu_worlds = 64 if device != "cpu" else 8
    cpu = cpu_rate(cpu_worlds, 5 if device != "cpu" else 2, args.seed)
    print(f"MuJoCo CPU ({os.cpu_count()} threads, {cpu_worlds} worlds): {cpu:.3g} world-steps/s")
    print(f"{'worlds':>8} {'world-steps/s':>14} {'x CPU':>8} {'host draws/s':>13}")
    rates = {}
    for w in sizes:
        rate, draws = gpu_rate(w, device, chunks, args.seed)
        rates[w] = rate
        print(f"{w:>8} {rate:>14.3g} {rate / cpu:>8.3g} {draws:>13.3g}")

    # paper workload: 100 realisations x 1200 s
    n_paper = round(1200.0 / PAPER.dt)
    if args.full and device != "cpu":
        b = _batch(100, device)
        noise = GainNoise(args.seed, 100, 2)
        t0 = time.perf_counter()
        for _ in range(n_paper // PAPER.delay_steps):
            b.advance(noise.next_chunk(PAPER.delay_steps), fetch=False)
        b.synchronize()
        print(f"paper workload 100 x 1200 s: {time.perf_counter() - t0:.1f} s wall (measured)")
    else:
        w100 = 100 if device != "cpu" else 4
        r100, _ = gpu_rate(w100, device, chunks, args.seed)
        print(f"paper workload 100 x 1200 s: {100 * n_paper / r100:.1f} s wall (projected from "
              f"{chunks} chunks of {w100} worlds; --full measures it)")  # fmt: skip

    # sweep: 64 points x 1024 realisations x 30 s, packed, recording every 5th step
    n_pts, n_real = (64, 1024) if device != "cpu" else (4, 2)
    models, controls = sweep_grid(n_pts)
    n_sweep = round(30.0 / PAPER.dt)
    kw = {"models": models, "controls": controls, "every": 5}
    if args.full and device != "cpu":
        b = _batch(n_pts * n_real, device, **kw)
        noise = GainNoise(args.seed, b.W, 2)
        t0 = time.perf_counter()
        for _ in range(n_sweep // PAPER.delay_steps):
            b.advance(noise.next_chunk(PAPER.delay_steps))
        print(f"sweep {n_pts} x {n_real} x 30 s: {time.perf_counter() - t0:.1f} s wall (measured)")
    else:
        rs, _ = gpu_rate(n_pts * n_real, device, chunks, args.seed, **kw)
        wall = n_pts * n_real * n_sweep / rs
        print(f"sweep {n_pts} x {n_real} x 30 s: {wall:.1f} s wall (projected from {chunks} "
              "chunks, records fetched; metrics not included)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
