"""Reduced coupled model in Lyapunov mode vs the cost of its Gaussian draws.

Prints realisation-steps per second of ``reduced.lyapunov`` (coupled, paper
parameters) and of drawing the same number of standard normals with the same
generators and threads (the bound: 2 draws per realisation-step), measured in
one run.  Usage:  python benchmarks/bench_reduced.py [--realizations 32] [--duration 200]
"""

from __future__ import annotations

import argparse
import time

from cipcore.driver import run_blocks
from cipcore.scenario import Execution, Scenario
from reduced import BalanceParams, GainNoise, lyapunov


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--realizations", type=int, default=32)
    ap.add_argument("--duration", type=float, default=200.0)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    p = BalanceParams(beta=21.032)
    n_steps = round(a.duration / p.dt)
    total = n_steps * a.realizations
    lyapunov(
        Scenario("coupled", p, 1.0, 2), execution=Execution(threads=a.threads)
    )  # compile / load the cache

    def draws_only() -> None:
        noise = GainNoise(0, a.realizations, 2)
        run_blocks(noise, n_steps, lambda block, xi, n0: None, threads=a.threads)

    def model() -> None:
        lyapunov(
            Scenario("coupled", p, a.duration, a.realizations),
            execution=Execution(threads=a.threads),
        )

    best = {}
    for name, fn in (("gaussian draws only", draws_only), ("coupled lyapunov", model)):
        times = []
        for _ in range(a.repeats):
            t = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t)
        best[name] = min(times)
    print(f"{a.realizations} realisations x {n_steps} steps = {total:.3g} realisation-steps, "
          f"threads={a.threads or 'all'}, best of {a.repeats}")  # fmt: skip
    for name, t in best.items():
        print(f"  {name:22s} {total / t / 1e6:8.1f} M realisation-steps/s  ({t:.3f} s)")
    ratio = best["coupled lyapunov"] / best["gaussian draws only"]
    print(f"  cost ratio model / draws: {ratio:.2f}  (target <= 2)")
    print(
        f"  per realisation-step: {best['coupled lyapunov'] / total * 1e9:.1f} ns, "
        f"draws alone {best['gaussian draws only'] / total * 1e9:.1f} ns (2 draws each)"
    )


if __name__ == "__main__":
    main()
