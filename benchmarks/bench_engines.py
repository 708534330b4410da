"""Throughput of every registered engine, and its ratio to MuJoCo on the CPU, in one run.

For the coupled CIP at the paper's coupled gain, each available engine
simulates R realisations for ``--duration`` s (delayed random-gain control,
noise, recording of the balancing errors) after one warm-up call of the same
shape (compilation is reported separately as "first call").  Prints
realisation-steps/s per engine and batch size, and the ratio to the engine
named by ``--baseline`` measured in the same run.

Usage:  python benchmarks/bench_engines.py [--engines mujoco,mjx] [--realizations 1,16,128]
                                           [--duration 1] [--threads N]
"""

from __future__ import annotations

import argparse
import time

from cipcore.params import BalanceParams
from cipcore.registry import availability, engine_names, get_engine


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--engines", default=",".join(engine_names()))
    ap.add_argument("--realizations", default="1,16,128")
    ap.add_argument("--duration", type=float, default=1.0, help="simulated s per realisation")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--baseline", default="mujoco")
    a = ap.parse_args()
    p = BalanceParams(beta=21.032)
    steps = round(a.duration / p.dt)
    sizes = [int(s) for s in a.realizations.split(",")]
    rate: dict[tuple[str, int], float] = {}
    print(f"coupled CIP, {a.duration:g} s = {steps} steps per realisation, threads {a.threads}")
    print(
        f"{'engine':12s} {'R':>7s} {'first call s':>13s} {'steps/s':>12s} {'x ' + a.baseline:>12s}"
    )
    for name in a.engines.split(","):
        why = availability(name)
        if why is not None:
            print(f"{name:12s} skipped: {why}")
            continue
        eng = get_engine(name)
        for r in sizes:
            kw = dict(amplitude=1e-3, threads=a.threads, fields=("balancing_error",))
            t0 = time.perf_counter()
            eng.simulate("coupled", p, a.duration, r, 0, **kw)
            first = time.perf_counter() - t0
            t0 = time.perf_counter()
            eng.simulate("coupled", p, a.duration, r, 0, **kw)
            rate[name, r] = r * steps / (time.perf_counter() - t0)
            base = rate.get((a.baseline, r))
            ratio = f"{rate[name, r] / base:12.3f}" if base else f"{'n/a':>12s}"
            print(f"{name:12s} {r:7d} {first:13.2f} {rate[name, r]:12.4g} {ratio}")


if __name__ == "__main__":
    main()
