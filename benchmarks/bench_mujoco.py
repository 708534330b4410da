"""Delayed random-gain MuJoCo CIP vs the engine's own speed.

In one run, for the coupled CIP (default 128 realisations, paper parameters):
  * engine: ``mujoco.rollout`` of the same model with precomputed controls
    (one call, nstep steps: the engine's own multi-threaded speed);
  * ours:   ``cip.simulate.simulate_full`` (tau-at-a-time rollout, delay buffer,
    noise, recording of balancing errors);
each with 1 thread and with all threads.  Prints steps/s and the ratios.
Usage:  python benchmarks/bench_mujoco.py [--realizations 128] [--duration 2]
"""

from __future__ import annotations

import argparse
import os
import time

import mujoco
import numpy as np
from mujoco import rollout

from cip.model import CIPParams, build
from cip.simulate import simulate_full
from reduced import BalanceParams


def engine(m: mujoco.MjModel, nreal: int, nstep: int, threads: int) -> float:
    datas = [mujoco.MjData(m) for _ in range(threads)]
    d = mujoco.MjData(m)
    d.qpos[1] = d.qpos[3] = 1e-3
    s0 = np.empty(mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(m, d, s0, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    init = np.tile(s0, (nreal, 1))
    ctrl = np.random.default_rng(0).normal(0, 1e-3, (nreal, nstep, m.nu))
    t = time.perf_counter()
    rollout.rollout(m, datas, init, ctrl)
    return time.perf_counter() - t


def ours(p: BalanceParams, nreal: int, duration: float, threads: int) -> float:
    t = time.perf_counter()
    simulate_full("coupled", p, duration, nreal, seed=0, amplitude=1e-3, threads=threads,
                  fields=("balancing_error",), dtype=np.float32)  # fmt: skip
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--realizations", type=int, default=128)
    ap.add_argument("--duration", type=float, default=2.0)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    p = BalanceParams(beta=21.032)
    m = build("coupled", CIPParams.from_reduced(p))
    nstep = round(a.duration / p.dt)
    total = nstep * a.realizations
    ncpu = os.cpu_count() or 1
    print(f"coupled CIP, {a.realizations} realisations x {nstep} steps, best of {a.repeats}, "
          f"mujoco {mujoco.__version__}, {ncpu} cores")  # fmt: skip
    rate = {}
    for threads in sorted({1, ncpu}):
        e = min(engine(m, a.realizations, nstep, threads) for _ in range(a.repeats))
        o = min(ours(p, a.realizations, a.duration, threads) for _ in range(a.repeats))
        rate[threads] = (total / e, total / o)
        print(
            f"  threads={threads}: engine rollout {total / e / 1e3:8.1f} k steps/s   "
            f"delayed random gain {total / o / 1e3:8.1f} k steps/s   ratio {e / o:.2f}"
        )
    if ncpu > 1:
        se = rate[ncpu][0] / rate[1][0]
        so = rate[ncpu][1] / rate[1][1]
        print(f"  scaling 1 -> {ncpu} threads: engine x{se:.2f}, ours x{so:.2f}")
    print("  target: ratio >= 0.8 of the engine's speed, near-linear scaling over the cores")


if __name__ == "__main__":
    main()
