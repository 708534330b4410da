"""How fast this host is right now: microseconds per MuJoCo step of the single CIP.

On a shared (virtual) machine the same code runs at different speeds from one half
hour to the next: a single-model MuJoCo step took 1.2 us in one series and 2.2 us in
another, the code unchanged.  A time measured there means little without this
number beside it, so ``bench_run.py`` and ``bench_tests.py`` print it before and
after what they time (``python benchmarks/hostspeed.py`` prints it alone).

The probe: ``bench_mujoco.engine``, i.e. ``mujoco.rollout`` on one thread with
MuJoCo's profiling timers off (as the engine steps), 64 realisations x 2000 steps of
the single CIP at the paper's parameters (beta 21.032), the best of three (about
0.5 s).  Compare times between runs by their ratio to it, never across probes that
differ by more than a few per cent.
"""

from __future__ import annotations

import os

from bench_mujoco import engine

from cip.model import CIPParams, build
from cipcore.params import BalanceParams

REALIZATIONS, STEPS, REPEATS = 64, 2000, 3


def us_per_step(realizations: int = REALIZATIONS, steps: int = STEPS,
                repeats: int = REPEATS) -> float:  # fmt: skip
    """Best-of-``repeats`` us per step of one-thread ``mujoco.rollout`` of the single CIP,
    timers off (``bench_mujoco.engine``: the pendulum tilted by 1 mrad, small random
    controls)."""
    m = build("single", CIPParams.from_reduced(BalanceParams(beta=21.032)))
    best = min(engine(m, realizations, steps, 1, timers=False) for _ in range(repeats))
    return best / (realizations * steps) * 1e6


def line() -> str:
    """``host: 1.234 us per MuJoCo step (single CIP, one thread), load 0.12 0.34 0.56``."""
    load = " ".join(f"{v:.2f}" for v in os.getloadavg())
    return f"host: {us_per_step():.3f} us per MuJoCo step (single CIP, one thread), load {load}"


if __name__ == "__main__":
    print(line())
