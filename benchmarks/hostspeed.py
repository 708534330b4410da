"""How fast this host is right now: microseconds per MuJoCo step of the single CIP.

On a shared (virtual) machine the same code runs at different speeds from one half
hour to the next: a single-model MuJoCo step took 1.2 us in one series and 2.2 us in
another, the code unchanged.  A time measured there means little without this
number beside it, so ``bench_run.py``, ``bench_tests.py`` and ``targets.py`` print
it before and after what they time (``python benchmarks/hostspeed.py`` prints it
alone), with the same probe run on every core at once (the slowest core's number: a
two-core run goes at the pace of its slower core, which the one-thread probe misses).

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

REALIZATIONS, REPEATS = 64, 3


def _probe_steps() -> int:
    """Steps per realisation of the probe: 2000, or ``CIPVAL_HOSTSPEED_STEPS`` (a positive
    integer), which the tests of the benchmark scripts set small: they check the line's
    form, not the host."""
    raw = os.environ.get("CIPVAL_HOSTSPEED_STEPS", "2000")
    if not raw.isdigit() or int(raw) < 1:
        raise SystemExit(f"CIPVAL_HOSTSPEED_STEPS must be a positive integer, got {raw!r}")
    return int(raw)


STEPS = _probe_steps()


def us_per_step(realizations: int = REALIZATIONS, steps: int = STEPS,
                repeats: int = REPEATS) -> float:  # fmt: skip
    """Best-of-``repeats`` us per step of one-thread ``mujoco.rollout`` of the single CIP,
    timers off (``bench_mujoco.engine``: the pendulum tilted by 1 mrad, small random
    controls)."""
    m = build("single", CIPParams.from_reduced(BalanceParams(beta=21.032)))
    best = min(engine(m, realizations, steps, 1, timers=False) for _ in range(repeats))
    return best / (realizations * steps) * 1e6


def _probe(_: int) -> float:
    return us_per_step()


def us_per_step_all_cores(processes: int | None = None) -> float:
    """The probe of :func:`us_per_step` in ``processes`` (default: one per core) forked
    processes at once: the slowest process's us per step.  A run on every core goes
    at the pace of its slowest core, and on a shared virtual machine a second core
    can be slower than the first (a neighbour on it): the one-thread probe alone
    does not show that."""
    import multiprocessing as mp

    n = processes or os.cpu_count() or 1
    method = "fork" if "fork" in mp.get_all_start_methods() else "spawn"
    with mp.get_context(method).Pool(n) as pool:
        return max(pool.map(_probe, range(n)))


def load() -> str:
    """The load average now, as ``0.12 0.34 0.56`` (1, 5 and 15 minutes)."""
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def line() -> str:
    """``host: 1.234 us per MuJoCo step (single CIP, one thread), 1.345 us with every core
    stepping (2), load 0.12 0.34 0.56``."""
    now = load()
    one, every = us_per_step(), us_per_step_all_cores()
    return (f"host: {one:.3f} us per MuJoCo step (single CIP, one thread), {every:.3f} us "
            f"with every core stepping ({os.cpu_count()}), load {now}")  # fmt: skip


if __name__ == "__main__":
    print(line())
