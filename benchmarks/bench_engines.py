"""Throughput of registered engines vs MuJoCo on the CPU, measured in the same run.

For each model (single, coupled) and engine: ``engine.simulate`` of R
realisations x the duration at the paper's parameters (beta = 20.306,
amplitude 1e-3 m, seed 0, balancing error recorded only, one thread), best of
the repeats after one warm-up call; prints realisation-steps/s and the ratio
to the baseline engine.  Engines that are not available are listed as skipped
with the reason.
Usage:  python benchmarks/bench_engines.py [--engines mujoco,drake] [--realizations 16]
        [--duration 1] [--repeats 2]
"""

from __future__ import annotations

import argparse
import time

from cipcore.params import BalanceParams
from cipcore.registry import availability, get_engine

BASELINE = "mujoco"


def rate(name: str, model: str, p: BalanceParams, nreal: int, duration: float) -> float:
    """Realisation-steps per second of one ``simulate`` call."""
    engine = get_engine(name)
    t = time.perf_counter()
    engine.simulate(model, p, duration, nreal, seed=0, amplitude=1e-3, threads=1,
                    fields=("balancing_error",))  # fmt: skip
    return nreal * round(duration / p.dt) / (time.perf_counter() - t)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--engines", default="mujoco,drake")
    ap.add_argument("--realizations", type=int, default=16)
    ap.add_argument("--duration", type=float, default=1.0)
    ap.add_argument("--repeats", type=int, default=2)
    a = ap.parse_args()
    names = [BASELINE] + [n for n in a.engines.split(",") if n and n != BASELINE]
    p = BalanceParams(beta=20.306)
    print(f"{a.realizations} realisations x {round(a.duration / p.dt)} steps, 1 thread, "
          f"best of {a.repeats} after a warm-up call")  # fmt: skip
    for model in ("single", "coupled"):
        base = None
        for name in names:
            why = availability(name)
            if why is not None:
                print(f"  {model:7s} {name:8s} skipped: {why}")
                continue
            rate(name, model, p, a.realizations, min(a.duration, 0.1))  # warm-up
            r = max(rate(name, model, p, a.realizations, a.duration) for _ in range(a.repeats))
            base = base or r
            print(f"  {model:7s} {name:8s} {r:12.4g} realisation-steps/s   "
                  f"ratio to {BASELINE} {r / base:.4g}")  # fmt: skip


if __name__ == "__main__":
    main()
