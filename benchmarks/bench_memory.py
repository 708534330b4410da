"""Peak memory of the paper's workload with the reduced model.

100 realisations x 1200 s at dt = 1 ms (1.2e8 realisation-steps per model) of
the coupled model, recording the balancing errors of both controllers in
float32 (960 MB of results), in one process; prints the time and the peak
resident memory (target: within 2 GiB).
Usage:  python benchmarks/bench_memory.py [--realizations 100] [--duration 1200]
"""

from __future__ import annotations

import argparse
import resource
import time

import numpy as np

from cipcore.scenario import Recording, Scenario
from reduced import BalanceParams, simulate


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--realizations", type=int, default=100)
    ap.add_argument("--duration", type=float, default=1200.0)
    a = ap.parse_args()
    t = time.perf_counter()
    tr = simulate(
        Scenario("coupled", BalanceParams(beta=21.032), a.duration, a.realizations, 1),
        recording=Recording(fields=("balancing_error",), dtype=np.float32),
    )
    el = time.perf_counter() - t
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # KiB -> GiB
    e = tr["balancing_error"]
    print(f"coupled reduced model, {a.realizations} x {a.duration:g} s at 1 ms: "
          f"{e.shape} float32 = {e.nbytes / 2**30:.2f} GiB recorded")  # fmt: skip
    print(f"  time {el:.1f} s ({e.shape[0] * e.shape[1] / el / 1e6:.1f} M realisation-steps/s)")
    print(f"  peak resident memory {peak:.2f} GiB (target <= 2 GiB)")


if __name__ == "__main__":
    main()
