"""Delayed random-gain MuJoCo CIP vs the engine's own speed.

In one run, for the coupled CIP (default 128 realisations, paper parameters):
  * engine: ``mujoco.rollout`` of the same model with precomputed controls
    (one call, nstep steps: the engine's own multi-threaded speed);
  * ours:   ``cip.simulate.simulate_full`` (tau-at-a-time rollout, delay buffer,
    noise, recording of balancing errors);
each with 1 thread and with all threads.  Prints steps/s and the ratios: ours
against the engine as a plain Python program runs it (MuJoCo's profiling timers on,
as the bindings install them) and against the engine as ours steps it, with the
timers off (:mod:`cip.mjtimer`) and the constraint stages the model cannot use off
(:mod:`cip.mjstages`) and its sensors off, which isolates our own overhead.
``--timers`` instead prints the cost of the timers alone: us per step of
``mujoco.rollout`` on one thread, single and coupled CIP, timers on and off, and
whether the states are bit-identical; ``--stages`` the same for the unused stages
(timers off in both).
Usage:  python benchmarks/bench_mujoco.py [--realizations 128] [--duration 2] [--timers | --stages]
"""

from __future__ import annotations

import argparse
import copy
import os
import time

import mujoco
import numpy as np
from mujoco import rollout

from cip.mjstages import unused_stage_flags
from cip.mjtimer import timers_off
from cip.model import CIPParams, build
from cip.simulate import simulate_full
from cipcore.scenario import Execution, Recording, Scenario
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


def as_the_runner_steps(m: mujoco.MjModel, unused: bool = True) -> mujoco.MjModel:
    """A copy of ``m`` as :class:`cip.runner.MujocoRollout` steps it: sensors off and, with
    ``unused``, the constraint stages it cannot use off (:mod:`cip.mjstages`)."""
    m = copy.copy(m)
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_SENSOR
    if unused:
        m.opt.disableflags |= unused_stage_flags(m)
    return m


def stage_cost(p: BalanceParams, nreal: int, nstep: int, repeats: int) -> None:
    """us/step of one-thread rollouts (timers off) with and without the unused stages."""
    print(f"constraint stages the model cannot use (cip.mjstages), mujoco.rollout on 1 "
          f"thread, timers and sensors off, {nreal} x {nstep} steps, median of {repeats} "
          "alternated")  # fmt: skip
    for model in ("single", "coupled"):
        m = build(model, CIPParams.from_reduced(p))
        variants = {"every stage": as_the_runner_steps(m, unused=False),
                    "unused off": as_the_runner_steps(m)}  # fmt: skip
        runs: dict[str, list] = {k: [] for k in variants}
        states = {}
        for _ in range(repeats):  # interleaved, so that load changes hit both alike
            for k, mk in variants.items():
                t, states[k] = _engine(mk, nreal, nstep, 1, False)
                runs[k].append(t / (nreal * nstep) * 1e6)
        us = {k: float(np.median(v)) for k, v in runs.items()}
        same = np.array_equal(states["every stage"], states["unused off"])
        unused = unused_stage_flags(m)
        flags = mujoco.mjtDisableBit(unused).name if unused else "-"
        print(f"  {model:8s} {flags:18s} every stage {us['every stage']:6.3f} us/step   unused off "
              f"{us['unused off']:6.3f} us/step   ratio {us['unused off'] / us['every stage']:.2f}"
              f"   states bit-identical: {same}")  # fmt: skip


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
    simulate_full(
        Scenario("coupled", p, duration, nreal, 0, amplitude=1e-3),
        recording=Recording(fields=("balancing_error",), dtype=np.float32),
        execution=Execution(threads=threads),
    )
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--realizations", type=int, default=128)
    ap.add_argument("--duration", type=float, default=2.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--timers", action="store_true", help="the cost of MuJoCo's timers alone")
    ap.add_argument("--stages", action="store_true",
                    help="the cost of the constraint stages the models cannot use")  # fmt: skip
    a = ap.parse_args()
    p = BalanceParams(beta=21.032)
    if a.timers or a.stages:
        print(f"mujoco {mujoco.__version__}; load average {os.getloadavg()}")
        cost = timer_cost if a.timers else stage_cost
        cost(p, a.realizations, round(a.duration / p.dt), a.repeats)
        return
    m = build("coupled", CIPParams.from_reduced(p))
    lean = as_the_runner_steps(m)
    nstep = round(a.duration / p.dt)
    total = nstep * a.realizations
    ncpu = os.cpu_count() or 1
    print(f"load average {os.getloadavg()}")
    print(f"coupled CIP, {a.realizations} realisations x {nstep} steps, best of {a.repeats}, "
          f"mujoco {mujoco.__version__}, {ncpu} cores")  # fmt: skip
    rate = {}
    for threads in sorted({1, ncpu}):
        e = min(engine(m, a.realizations, nstep, threads) for _ in range(a.repeats))
        eo = min(engine(lean, a.realizations, nstep, threads, False) for _ in range(a.repeats))
        o = min(ours(p, a.realizations, a.duration, threads) for _ in range(a.repeats))
        rate[threads] = (total / e, total / o)
        print(
            f"  threads={threads}: engine rollout {total / e / 1e3:8.1f} k steps/s "
            f"(as ours steps it {total / eo / 1e3:8.1f})   "
            f"delayed random gain {total / o / 1e3:8.1f} k steps/s   "
            f"ratio {e / o:.2f} (against the engine as ours steps it {eo / o:.2f})"
        )
    if ncpu > 1:
        se = rate[ncpu][0] / rate[1][0]
        so = rate[ncpu][1] / rate[1][1]
        print(f"  scaling 1 -> {ncpu} threads: engine x{se:.2f}, ours x{so:.2f}")
    print("  target: ratio >= 0.8 of the engine's speed, near-linear scaling over the cores")


if __name__ == "__main__":
    main()
