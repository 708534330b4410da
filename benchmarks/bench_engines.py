"""Throughput of every registered engine, and its ratio to MuJoCo on the CPU, in one run.

For the coupled CIP at the paper's coupled gain, each available engine
simulates R realisations for ``--duration`` s (delayed random-gain control,
noise, recording of the balancing errors) after one warm-up call of the same
shape (compilation is reported separately as "first call").  Prints
realisation-steps/s per engine and batch size, and the ratio to the engine
named by ``--baseline`` measured in the same run.  ``--threads`` takes a list
(``--threads 1,2``): each engine runs at each count, and the speed-up over the first
count is printed (for Drake the threads are worker processes, so ``--engines drake
--threads 1,2`` shows its 1-process against its 2-process speed in one run).  The
load average is printed before and after (a shared machine's numbers mean little
without it); when MJX ran, its compile times (``cip.engines.mjx.COMPILE_LOG``) too.

Usage:  python benchmarks/bench_engines.py [--engines mujoco,mjx] [--realizations 1,16,128]
                                           [--duration 1] [--threads N[,M...]]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from cipcore.params import BalanceParams
from cipcore.registry import availability, engine_names, get_engine


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--engines", default=",".join(engine_names()))
    ap.add_argument("--realizations", default="1,16,128")
    ap.add_argument("--duration", type=float, default=1.0, help="simulated s per realisation")
    ap.add_argument("--threads", default=None, help="thread (Drake: process) counts, e.g. 1,2")
    ap.add_argument("--baseline", default="mujoco")
    a = ap.parse_args()
    p = BalanceParams(beta=21.032)
    steps = round(a.duration / p.dt)
    sizes = [int(s) for s in a.realizations.split(",")]
    counts = [int(t) for t in a.threads.split(",")] if a.threads else [None]
    rate: dict[tuple[str, int, int | None], float] = {}
    print("load average before: {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()))
    print(f"coupled CIP, {a.duration:g} s = {steps} steps per realisation")
    print(
        f"{'engine':12s} {'threads':>7s} {'R':>7s} {'first call s':>13s} {'steps/s':>12s} "
        f"{'x ' + a.baseline:>12s} {'x threads ' + str(counts[0]):>12s}"
    )
    for name in a.engines.split(","):
        why = availability(name)
        if why is not None:
            print(f"{name:12s} skipped: {why}")
            continue
        eng = get_engine(name)
        for r in sizes:
            for t in counts:
                kw = dict(amplitude=1e-3, threads=t, fields=("balancing_error",))
                t0 = time.perf_counter()
                eng.simulate("coupled", p, a.duration, r, 0, **kw)
                first = time.perf_counter() - t0
                t0 = time.perf_counter()
                eng.simulate("coupled", p, a.duration, r, 0, **kw)
                rate[name, r, t] = v = r * steps / (time.perf_counter() - t0)
                base, one = rate.get((a.baseline, r, t)), rate[name, r, counts[0]]
                ratio = f"{v / base:12.3f}" if base else f"{'n/a':>12s}"
                print(f"{name:12s} {t or '-':>7} {r:7d} {first:13.2f} {v:12.4g} {ratio} "
                      f"{v / one:12.3f}")  # fmt: skip
    print("load average after:  {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()))
    mjx = sys.modules.get("cip.engines.mjx")
    for c in getattr(mjx, "COMPILE_LOG", []):
        print(f"mjx compiled {c['rows']} rows x {c['steps']} steps in {c['seconds']:.2f} s "
              f"(persistent cache {c['persistent_cache']}, "
              f"exported chunk {c['exported']})")  # fmt: skip


if __name__ == "__main__":
    main()
