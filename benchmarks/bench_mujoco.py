"""Delayed random-gain MuJoCo CIP vs the engine's own speed.

In one run, for the coupled CIP (default 128 realisations, paper parameters):
  * engine: ``mujoco.rollout`` of the same model with precomputed controls
    (one call, nstep steps: the engine's own multi-threaded speed);
  * ours:   ``cip.simulate.simulate_full`` (tau-at-a-time rollout, delay buffer,
    noise, recording of balancing errors);
each with 1 thread and with all threads.  Prints steps/s and the ratios: ours
against the engine as a plain Python program runs it (MuJoCo's profiling timers on,
as the bindings install them) and against the engine with the timers off, as ours
steps (:mod:`cip.mjtimer`), which isolates our own overhead.
``--timers`` instead prints the cost of the timers alone: us per step of
``mujoco.rollout`` on one thread, single and coupled CIP, timers on and off, and
whether the states are bit-identical.
Usage:  python benchmarks/bench_mujoco.py [--realizations 128] [--duration 2] [--timers]
"""

from __future__ import annotations

import argparse
import os
import time

import mujoco
import numpy as np
from mujoco import rollout

from cip.mjtimer import timers_off
from cip.model import CIPParams, build
from cip.simulate import simulate_full
from reduced import BalanceParams


def engine(m: mujoco.MjModel, nreal: int, nstep: int, threads: int, timers: bool = True) -> float:
    return _engine(m, nreal, nstep, threads, timers)[0]


def _engine(
    m: mujoco.MjModel, nreal: int, nstep: int, threads: int, timers: bool
) -> tuple[float, np.ndarray]:
    datas = [mujoco.MjData(m) for _ in range(threads)]
    d = mujoco.MjData(m)
    for j in range(m.njnt):  # every pendulum tilted by 1 mrad
        if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE:
            d.qpos[m.jnt_qposadr[j]] = 1e-3
    s0 = np.empty(mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(m, d, s0, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    init = np.tile(s0, (nreal, 1))
    ctrl = np.random.default_rng(0).normal(0, 1e-3, (nreal, nstep, m.nu))
    if timers:
        t = time.perf_counter()
        state, _ = rollout.rollout(m, datas, init, ctrl)
        return time.perf_counter() - t, state
    with timers_off():
        t = time.perf_counter()
        state, _ = rollout.rollout(m, datas, init, ctrl)
        return time.perf_counter() - t, state


def timer_cost(p: BalanceParams, nreal: int, nstep: int, repeats: int) -> None:
    """us/step of one-thread rollouts with MuJoCo's timers on and off."""
    print(f"MuJoCo's profiling timers, mujoco.rollout on 1 thread, {nreal} x {nstep} steps, "
          f"best of {repeats}")  # fmt: skip
    for model in ("single", "coupled"):
        m = build(model, CIPParams.from_reduced(p))
        runs = {}
        for _ in range(repeats):  # interleaved, so that load changes hit both alike
            for on in (True, False):
                t, state = _engine(m, nreal, nstep, 1, on)
                best = runs.get(on, (np.inf, None))[0]
                runs[on] = (min(best, t), state)
        us = {on: runs[on][0] / (nreal * nstep) * 1e6 for on in runs}
        same = np.array_equal(runs[True][1], runs[False][1])
        print(f"  {model:8s} timers on {us[True]:6.3f} us/step   off {us[False]:6.3f} us/step   "
              f"ratio {us[True] / us[False]:.2f}   states bit-identical: {same}")  # fmt: skip


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
    ap.add_argument("--timers", action="store_true", help="the cost of MuJoCo's timers alone")
    a = ap.parse_args()
    p = BalanceParams(beta=21.032)
    if a.timers:
        print(f"mujoco {mujoco.__version__}; load average {os.getloadavg()}")
        timer_cost(p, a.realizations, round(a.duration / p.dt), a.repeats)
        return
    m = build("coupled", CIPParams.from_reduced(p))
    nstep = round(a.duration / p.dt)
    total = nstep * a.realizations
    ncpu = os.cpu_count() or 1
    print(f"load average {os.getloadavg()}")
    print(f"coupled CIP, {a.realizations} realisations x {nstep} steps, best of {a.repeats}, "
          f"mujoco {mujoco.__version__}, {ncpu} cores")  # fmt: skip
    rate = {}
    for threads in sorted({1, ncpu}):
        e = min(engine(m, a.realizations, nstep, threads) for _ in range(a.repeats))
        eo = min(engine(m, a.realizations, nstep, threads, False) for _ in range(a.repeats))
        o = min(ours(p, a.realizations, a.duration, threads) for _ in range(a.repeats))
        rate[threads] = (total / e, total / o)
        print(
            f"  threads={threads}: engine rollout {total / e / 1e3:8.1f} k steps/s "
            f"(timers off {total / eo / 1e3:8.1f})   "
            f"delayed random gain {total / o / 1e3:8.1f} k steps/s   "
            f"ratio {e / o:.2f} (against timers off {eo / o:.2f})"
        )
    if ncpu > 1:
        se = rate[ncpu][0] / rate[1][0]
        so = rate[ncpu][1] / rate[1][1]
        print(f"  scaling 1 -> {ncpu} threads: engine x{se:.2f}, ours x{so:.2f}")
    print("  target: ratio >= 0.8 of the engine's speed, near-linear scaling over the cores")


if __name__ == "__main__":
    main()
