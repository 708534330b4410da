"""Cost of the STCC (eq. (8)) and of its Bartlett significance level at the paper's settings.

    python benchmarks/bench_stcc.py [--realizations 4] [--duration 1200]

Tip and base velocities sampled every 5 ms, Dt = 5 s, lags 0-0.3 s, windows every
0.25 s (the profiles' settings).  Prints seconds per realisation for each, after one
untimed call on a short series (which loads or compiles the STCC's compiled loop).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from validation.checks.metrics import stcc, stcc_significance_bartlett


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--realizations", type=int, default=4)
    ap.add_argument("--duration", type=float, default=1200.0)
    a = ap.parse_args()
    dt = 0.005
    rng = np.random.default_rng(0)
    n = round(a.duration / dt)
    x = rng.standard_normal((a.realizations, n)).cumsum(-1)
    y = np.roll(x, 7, -1) + rng.standard_normal((a.realizations, n))
    # a first call on a short series: the compiled loop loaded (or compiled) before timing
    stcc(x[:1, :4000], y[:1, :4000], dt, 5.0, 0.3, 0.25)
    t0 = time.perf_counter()
    t, lags, _r = stcc(x, y, dt, 5.0, 0.3, 0.25)
    t1 = time.perf_counter()
    stcc_significance_bartlett(x, y, dt, t, 5.0)
    t2 = time.perf_counter()
    print(f"{a.realizations} x {a.duration:g} s, {t.size} windows x {lags.size} lags")
    print(f"stcc: {(t1 - t0) / a.realizations:.3f} s per realisation")
    print(f"Bartlett level: {(t2 - t1) / a.realizations:.3f} s per realisation")


if __name__ == "__main__":
    main()
